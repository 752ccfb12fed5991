"""ROS map_server map files: a YAML description plus an image, written and read as Nav2 does.

Writing (``write_ros_map``) produces a *trinary* map that Nav2's ``map_server`` loads back
to the same OccupancyGrid: a binary PGM (P5, 8 bit) with 254 = free, 0 = occupied,
205 = unknown, the image's top row being the map's top row (the grid's last row), and a
YAML with ``image, mode, resolution, origin [x, y, 0.0], negate 0, occupied_thresh 0.65,
free_thresh 0.196``. Those thresholds are the ones ROS 1's ``map_saver`` writes and Nav2
writes for trinary maps since navigation2 PR #5278 ("Use fixed thresholds for Trinary
yaml"): 205 reads as ``occ = (255 - 205) / 255 = 0.196078...``, which is neither
``< 0.196`` (free) nor ``> 0.65`` (occupied), so it stays unknown; 254 reads as 0.0039
(free) and 0 as 1.0 (occupied). (Nav2's older default ``free_thresh: 0.25`` turned every
unknown pixel free.) Occupancy values between free and occupied are classified as
Nav2's ``map_saver`` does: ``<= rint(100 * free_threshold)`` is free,
``>= rint(100 * occupied_threshold)`` is occupied, anything else unknown.

Reading (``read_ros_map``) follows navigation2 ``nav2_map_server/src/map_io.cpp``
(``loadMapYaml`` and ``loadMapFromFile``), per pixel:

- ``shade`` in [0, 1] is the mean of the red, green and blue channels (grey images have
  all three equal), plus, in trinary mode only, the alpha channel (255 = opaque) when the
  image has one; channel values are scaled as GraphicsMagick's 16-bit quanta (x 257, then
  / 65535), as Nav2's usual build does.
- ``occ = shade`` when ``negate`` is set, else ``1 - shade``.
- trinary: ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0, else -1.
- scale: a pixel that is not fully opaque -> -1; ``occ > occupied_thresh`` -> 100,
  ``occ < free_thresh`` -> 0, else ``rint(100 * (occ - free_thresh) / (occupied_thresh -
  free_thresh))`` (round half to even).
- raw: ``v = round(255 * shade)`` (half away from zero); ``v`` if ``0 <= v <= 100``, else
  -1. ``negate`` is ignored, as in Nav2.

The image's row 0 is the map's top row, so rows are flipped to this project's layout (row
0 at the origin's y). ``mode`` is optional (default trinary, any letter case); the other
keys are required as Nav2 requires them. A relative ``image`` path is resolved against the
YAML file's folder. Stricter than Nav2, which checks neither: the origin's yaw must be 0
(this project's maps are axis-aligned) and ``0 <= free_thresh < occupied_thresh <= 1``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from mapserver.core.costvalues import OCC_FREE, OCC_OCCUPIED, OCC_UNKNOWN
from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.store.atomic import atomic_output

# Trinary image shades (map_saver's, read back by the thresholds below)
PIXEL_FREE = 254
PIXEL_OCCUPIED = 0
PIXEL_UNKNOWN = 205
# Thresholds written to the YAML of a trinary map [probability]
YAML_OCCUPIED_THRESH = 0.65
YAML_FREE_THRESH = 0.196
# GraphicsMagick (Q16) stores an 8-bit channel value v as the quantum v * 257 of 65535
_QUANTUM_PER_LEVEL = 257.0
_MAX_QUANTUM = 65535.0


class MapMode(StrEnum):
    """How pixel shades become occupancy (the YAML's ``mode``)."""

    TRINARY = "trinary"
    SCALE = "scale"
    RAW = "raw"


class MapFileError(FleetmapError, ValueError):
    """A map YAML or image that cannot be read; the message names the key and value."""


@dataclass(frozen=True)
class RosMap:
    """A map read from a ROS map_server YAML + image.

    geometry: width/height [cells] from the image, resolution [m/cell] and origin [m].
    occupancy: int8 (height, width), row 0 at the origin's y; -1 unknown, 0..100 percent.
    mode, negate, occupied_thresh, free_thresh: as given in the YAML (thresholds are
        probabilities in [0, 1]).
    image: absolute path of the image file.
    """

    geometry: GridGeometry
    occupancy: np.ndarray
    mode: MapMode
    negate: bool
    occupied_thresh: float
    free_thresh: float
    image: Path


# ---------------------------------------------------------------------------- writing
def write_ros_map(
    directory: str | os.PathLike[str],
    occupancy: np.ndarray,
    geometry: GridGeometry,
    image_name: str = "map.pgm",
    free_threshold: float = 0.25,
    occupied_threshold: float = 0.65,
) -> Path:
    """Write a trinary map (PGM + YAML) into ``directory``; returns the YAML's path.

    occupancy: int8 (height, width) OccupancyGrid values, row 0 at the origin's y:
        -1 unknown, 0..100 occupancy [percent].
    geometry: the grid's size, resolution [m/cell] and origin [m].
    image_name: file name of the image, ending in ``.pgm``; the YAML is named after it
        (``map.pgm`` -> ``map.yaml``).
    free_threshold, occupied_threshold: [probability] classify values as Nav2's
        map_saver does (module docstring); the defaults are this project's sensor-model
        thresholds (and map_saver's).

    The directory is created if needed. Each file is written to a temporary file in the
    directory and renamed over the target (image first, then the YAML naming it), so a
    failure leaves no partial file behind.
    """
    if Path(image_name).name != image_name or not image_name.lower().endswith(".pgm"):
        raise ValueError(f"image_name must be a bare file name ending in .pgm, got {image_name!r}")
    if not 0.0 <= free_threshold < occupied_threshold <= 1.0:
        raise ValueError(
            "thresholds must satisfy 0 <= free_threshold < occupied_threshold <= 1, got "
            f"free_threshold={free_threshold!r}, occupied_threshold={occupied_threshold!r}"
        )
    pixels = _trinary_pixels(occupancy, geometry, free_threshold, occupied_threshold)
    header = f"P5\n{geometry.width} {geometry.height}\n255\n".encode("ascii")
    document = {
        "image": image_name,
        "mode": MapMode.TRINARY.value,
        "resolution": float(geometry.resolution),
        "origin": [float(geometry.origin_x), float(geometry.origin_y), 0.0],
        "negate": 0,
        "occupied_thresh": YAML_OCCUPIED_THRESH,
        "free_thresh": YAML_FREE_THRESH,
    }
    text = yaml.safe_dump(document, sort_keys=False, default_flow_style=None)
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    yaml_path = folder / (Path(image_name).stem + ".yaml")
    with atomic_output(folder / image_name) as f:
        f.write(header + pixels.tobytes())
    with atomic_output(yaml_path) as f:
        f.write(text.encode("utf-8"))
    return yaml_path


def _trinary_pixels(
    occupancy: np.ndarray, geometry: GridGeometry, free_threshold: float, occupied_threshold: float
) -> np.ndarray:
    """uint8 image rows (top row first) of trinary shades for an occupancy grid."""
    occ = np.asarray(occupancy)
    if occ.dtype != np.int8 or occ.shape != geometry.shape:
        raise ValueError(
            f"occupancy must be int8 of shape {geometry.shape} (height, width), "
            f"got {occ.dtype} {occ.shape}"
        )
    bad = (occ < OCC_UNKNOWN) | (occ > OCC_OCCUPIED)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"occupancy values must be -1 or 0..100, got {int(occ[row, col])} "
            f"at row {row}, col {col}"
        )
    free_max = round(free_threshold * 100.0)  # map_saver: std::rint, half to even
    occupied_min = round(occupied_threshold * 100.0)
    pixels = np.full(occ.shape, PIXEL_UNKNOWN, dtype=np.uint8)
    known = occ >= OCC_FREE
    pixels[known & (occ <= free_max)] = PIXEL_FREE
    pixels[known & (occ >= occupied_min)] = PIXEL_OCCUPIED
    return np.ascontiguousarray(pixels[::-1])


