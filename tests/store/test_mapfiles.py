"""ROS map_server files: trinary PGM + YAML written loadable by Nav2, read as Nav2 reads them."""

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from mapserver.core.geometry import GridGeometry
from mapserver.store.mapfiles import MapFileError, MapMode, read_ros_map, write_ros_map

GOOD_YAML = {
    "image": "map.pgm",
    "resolution": 0.05,
    "origin": [1.0, -2.0, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}


def write_pgm(path: Path, rows: list[list[int]]) -> None:
    """A binary (P5) 8-bit PGM written by hand; ``rows[0]`` is the image's top row."""
    height, width = len(rows), len(rows[0])
    path.write_bytes(f"P5\n{width} {height}\n255\n".encode() + bytes(sum(rows, [])))


def write_yaml(path: Path, **overrides: object) -> Path:
    doc = {**GOOD_YAML, **overrides}
    doc = {key: value for key, value in doc.items() if value is not None}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def load_row(tmp_path: Path, pixels: list[int], **yaml_keys: object) -> list[int]:
    """Occupancy of a one-row PGM made of ``pixels`` under the given YAML keys."""
    write_pgm(tmp_path / "map.pgm", [pixels])
    return read_ros_map(write_yaml(tmp_path / "map.yaml", **yaml_keys)).occupancy[0].tolist()


# ------------------------------------------------------------------- writing
def test_written_yaml_has_the_keys_nav2_reads(tmp_path):
    geometry = GridGeometry(3, 2, 0.05, origin_x=-1.5, origin_y=2.25)
    occupancy = np.zeros((2, 3), dtype=np.int8)
    yaml_path = write_ros_map(tmp_path, occupancy, geometry)
    assert yaml_path == tmp_path / "map.yaml"
    assert yaml.safe_load(yaml_path.read_text()) == {
        "image": "map.pgm",
        "mode": "trinary",
        "resolution": 0.05,
        "origin": [-1.5, 2.25, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }


def test_written_pgm_is_trinary_p5_with_the_top_row_first(tmp_path):
    geometry = GridGeometry(3, 2, 0.1)
    occupancy = np.array([[0, 100, -1], [-1, 0, 100]], dtype=np.int8)  # row 0 = bottom
    write_ros_map(tmp_path, occupancy, geometry)
    data = (tmp_path / "map.pgm").read_bytes()
    assert data == b"P5\n3 2\n255\n" + bytes([205, 254, 0, 254, 0, 205])


def test_intermediate_occupancy_is_classified_as_nav2_map_saver(tmp_path):
    geometry = GridGeometry(6, 1, 0.05)
    occupancy = np.array([[0, 25, 26, 64, 65, 99]], dtype=np.int8)
    write_ros_map(tmp_path, occupancy, geometry)
    pixels = list((tmp_path / "map.pgm").read_bytes()[-6:])
    assert pixels == [254, 254, 205, 205, 0, 0]  # <= 25 free, >= 65 occupied, else unknown


def test_image_name_names_the_yaml(tmp_path):
    path = write_ros_map(
        tmp_path, np.zeros((1, 1), np.int8), GridGeometry(1, 1, 0.05), image_name="floor2.pgm"
    )
    assert path.name == "floor2.yaml"
    assert yaml.safe_load(path.read_text())["image"] == "floor2.pgm"


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 12),
    st.integers(1, 12),
    st.floats(0.001, 2.0),
    st.floats(-1e4, 1e4),
    st.floats(-1e4, 1e4),
    st.integers(0, 2**32 - 1),
)
def test_map_file_round_trip_is_exact(width, height, resolution, origin_x, origin_y, seed):
    geometry = GridGeometry(width, height, resolution, origin_x, origin_y)
    rng = np.random.default_rng(seed)
    occupancy = rng.choice(np.array([-1, 0, 100], dtype=np.int8), size=(height, width))
    with tempfile.TemporaryDirectory() as folder:
        loaded = read_ros_map(write_ros_map(Path(folder) / "out", occupancy, geometry))
    assert loaded.geometry == geometry
    assert loaded.occupancy.dtype == np.int8
    np.testing.assert_array_equal(loaded.occupancy, occupancy)
    assert loaded.mode is MapMode.TRINARY
    assert loaded.negate is False


