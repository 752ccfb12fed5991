"""One root for every error fleetmap raises on purpose; a bad field carried as attributes."""

import importlib
import inspect
import pkgutil

import pytest
from conftest import HAVE_SIM

import fleet
import mapserver
import planner
import scenarios
from fleet.bullet import SimulatorMissing
from mapserver.core.errors import FieldError, FleetmapError
from mapserver.core.sensor_model import SensorModel
from mapserver.service.settings import SettingsError, load_settings


def test_a_field_error_carries_the_field_the_value_and_the_reason():
    with pytest.raises(FieldError) as caught:
        SensorModel(p_hit=0.3)
    exc = caught.value
    assert (exc.field, exc.value, exc.reason) == (
        "p_hit",
        0.3,
        "must be greater than the prior (0.5)",
    )
    assert str(exc) == "p_hit must be greater than the prior (0.5), got 0.3"
    assert isinstance(exc, ValueError) and isinstance(exc, FleetmapError)


def test_settings_place_a_domain_error_by_its_field_and_keep_it_structured():
    with pytest.raises(SettingsError) as caught:
        load_settings(None, {"sensor_model.p_hit": 0.3})
    assert caught.value.fields == [
        ("sensor_model.p_hit", "must be greater than the prior (0.5), got 0.3")
    ]
    assert caught.value.problems == [
        "sensor_model.p_hit: must be greater than the prior (0.5), got 0.3"
    ]


def test_every_exception_class_of_the_project_derives_from_the_root():
    found, need_sim = [], []
    for package in (mapserver, planner, fleet, scenarios):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            try:
                module = importlib.import_module(info.name)
            except SimulatorMissing:  # only without PyBullet (tests/conftest.py)
                need_sim.append(info.name)
                continue
            for _, cls in inspect.getmembers(module, inspect.isclass):
                if cls.__module__ == module.__name__ and issubclass(cls, BaseException):
                    found.append(cls)
    assert len(found) > 20
    assert [c.__qualname__ for c in found if not issubclass(c, FleetmapError)] == []
    assert not (need_sim and HAVE_SIM)
    assert [m for m in need_sim if not m.startswith(("fleet.", "scenarios."))] == []
