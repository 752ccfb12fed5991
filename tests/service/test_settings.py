"""Server settings: defaults, YAML file, FLEETMAP_* variables, overrides, and clear errors."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.core.sensor_model import DEFAULT_POLICY, DecayParams, Policy, SensorModel
from mapserver.service.settings import (
    Role,
    Settings,
    SettingsError,
    is_loopback,
    load_settings,
)
from mapserver.store.mapfiles import write_ros_map


@pytest.fixture(autouse=True)
def clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """No FLEETMAP_* variable of the machine running the tests leaks in."""
    for name in list(os.environ):
        if name.upper().startswith("FLEETMAP_"):
            monkeypatch.delenv(name)


def write_config(tmp_path: Path, document: object) -> Path:
    path = tmp_path / "fleetmap.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def problems(config: Path | None = None, **overrides: object) -> list[str]:
    """The problem lines of the SettingsError that loading must raise."""
    with pytest.raises(SettingsError) as info:
        load_settings(config, overrides)
    return info.value.problems


# ---------------------------------------------------------------------------- defaults
def test_defaults_are_the_documented_ones() -> None:
    s = load_settings(None, {})
    assert (s.host, s.port, s.data_dir) == ("127.0.0.1", 8700, Path("fleetmap-data"))
    assert s.map_yaml is None and s.static_map() is None
    assert s.geometry() == GridGeometry(2000, 1000, 0.05, 0.0, 0.0)  # 100 m x 50 m
    assert s.build_sensor_model() == SensorModel()
    assert s.policy is DEFAULT_POLICY is Policy.DUAL
    assert s.build_decay() == DecayParams(30.0, 120.0, 0.05)
    assert s.build_inflation() == InflationParams(0.55, 10.0, 0.3, False)
    assert s.clearing_range() == math.inf
    assert s.tokens == [] and s.open_access
    assert (s.limits.max_body_bytes, s.limits.max_beams, s.limits.max_batch) == (
        2 * 1024 * 1024,
        16384,
        256,
    )
    j = s.journal
    assert (j.synchronous, j.snapshot_every_scans, j.snapshot_every_seconds, j.history) == (
        "FULL",
        2000,
        60.0,
        256,
    )


def test_belief_grid_is_built_from_the_settings() -> None:
    s = load_settings(None, {"grid": {"width": 40, "height": 20}, "policy": "sticky"})
    grid = s.belief_grid()
    assert grid.geometry == GridGeometry(40, 20, 0.05)
    assert grid.policy is Policy.STICKY
    assert grid.sensor_model == s.build_sensor_model()


# ---------------------------------------------------------------------------- sources
def test_yaml_file_sets_values_and_keeps_other_defaults(tmp_path: Path) -> None:
    config = write_config(
        tmp_path,
        {
            "port": 9001,
            "grid": {"width": 400, "height": 300, "resolution": 0.1, "origin_x": -5.0},
            "sensor_model": {"p_hit": 0.8},
            "policy": "binary",
            "decay": {"half_life_occupied": 10},
            "inflation": {"inflation_radius": 1.0, "inflate_unknown": True},
            "max_clearing_range": 8.0,
            "tokens": [{"token": "t-unit", "role": "unit", "name": "robot 1", "units": ["r1"]}],
            "limits": {"max_batch": 64},
            "journal": {"synchronous": "normal", "snapshot_every_scans": 500},
        },
    )
    s = load_settings(config, {})
    assert s.port == 9001
    assert s.geometry() == GridGeometry(400, 300, 0.1, -5.0, 0.0)
    assert s.build_sensor_model() == SensorModel(p_hit=0.8)
    assert s.policy is Policy.BINARY
    assert s.build_decay().half_life_occupied == 10.0
    assert s.build_decay().half_life_free == 120.0
    assert s.build_inflation() == InflationParams(1.0, 10.0, 0.3, True)
    assert s.clearing_range() == 8.0
    assert s.token_roles() == {"t-unit": Role.UNIT}
    assert s.tokens[0].name == "robot 1"
    assert s.limits.max_batch == 64 and s.limits.max_beams == 16384
    assert s.journal.synchronous == "NORMAL" and s.journal.snapshot_every_scans == 500


def test_relative_paths_in_a_config_file_are_relative_to_its_folder(tmp_path: Path) -> None:
    config = write_config(tmp_path, {"data_dir": "state"})
    assert load_settings(config, {}).data_dir == tmp_path / "state"
    assert load_settings(None, {"data_dir": "state"}).data_dir == Path("state")


def test_map_yaml_gives_the_geometry_and_static_layer(tmp_path: Path) -> None:
    occupancy = np.full((6, 8), -1, dtype=np.int8)
    occupancy[2, 3] = 100
    occupancy[0, :] = 0
    geometry = GridGeometry(8, 6, 0.1, 1.0, -2.0)
    map_yaml = write_ros_map(tmp_path / "maps", occupancy, geometry)
    config = write_config(tmp_path, {"map_yaml": "maps/map.yaml", "grid": {"width": 5}})
    s = load_settings(config, {})
    assert s.map_yaml == map_yaml
    assert s.geometry() == geometry  # the map wins over `grid`
    static = s.static_map()
    assert static is not None
    np.testing.assert_array_equal(static.occupancy, occupancy)


def test_environment_overrides_yaml(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = write_config(tmp_path, {"port": 9001, "sensor_model": {"p_miss": 0.3}})
    monkeypatch.setenv("FLEETMAP_PORT", "9100")
    monkeypatch.setenv("FLEETMAP_SENSOR_MODEL__P_HIT", "0.85")
    s = load_settings(config, {})
    assert s.port == 9100
    # nested values merge: p_hit from the environment, p_miss from the file
    assert s.build_sensor_model() == SensorModel(p_hit=0.85, p_miss=0.3)


def test_environment_sets_tokens_as_json(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLEETMAP_TOKENS", '[{"token": "abc", "role": "reader"}]')
    monkeypatch.setenv("FLEETMAP_HOST", "0.0.0.0")
    s = load_settings(None, {})
    assert s.token_roles() == {"abc": Role.READER}
    assert not s.open_access


def test_explicit_overrides_beat_environment_and_yaml(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = write_config(tmp_path, {"port": 9001, "policy": "binary"})
    monkeypatch.setenv("FLEETMAP_PORT", "9100")
    monkeypatch.setenv("FLEETMAP_SENSOR_MODEL__P_HIT", "0.85")
    s = load_settings(config, {"port": 9200, "sensor_model.p_hit": 0.9, "host": None})
    assert s.port == 9200
    assert s.build_sensor_model().p_hit == 0.9
    assert s.host == "127.0.0.1"  # None means "flag not given"
    assert s.policy is Policy.BINARY


def test_from_yaml_takes_keyword_overrides(tmp_path: Path) -> None:
    config = write_config(tmp_path, {"port": 9001})
    assert Settings.from_yaml(config, port=9002).port == 9002


# ---------------------------------------------------------------------------- errors
def test_sensor_model_error_names_the_nested_field() -> None:
    assert problems(**{"sensor_model.p_hit": 0.4}) == [
        "sensor_model.p_hit: must be greater than the prior (0.5), got 0.4"
    ]


def test_unknown_policy_names_the_choices() -> None:
    (line,) = problems(policy="fancy")
    assert line.startswith("policy:")
    assert "'decay', 'binary', 'sticky' or 'dual'" in line and "'fancy'" in line


def test_negative_resolution_names_the_field_and_value() -> None:
    assert problems(grid={"resolution": -0.05}) == [
        "grid.resolution: must be positive metres, got -0.05"
    ]


def test_bad_token_role_names_the_token_and_value() -> None:
    (line,) = problems(tokens=[{"token": "abc", "role": "admin"}, {"token": "d", "role": "root"}])
    assert line.startswith("tokens[1].role:")
    assert "'unit', 'reader' or 'admin'" in line and "'root'" in line


def test_token_problems_never_print_the_secret() -> None:
    (line,) = problems(tokens=[{"token": "my secret", "role": "admin"}])
    assert line.startswith("tokens[0].token:") and "my secret" not in line
    (line,) = problems(
        tokens=[
            {"token": "same", "role": "unit", "units": ["*"]},
            {"token": "same", "role": "admin"},
        ]
    )
    assert line.startswith("tokens[1].token: duplicates") and "same" not in line


def test_rules_joining_sections_name_their_field() -> None:
    (line,) = problems(decay={"fade_bound": 0.7})
    assert line.startswith("decay.fade_bound: must be below") and line.endswith("got 0.7")
    assert problems(max_clearing_range=-1.0) == ["max_clearing_range: must be positive, got -1.0"]
    (line,) = problems(inflation={"inflation_radius": 0.1})
    assert line.startswith("inflation.inflation_radius: must be >= inscribed_radius")


def test_every_problem_is_reported_at_once(tmp_path: Path) -> None:
    config = write_config(
        tmp_path, {"port": "eighty", "grid": {"width": 0}, "prot": 1, "journal": {"history": 0}}
    )
    lines = problems(config)
    fields = sorted(line.split(":")[0] for line in lines)
    assert fields == ["grid.width", "journal.history", "port", "prot"]
    assert any("got 'eighty'" in line for line in lines)


def test_unknown_names_get_the_closest_field_and_types_read_as_one_sentence() -> None:
    assert sorted(problems(prot=1, sensor_model={"p_ht": 0.8}, grid={"width": "a"})) == [
        "grid.width: must be an integer, got 'a'",
        "prot: is not a field of settings; did you mean 'port'?",
        "sensor_model.p_ht: is not a field of sensor_model; did you mean 'p_hit'?",
    ]


def test_bad_environment_value_names_the_field_and_the_variable(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("FLEETMAP_SENSOR_MODEL__P_MISS", "0.6")
    assert problems() == [
        "sensor_model.p_miss: must be less than the prior (0.5), got 0.6 (set by the "
        "environment variable FLEETMAP_SENSOR_MODEL__P_MISS: correct or unset it)"
    ]


def test_missing_map_yaml_is_a_clear_error(tmp_path: Path) -> None:
    (line,) = problems(map_yaml=tmp_path / "nope.yaml")
    assert line.startswith("map_yaml:") and "nope.yaml" in line


# ---------------------------------------------------------------------------- security
def test_open_server_may_not_bind_beyond_loopback() -> None:
    (line,) = problems(host="0.0.0.0")
    assert line.startswith("host: an open server") and "loopback" in line
    assert line.endswith("got '0.0.0.0'")
    (line,) = problems(host="192.168.1.20")
    assert line.startswith("host:")


def test_tokens_allow_binding_any_address() -> None:
    s = load_settings(None, {"host": "0.0.0.0", "tokens": [{"token": "abc", "role": "admin"}]})
    assert s.host == "0.0.0.0" and s.token_roles() == {"abc": Role.ADMIN}


@pytest.mark.parametrize("host", ["127.0.0.1", "127.8.9.10", "::1", "[::1]", "localhost"])
def test_open_server_binds_loopback(host: str) -> None:
    assert is_loopback(host)
    assert load_settings(None, {"host": host}).open_access


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "10.0.0.1", "example.com", "localhost.evil"])
def test_other_hosts_are_not_loopback(host: str) -> None:
    assert not is_loopback(host)


def test_token_secrets_stay_out_of_repr() -> None:
    s = load_settings(None, {"tokens": [{"token": "hunter22", "role": "unit", "units": ["*"]}]})
    assert "hunter22" not in repr(s)


# ---------------------------------------------------------------------------- the file
def test_config_that_is_not_a_mapping_is_a_clear_error(tmp_path: Path) -> None:
    config = write_config(tmp_path, ["port", 9000])
    with pytest.raises(SettingsError) as info:
        load_settings(config, {})
    assert info.value.problems == ["config: must be a mapping of setting names to values, got list"]
    assert str(config) in str(info.value)


def test_unreadable_config_is_a_clear_error(tmp_path: Path) -> None:
    missing = tmp_path / "missing.yaml"
    with pytest.raises(SettingsError, match="config: cannot read the file") as info:
        load_settings(missing, {})
    assert str(missing) in str(info.value)


def test_invalid_yaml_is_a_clear_error(tmp_path: Path) -> None:
    config = tmp_path / "broken.yaml"
    config.write_text("port: [9000\n")
    with pytest.raises(SettingsError, match="config: not valid YAML"):
        load_settings(config, {})


def test_empty_config_file_means_defaults(tmp_path: Path) -> None:
    config = tmp_path / "empty.yaml"
    config.write_text("")
    assert load_settings(config, {}) == load_settings(None, {})


# ---------------------------------------------------------------------- no-return beams
def test_no_return_settings_default_to_the_sensor_model_and_can_be_set() -> None:
    s = load_settings(None, {})
    assert (s.sensor_model.p_miss_no_return, s.sensor_model.no_return_range) == (0.45, 1.0)
    s = load_settings(None, {"sensor_model": {"p_miss_no_return": 0.5, "no_return_range": None}})
    assert s.build_sensor_model() == SensorModel(p_miss_no_return=0.5, no_return_range=None)


def test_bad_no_return_settings_name_the_field() -> None:
    (line,) = problems(sensor_model={"p_miss_no_return": 0.3})
    assert line.startswith("sensor_model.p_miss_no_return: must be between p_miss (0.4)")
    (line,) = problems(sensor_model={"no_return_range": -2.0})
    assert line.startswith("sensor_model.no_return_range: must be a positive range")


def test_a_data_dir_from_before_no_return_evidence_opens_only_under_its_own_rule(tmp_path) -> None:
    """Its map-settings.json lacks the new fields: it was fused with no-return beams at
    p_miss out to range_max, which is what it is read as."""
    from mapserver.service.map_service import (
        MAP_SETTINGS_FILE,
        DataDirError,
        _check_map_settings,
        _map_settings,
    )

    old = _map_settings(load_settings(None, {}))
    for name in ("p_miss_no_return", "no_return_range", "fill_between_beams"):
        del old["sensor_model"][name]
    (tmp_path / MAP_SETTINGS_FILE).write_text(json.dumps(old))
    with pytest.raises(DataDirError, match="sensor_model differ"):
        _check_map_settings(tmp_path, _map_settings(load_settings(None, {})))
    legacy = {
        "sensor_model": {
            "p_miss_no_return": 0.4,
            "no_return_range": None,
            "fill_between_beams": False,
        }
    }
    _check_map_settings(tmp_path, _map_settings(load_settings(None, legacy)))  # accepted


def test_a_data_dir_from_before_the_fill_between_beams_opens_only_without_it(tmp_path) -> None:
    """Its map-settings.json lacks ``fill_between_beams``: it was fused beams only."""
    from mapserver.service.map_service import (
        MAP_SETTINGS_FILE,
        DataDirError,
        _check_map_settings,
        _map_settings,
        read_map_settings,
    )

    old = _map_settings(load_settings(None, {}))
    del old["sensor_model"]["fill_between_beams"]
    (tmp_path / MAP_SETTINGS_FILE).write_text(json.dumps(old))
    assert read_map_settings(tmp_path)["sensor_model"]["fill_between_beams"] is False
    with pytest.raises(DataDirError, match="sensor_model differ"):
        _check_map_settings(tmp_path, _map_settings(load_settings(None, {})))
    beams_only = {"sensor_model": {"fill_between_beams": False}}
    _check_map_settings(tmp_path, _map_settings(load_settings(None, beams_only)))  # accepted


def test_the_fill_between_beams_defaults_on_and_a_bad_value_names_the_field() -> None:
    assert load_settings(None, {}).build_sensor_model().fill_between_beams is True
    (line,) = problems(sensor_model={"fill_between_beams": "sometimes"})
    assert line.startswith("sensor_model.fill_between_beams:")
    assert "sometimes" in line
