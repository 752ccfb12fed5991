"""The replay's viewing channels, and the one place that turns a run's record into their
messages: ``replay_mcap`` writes them to ``replay.mcap`` once the run is over, and
``replay_live`` sends the same messages over the Foxglove WebSocket protocol while the run
goes. Each function takes record items in time order and yields ``Item``s, (log time
[ns], channel, message).

=======================  =========================  ======================================
topic                    schema                     one message per
=======================  =========================  ======================================
``/units/<id>/scan``     foxglove.LaserScan         recorded scan (``scan_items``)
``/units/<id>/plan``     foxglove.PosesInFrame      plan the unit made
``/map/occupancy``       foxglove.Grid              grid sample (int8 field ``occupancy``)
``/map/costmap``         foxglove.Grid              grid sample (uint8 ``red``, ``green``,
                                                    ``blue``, ``alpha``, ``cost``)
``/scene``               foxglove.SceneUpdate       unit-sample stamp (entities
                                                    ``unit/<id>``); objects sample
                                                    (``object/<id>``, deletions)
``/tf``                  foxglove.FrameTransforms   unit-sample stamp: ``map`` ->
                                                    ``<id>/base_link`` per unit
``/log``                 foxglove.Log               event, freeze, recovery action,
                                                    unsafe plan, collision incident
``/metrics``             fleetmap.RunMetrics        counters sample (``metrics_channel``)
``/metrics/map_truth``   fleetmap.MapTruth          map read (``map_truth_channel``)
=======================  =========================  ======================================
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import groupby
from operator import attrgetter
from typing import Final

import orjson

from fleet.unit import DriveLimits
from mapserver.core.geometry import GridGeometry
from scenarios.replay.foxglove_messages import (
    Message,
    costmap_grid,
    deletion,
    frame_transforms,
    grid,
    laser_scan,
    log,
    object_entity,
    object_entity_id,
    poses_in_frame,
    scene_update,
    stamp_ns,
    unit_entity,
)
from scenarios.replay.foxglove_schemas import SCHEMAS as FOXGLOVE_SCHEMAS
from scenarios.replay.fused import FUSED_SCHEMA
from scenarios.replay.log import LogLine
from scenarios.replay.map_truth_channel import MAP_TRUTH_SCHEMA, MAP_TRUTH_TOPIC, map_truth_message
from scenarios.replay.map_truth_channel import SCHEMA as MAP_TRUTH_SCHEMA_JSON
from scenarios.replay.metrics_channel import METRICS_SCHEMA, METRICS_TOPIC, metrics_message
from scenarios.replay.metrics_channel import SCHEMA as METRICS_SCHEMA_JSON
from scenarios.run.record import (
    CountersSample,
    FreezeRecord,
    GridSample,
    MapTruthSample,
    ObjectsSample,
    PlanSample,
    ScanSample,
    UnitSample,
)

OCCUPANCY_TOPIC: Final = "/map/occupancy"
COSTMAP_TOPIC: Final = "/map/costmap"
SCENE_TOPIC: Final = "/scene"
TF_TOPIC: Final = "/tf"
LOG_TOPIC: Final = "/log"

_by_stamp = attrgetter("stamp")


def scan_topic(unit_id: str) -> str:
    return f"/units/{unit_id}/scan"


def plan_topic(unit_id: str) -> str:
    return f"/units/{unit_id}/plan"


@dataclass(frozen=True)
class Channel:
    """A channel to write: topic, schema name and metadata (sorted key-value pairs)."""

    topic: str
    schema: str
    metadata: tuple[tuple[str, str], ...] = ()


OCCUPANCY: Final = Channel(OCCUPANCY_TOPIC, "foxglove.Grid")
COSTMAP: Final = Channel(COSTMAP_TOPIC, "foxglove.Grid")
SCENE: Final = Channel(SCENE_TOPIC, "foxglove.SceneUpdate")
TF: Final = Channel(TF_TOPIC, "foxglove.FrameTransforms")
LOG: Final = Channel(LOG_TOPIC, "foxglove.Log")
METRICS: Final = Channel(METRICS_TOPIC, METRICS_SCHEMA)
MAP_TRUTH: Final = Channel(MAP_TRUTH_TOPIC, MAP_TRUTH_SCHEMA)

Item = tuple[int, Channel, Message | bytes]  # (log time [ns], channel, message or its JSON)


SCHEMAS: Final = {
    **FOXGLOVE_SCHEMAS,
    **{s["title"]: s for s in (FUSED_SCHEMA, MAP_TRUTH_SCHEMA_JSON, METRICS_SCHEMA_JSON)},
}
"""Every channel's JSON schema by name: the Foxglove schemas and fleetmap's own
(``fleetmap.FusedScan``, ``fleetmap.MapTruth``, ``fleetmap.RunMetrics``)."""


def schema_text(name: str) -> bytes:
    """The JSON text of schema ``name`` (a key of SCHEMAS) for an MCAP Schema record or a
    Foxglove WebSocket advertisement."""
    return json.dumps(SCHEMAS[name], separators=(",", ":")).encode()


def encode(message: Message | bytes) -> bytes:
    """A message's JSON bytes (numpy arrays as lists; bytes pass as they are)."""
    if isinstance(message, bytes):
        return message
    return orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY)