def test_bad_occupancy_is_rejected_and_nothing_is_written(tmp_path):
    geometry = GridGeometry(2, 1, 0.05)
    with pytest.raises(ValueError, match="got 101 at row 0, col 1"):
        write_ros_map(tmp_path, np.array([[0, 101]], dtype=np.int8), geometry)
    with pytest.raises(ValueError, match="int8 of shape"):
        write_ros_map(tmp_path, np.zeros((2, 1), dtype=np.int8), geometry)
    with pytest.raises(ValueError, match="'map.png'"):
        write_ros_map(tmp_path, np.zeros((1, 2), dtype=np.int8), geometry, image_name="map.png")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_old_files_whole_and_no_temporaries(tmp_path, monkeypatch):
    geometry = GridGeometry(2, 1, 0.05)
    write_ros_map(tmp_path, np.array([[0, 100]], dtype=np.int8), geometry)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def broken_fsync(fd: int) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk full"):
        write_ros_map(tmp_path, np.array([[100, 0]], dtype=np.int8), geometry)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


# ------------------------------------------------------- reading, per mode
# occ = (255 - p) / 255 without negate, p / 255 with it; thresholds 0.65 and 0.196.
def test_trinary_pgm_loads_as_nav2(tmp_path):
    pixels = [0, 80, 100, 200, 205, 254, 255]
    # occ:    1.0 .686 .608 .216 .196 .004  0.0
    assert load_row(tmp_path, pixels) == [100, 100, -1, -1, -1, 0, 0]


def test_trinary_pgm_with_negate_loads_as_nav2(tmp_path):
    pixels = [0, 40, 50, 100, 200, 205, 254]
    # occ:    0.0 .157 .196 .392 .784 .804 .996
    assert load_row(tmp_path, pixels, negate=1) == [0, 0, -1, -1, 100, 100, 100]


def test_scale_pgm_loads_as_nav2(tmp_path):
    pixels = [0, 89, 90, 128, 150, 200, 254, 255]
    # occ:    1.0 .651 .647 .498 .412 .216 .004 0.0
    # between: rint(100 * (occ - 0.196) / 0.454)
    assert load_row(tmp_path, pixels, mode="scale") == [100, 100, 99, 67, 48, 4, 0, 0]


def test_scale_pgm_with_negate_loads_as_nav2(tmp_path):
    pixels = [0, 49, 50, 100, 128, 200, 255]
    # occ:    0.0 .192 .196 .392 .502 .784 1.0
    assert load_row(tmp_path, pixels, mode="scale", negate=1) == [0, 0, 0, 43, 67, 100, 100]


def test_raw_pgm_loads_pixel_values_as_nav2(tmp_path):
    pixels = [0, 1, 50, 100, 101, 205, 254, 255]
    assert load_row(tmp_path, pixels, mode="raw") == [0, 1, 50, 100, -1, -1, -1, -1]


def test_raw_pgm_ignores_negate_as_nav2(tmp_path):
    pixels = [0, 1, 50, 100, 101, 255]
    assert load_row(tmp_path, pixels, mode="RAW", negate=True) == [0, 1, 50, 100, -1, -1]


def test_scale_png_treats_any_transparency_as_unknown(tmp_path):
    la = np.array([[[0, 255], [0, 254], [255, 255], [128, 0]]], dtype=np.uint8)
    Image.fromarray(la, mode="LA").save(tmp_path / "map.png")
    write_yaml(tmp_path / "map.yaml", image="map.png", mode="scale")
    assert read_ros_map(tmp_path / "map.yaml").occupancy.tolist() == [[100, -1, 0, -1]]


def test_trinary_png_averages_alpha_into_the_shade(tmp_path):
    # shade = (3 * grey + alpha) / 4 / 255 in trinary mode (Nav2 keeps this legacy rule)
    la = np.array([[[254, 255], [254, 0], [0, 0], [0, 255]]], dtype=np.uint8)
    Image.fromarray(la, mode="LA").save(tmp_path / "map.png")
    write_yaml(tmp_path / "map.yaml", image="map.png")
    # occ: 1 - 254.25/255 = .003 -> 0; 1 - 190.5/255 = .253 -> -1; 1.0 -> 100; .75 -> 100
    assert read_ros_map(tmp_path / "map.yaml").occupancy.tolist() == [[0, -1, 100, 100]]


def test_colour_png_uses_the_mean_of_red_green_blue(tmp_path):
    rgb = np.array([[[10, 20, 30], [200, 255, 250], [1, 2, 2]]], dtype=np.uint8)
    Image.fromarray(rgb, mode="RGB").save(tmp_path / "map.png")
    write_yaml(tmp_path / "map.yaml", image="map.png")
    assert read_ros_map(tmp_path / "map.yaml").occupancy.tolist() == [[100, 0, 100]]
    write_yaml(tmp_path / "map.yaml", image="map.png", mode="raw")
    assert read_ros_map(tmp_path / "map.yaml").occupancy.tolist() == [[20, -1, 2]]  # 5/3 -> 2


