"""The ``map_server`` section of a scenario: the map server's settings for a run.

The section uses the server config's own names (``policy``, ``sensor_model``, ``decay``,
``inflation``, ``max_clearing_range``) plus ``resolution`` [m/cell]; the grid covers the
whole floor from origin (0, 0). It is checked by building the server's ``Settings``
through ``mapserver.service.settings.load_settings``, never by rules of its own: the server's
first problem becomes a ScenarioError at ``map_server.<its field>``. Every value is
pinned (defaults filled in, ``inflation.inscribed_radius`` defaulting to the units'
radius, as Nav2 derives it from the footprint), so ``FLEETMAP_*`` variables cannot
change a run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from fleet.layout import Layout
from fleet.unit import DriveLimits
from mapserver.client.zones import MAX_ZONES
from mapserver.core.inflation import InflationParams
from mapserver.core.sensor_model import DEFAULT_POLICY, DecayParams, Policy, SensorModel
from mapserver.service.settings import (
    DecaySettings,
    GridSettings,
    InflationSettings,
    SensorModelSettings,
    Settings,
    SettingsError,
    load_settings,
)
from mapserver.service.validation import Section, domain_section, number, reworded
from scenarios.spec.yaml_lines import Document, field_path

DEFAULT_RESOLUTION_M = 0.1
MAX_GRID_CELLS = 25_000_000
"""Largest map grid a scenario may ask for (the server keeps ~20 bytes per cell)."""
MAP_SERVER_SECTIONS = {
    "sensor_model": SensorModelSettings,
    "decay": DecaySettings,
    "inflation": InflationSettings,
}
PolicyName = Annotated[
    Literal[tuple(p.value for p in Policy)],
    reworded("must be one of " + ", ".join(p.value for p in Policy)),
]
"""A map policy's name (``Policy``)."""
_TYPES_ONLY = "Types only: the values are checked by the server's own Settings."
SensorModelFields = domain_section(SensorModel, "SensorModelFields", _TYPES_ONLY, check=False)
DecayFields = domain_section(DecayParams, "DecayFields", _TYPES_ONLY, check=False)
InflationFields = domain_section(InflationParams, "InflationFields", _TYPES_ONLY, check=False)


class MapServerFields(Section):
    """The ``map_server`` section (module docstring); the sections' values are checked
    by ``load_settings`` (so are only the given ones passed on)."""

    policy: PolicyName = DEFAULT_POLICY.value
    resolution: number("metres", ge=0.01, le=1.0) = DEFAULT_RESOLUTION_M
    sensor_model: SensorModelFields = SensorModelFields()
    decay: DecayFields = DecayFields()
    inflation: InflationFields = InflationFields()
    max_clearing_range: number("metres") | None = None
    zones: number("map servers", ge=1, le=MAX_ZONES, integer=True) = 1


@dataclass(frozen=True)
class MapServerSpec:
    """The map server a run uses: every value the scenario pins (defaults filled in).

    grid: the whole floor at the scenario's resolution, origin (0, 0).
    zones: how many map servers share the floor, each a strip of it with borders
    (``mapserver.client.zones.ZoneLayout``; 1: one server for the whole floor).
    """

    policy: Policy
    grid: GridSettings
    sensor_model: SensorModelSettings
    decay: DecaySettings
    inflation: InflationSettings
    max_clearing_range: float | None = None
    zones: int = 1

    def overrides(self) -> dict[str, Any]:
        """Settings overrides for ``load_settings`` (nested mappings): the policy, grid,
        sensor model, decay, inflation and clearing range, complete, so neither the
        environment nor a config file can change a run."""
        out: dict[str, Any] = {
            "policy": self.policy.value,
            "grid": self.grid.model_dump(),
            "sensor_model": self.sensor_model.model_dump(),
            "decay": self.decay.model_dump(),
            "inflation": self.inflation.model_dump(),
        }
        if self.max_clearing_range is not None:
            out["max_clearing_range"] = self.max_clearing_range
        return out

    def settings(self, extra: Mapping[str, Any] | None = None) -> Settings:
        """Server ``Settings`` with these values, plus ``extra`` overrides (``data_dir``,
        ``port``, ... as ``load_settings`` takes them)."""
        return load_settings(None, {**self.overrides(), **(extra or {})})


def parse_map_server(
    doc: Document, f: MapServerFields, layout: Layout, drive: DriveLimits
) -> MapServerSpec:
    """The map server section, checked by building the server's own Settings."""
    where = ("map_server",)
    width = math.ceil(layout.width / f.resolution - 1e-9)
    height = math.ceil(layout.height / f.resolution - 1e-9)
    if f.zones > width:
        raise doc.error(
            (*where, "zones"), f"must be at most the floor's {width} grid columns", f.zones
        )
    if width * height > MAX_GRID_CELLS:
        raise doc.error(
            (*where, "resolution"),
            f"gives a {width} x {height} grid, more than {MAX_GRID_CELLS} cells",
            f.resolution,
        )
    overrides: dict[str, Any] = {
        "policy": f.policy,
        "grid": {"width": width, "height": height, "resolution": f.resolution},
        "max_clearing_range": f.max_clearing_range,
    }
    for name, section in MAP_SERVER_SECTIONS.items():
        values = section().model_dump()
        if name == "inflation":  # Nav2 derives it from the footprint: so do we
            values["inscribed_radius"] = drive.radius
        values.update(getattr(f, name).model_dump(exclude_unset=True))
        overrides[name] = values
    try:
        settings = load_settings(None, overrides)
    except SettingsError as exc:
        name, detail = exc.fields[0] if exc.fields else ("", exc.problems[0])
        path = field_path(name)
        if not path or path[0] not in MapServerFields.model_fields:
            place = (*where, "resolution") if path[:1] == ("grid",) else where
            raise doc.error(place, exc.problems[0]) from None
        raise doc.error((*where, *path), detail) from None
    return MapServerSpec(
        policy=settings.policy,
        grid=settings.grid,
        sensor_model=settings.sensor_model,
        decay=settings.decay,
        inflation=settings.inflation,
        max_clearing_range=settings.max_clearing_range,
        zones=f.zones,
    )