# ---------------------------------------------------------------------------- reading
def read_ros_map(yaml_path: str | os.PathLike[str]) -> RosMap:
    """Load a ROS map_server map (YAML + PGM/PNG image) as Nav2's map_server would.

    Raises MapFileError naming the YAML key and the bad value (or the missing file).
    """
    path = Path(yaml_path)
    doc = _load_yaml(path)
    image = _image_path(path, _require(doc, "image", path))
    resolution = _number(doc, "resolution", path)
    if not resolution > 0:
        raise MapFileError(f"{path}: resolution must be > 0 m, got {doc['resolution']!r}")
    origin_x, origin_y = _origin(doc, path)
    occupied_thresh = _number(doc, "occupied_thresh", path)
    free_thresh = _number(doc, "free_thresh", path)
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise MapFileError(
            f"{path}: thresholds must satisfy 0 <= free_thresh < occupied_thresh <= 1, got "
            f"free_thresh={doc['free_thresh']!r}, occupied_thresh={doc['occupied_thresh']!r}"
        )
    negate = _negate(doc, path)
    mode = _mode(doc, path)
    rgb_sum, alpha = _read_image(image, path)
    occupancy = _occupancy_from_pixels(rgb_sum, alpha, mode, negate, occupied_thresh, free_thresh)
    height, width = occupancy.shape
    geometry = GridGeometry(width, height, resolution, origin_x, origin_y)
    return RosMap(geometry, occupancy, mode, negate, occupied_thresh, free_thresh, image)