def test_image_top_row_is_the_maps_last_row(tmp_path):
    write_pgm(tmp_path / "map.pgm", [[0, 0, 0], [254, 254, 205]])
    loaded = read_ros_map(write_yaml(tmp_path / "map.yaml"))
    assert loaded.occupancy.tolist() == [[0, 0, -1], [100, 100, 100]]
    assert loaded.geometry == GridGeometry(3, 2, 0.05, 1.0, -2.0)
    assert loaded.image == (tmp_path / "map.pgm").resolve()


def test_relative_image_path_resolves_against_the_yaml_folder(tmp_path, monkeypatch):
    (tmp_path / "images").mkdir()
    (tmp_path / "maps").mkdir()
    write_pgm(tmp_path / "images" / "floor.pgm", [[254]])
    yaml_path = write_yaml(tmp_path / "maps" / "floor.yaml", image="../images/floor.pgm")
    monkeypatch.chdir(tmp_path / "images")  # the working directory must not matter
    assert read_ros_map(yaml_path).image == (tmp_path / "images" / "floor.pgm").resolve()
    absolute = write_yaml(tmp_path / "maps" / "abs.yaml", image=str(tmp_path / "images/floor.pgm"))
    assert read_ros_map(absolute).occupancy.tolist() == [[0]]


def test_mode_defaults_to_trinary(tmp_path):
    write_pgm(tmp_path / "map.pgm", [[128]])
    loaded = read_ros_map(write_yaml(tmp_path / "map.yaml"))
    assert loaded.mode is MapMode.TRINARY
    assert loaded.occupancy.tolist() == [[-1]]


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"image": None}, "missing required key 'image'"),
        ({"image": ""}, "image must be a non-empty file name, got ''"),
        ({"image": "nowhere.pgm"}, "image 'nowhere.pgm' does not exist"),
        ({"mode": "fancy"}, "mode must be one of trinary, scale, raw, got 'fancy'"),
        ({"resolution": "abc"}, "resolution must be a finite number, got 'abc'"),
        ({"resolution": None}, "missing required key 'resolution'"),
        ({"resolution": 0}, "resolution must be > 0 m, got 0"),
        ({"origin": [0.0, 0.0, 0.5]}, "origin yaw must be 0 (maps are axis-aligned), got 0.5"),
        ({"origin": [0.0, 0.0]}, "origin must be a list of 3 finite numbers [x, y, yaw]"),
        ({"origin": [0.0, "x", 0.0]}, "origin must be a list of 3 finite numbers"),
        ({"negate": "maybe"}, "negate must be 0, 1, true or false, got 'maybe'"),
        ({"free_thresh": None}, "missing required key 'free_thresh'"),
        ({"occupied_thresh": 0.1}, "occupied_thresh=0.1"),
        ({"free_thresh": 1.5}, "free_thresh=1.5"),
    ],
)
def test_bad_yaml_errors_name_the_key_and_value(tmp_path, overrides, expected):
    write_pgm(tmp_path / "map.pgm", [[254]])
    yaml_path = write_yaml(tmp_path / "map.yaml", **overrides)
    with pytest.raises(MapFileError) as err:
        read_ros_map(yaml_path)
    assert expected in str(err.value)


def test_unreadable_files_give_clear_errors(tmp_path):
    with pytest.raises(MapFileError, match="does not exist"):
        read_ros_map(tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- just\n- a list\n")
    with pytest.raises(MapFileError, match="must be a mapping"):
        read_ros_map(tmp_path / "list.yaml")
    (tmp_path / "broken.yaml").write_text("image: [unclosed\n")
    with pytest.raises(MapFileError, match="not valid YAML"):
        read_ros_map(tmp_path / "broken.yaml")
    (tmp_path / "map.pgm").write_bytes(b"not an image")
    with pytest.raises(MapFileError, match="image 'map.pgm' cannot be read"):
        read_ros_map(write_yaml(tmp_path / "map.yaml"))
    Image.fromarray(np.zeros((2, 2), dtype=np.uint16)).save(tmp_path / "deep.png")  # 16 bit
    with pytest.raises(MapFileError, match="image 'deep.png' has unsupported mode"):
        read_ros_map(write_yaml(tmp_path / "deep.yaml", image="deep.png"))