class SceneObjects:
    """The world's objects on ``/scene``: each sample an update with every object at its
    pose then and a deletion (``MATCHING_ID``) of each shown before and gone now."""

    def __init__(self) -> None:
        self.shown: set[str] = set()

    def items(self, samples: Iterable[ObjectsSample]) -> Iterator[Item]:
        for sample in samples:
            present = {object_entity_id(o.object_id) for o in sample.objects}
            gone = [deletion(sample.stamp, entity) for entity in sorted(self.shown - present)]
            entities = [object_entity(sample.stamp, o) for o in sample.objects]
            yield stamp_ns(sample.stamp), SCENE, scene_update(entities, gone)
            self.shown = present


def unit_items(
    samples: Iterable[UnitSample], radius: float | None, height: float | None
) -> Iterator[Item]:
    """Per unit-sample stamp: the units on ``/scene`` (cylinders of ``radius``, ``height``
    [m]; None: ``DriveLimits``' defaults) and their frames on ``/tf``."""
    default = DriveLimits()
    radius = radius or default.radius
    height = height or default.height
    for stamp, group in groupby(samples, key=_by_stamp):
        units = list(group)
        ns = stamp_ns(stamp)
        yield ns, SCENE, scene_update(unit_entity(u, radius, height) for u in units)
        yield ns, TF, frame_transforms(units)


def grid_items(samples: Iterable[GridSample], geometry: GridGeometry) -> Iterator[Item]:
    """Per grid sample: the occupancy (int8 ``occupancy``) and the coloured costmap."""
    for sample in samples:
        ns = stamp_ns(sample.stamp)
        yield ns, OCCUPANCY, grid(sample.stamp, geometry, {"occupancy": sample.occupancy})
        yield ns, COSTMAP, costmap_grid(sample.stamp, geometry, sample.costs)


def scan_items(scans: Iterable[ScanSample]) -> Iterator[Item]:
    for scan in scans:
        yield stamp_ns(scan.stamp), scan_channel(scan), laser_scan(scan)


def plan_items(plans: Iterable[PlanSample]) -> Iterator[Item]:
    for plan in plans:
        channel = Channel(plan_topic(plan.unit_id), "foxglove.PosesInFrame")
        yield stamp_ns(plan.stamp), channel, poses_in_frame(plan)


def log_items(lines: Iterable[LogLine]) -> Iterator[Item]:
    for line in lines:
        yield stamp_ns(line.stamp), LOG, log(line.stamp, line.level, line.name, line.message)


def metrics_items(
    samples: Iterable[CountersSample], freezes: Sequence[FreezeRecord] | None
) -> Iterator[Item]:
    """Per counters sample, its ``/metrics`` message (verdicts from ``freezes`` when
    scored)."""
    for sample in samples:
        yield stamp_ns(sample.stamp), METRICS, metrics_message(sample, freezes)


def map_truth_items(samples: Iterable[MapTruthSample]) -> Iterator[Item]:
    for sample in samples:
        yield stamp_ns(sample.stamp), MAP_TRUTH, map_truth_message(sample)


def scan_channel(scan: ScanSample) -> Channel:
    """A unit's scan channel: its metadata carries what ``foxglove.LaserScan`` has no field
    for (``replay_mcap``)."""
    std = scan.pose_std
    metadata = {
        "unit_id": scan.unit_id,
        "range_min": repr(float(scan.range_min)),
        "range_max": repr(float(scan.range_max)),
        "angle_increment": repr(float(scan.angle_increment)),
        "pose_std_xy": "" if std is None else repr(float(std.xy)),
        "pose_std_yaw": "" if std is None else repr(float(std.yaw)),
    }
    return Channel(scan_topic(scan.unit_id), "foxglove.LaserScan", tuple(sorted(metadata.items())))