def _occupancy_from_pixels(
    rgb_sum: np.ndarray,
    alpha: np.ndarray | None,
    mode: MapMode,
    negate: bool,
    occupied_thresh: float,
    free_thresh: float,
) -> np.ndarray:
    """Nav2's per-pixel rule (module docstring) on image rows; returns int8, row 0 = bottom.

    rgb_sum: float64 (rows, cols), top row first: red + green + blue [0..765].
    alpha: float64 alpha values [0..255, 255 = opaque] of the same shape, or None.
    Arithmetic in Nav2's order: sum of 16-bit quanta / channel count / 65535.
    """
    if mode is MapMode.TRINARY and alpha is not None:
        shade = (rgb_sum + alpha) * _QUANTUM_PER_LEVEL / 4.0 / _MAX_QUANTUM
    else:
        shade = rgb_sum * _QUANTUM_PER_LEVEL / 3.0 / _MAX_QUANTUM
    occ = shade if negate else 1.0 - shade
    out = np.full(rgb_sum.shape, OCC_UNKNOWN, dtype=np.int8)
    if mode is MapMode.RAW:
        scaled = shade * 255.0
        value = np.where(scaled - np.floor(scaled) >= 0.5, np.ceil(scaled), np.floor(scaled))
        keep = value <= OCC_OCCUPIED  # std::round, half away from zero (values are >= 0)
        out[keep] = value[keep].astype(np.int8)
    else:
        if mode is MapMode.SCALE:
            between = np.rint((occ - free_thresh) / (occupied_thresh - free_thresh) * 100.0)
            middle = (occ >= free_thresh) & (occ <= occupied_thresh)
            out[middle] = between[middle].astype(np.int8)
        out[occ < free_thresh] = OCC_FREE
        out[occ > occupied_thresh] = OCC_OCCUPIED
        if mode is MapMode.SCALE and alpha is not None:
            out[alpha != 255] = OCC_UNKNOWN
    return np.ascontiguousarray(out[::-1])


def _load_yaml(path: Path) -> dict[str, object]:
    if not path.is_file():
        raise MapFileError(f"map YAML {path} does not exist (give a map.yaml, as map build writes)")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as err:
        raise MapFileError(f"{path}: not valid YAML: {err}") from err
    if not isinstance(doc, dict):
        raise MapFileError(f"{path}: a map YAML must be a mapping of keys, got {doc!r}")
    return doc


def _require(doc: dict[str, object], key: str, path: Path) -> object:
    if key not in doc:
        raise MapFileError(f"{path}: missing required key {key!r}")
    return doc[key]


def _finite(value: object) -> float | None:
    """``value`` as a finite float, else None. yaml-cpp scalars are untyped, so numeric
    strings count as numbers (as Nav2 reads them); booleans do not."""
    if isinstance(value, bool):
        return None
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _number(doc: dict[str, object], key: str, path: Path) -> float:
    value = _require(doc, key, path)
    number = _finite(value)
    if number is None:
        raise MapFileError(f"{path}: {key} must be a finite number, got {value!r}")
    return number


def _origin(doc: dict[str, object], path: Path) -> tuple[float, float]:
    value = _require(doc, "origin", path)
    numbers = [_finite(v) for v in value] if isinstance(value, list) else []
    if len(numbers) != 3 or None in numbers:
        raise MapFileError(
            f"{path}: origin must be a list of 3 finite numbers [x, y, yaw], got {value!r}"
        )
    x, y, yaw = numbers
    if yaw != 0.0:
        raise MapFileError(
            f"{path}: origin yaw must be 0 (maps are axis-aligned), got {value[2]!r} in {value!r}"
        )
    return x, y


def _negate(doc: dict[str, object], path: Path) -> bool:
    value = _require(doc, "negate", path)
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        return value != 0
    raise MapFileError(f"{path}: negate must be 0, 1, true or false, got {value!r}")


def _mode(doc: dict[str, object], path: Path) -> MapMode:
    value = doc.get("mode", MapMode.TRINARY.value)
    try:
        return MapMode(str(value).lower())
    except ValueError:
        names = ", ".join(m.value for m in MapMode)
        raise MapFileError(f"{path}: mode must be one of {names}, got {value!r}") from None


def _image_path(yaml_path: Path, value: object) -> Path:
    if not isinstance(value, str) or not value:
        raise MapFileError(f"{yaml_path}: image must be a non-empty file name, got {value!r}")
    image = Path(value)
    if not image.is_absolute():
        image = yaml_path.parent / image
    image = image.resolve()
    if not image.is_file():
        raise MapFileError(f"{yaml_path}: image {value!r} does not exist (looked for {image})")
    return image


def _read_image(image: Path, yaml_path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(R + G + B; alpha or None), float64, top row first, from an 8-bit image."""
    try:
        with Image.open(image) as img:
            img.load()
            if img.mode in ("1", "L", "LA", "RGB", "RGBA"):
                pic = img
            elif img.mode in ("P", "PA"):
                has_alpha = img.mode == "PA" or "transparency" in img.info
                pic = img.convert("RGBA" if has_alpha else "RGB")
            else:
                raise MapFileError(
                    f"{yaml_path}: image {image.name!r} has unsupported mode {img.mode!r} "
                    "(8-bit grey, grey+alpha, palette, RGB or RGBA are read)"
                )
            data = np.asarray(pic.convert("L") if pic.mode == "1" else pic, dtype=np.float64)
            mode = pic.mode
    except OSError as err:
        raise MapFileError(f"{yaml_path}: image {image.name!r} cannot be read: {err}") from err
    if mode in ("1", "L"):
        return 3.0 * data, None
    if mode == "LA":
        return 3.0 * data[..., 0], data[..., 1]
    return data[..., :3].sum(axis=2), (data[..., 3] if mode == "RGBA" else None)
