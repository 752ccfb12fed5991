"""``replay.mcap``: a run for Foxglove (docs/files.md), and its scans back for ``fleetmap replay``.

Every message is JSON with a Foxglove JSON schema (``foxglove_schemas``), stamped with sim
time in nanoseconds (log and publish time alike), written in time order:

======================  =====================  ==========================================
topic                   schema                 one message per
======================  =====================  ==========================================
``/units/<id>/scan``    foxglove.LaserScan     recorded scan (ranges: ``foxglove_messages``)
``/units/<id>/plan``    foxglove.PosesInFrame  plan the unit made
``/map/occupancy``      foxglove.Grid          grid sample (int8 field ``occupancy``)
``/map/costmap``        foxglove.Grid          grid sample (uint8 field ``cost``)
``/scene``              foxglove.SceneUpdate   stamp with unit samples (entities
                                               ``unit/<id>``), objects sample (entities
                                               ``object/<id>``, deletions for the gone)
``/log``                foxglove.Log           event, freeze, recovery action, stale-free
                                               plan, collision (``replay_log``)
``/fleetmap/scans``     fleetmap.FusedScan     scan the run's server fused, exactly
                                               (``replay_fused``)
``/metrics/map_truth``  fleetmap.MapTruth      map read (``map_truth_channel``)
======================  =====================  ==========================================

A scan channel's metadata carries what ``foxglove.LaserScan`` has no field for:
``unit_id``, ``range_min``, ``range_max`` [m], ``angle_increment`` [rad] and ``pose_std_xy``
[m], ``pose_std_yaw`` [rad] (empty when the scan had none), floats as Python ``repr``; a
unit whose values change gets another channel on the same topic. The file's metadata
record ``fleetmap.run`` holds the scenario, policy, seed and the map's grid geometry;
``fleetmap.map_settings`` the run's server's map settings (``replay_fused``).

``read_fused_replay`` gives the map settings and the fused scans back exactly, in the
server's fusion order; ``read_scans`` gives the sampled LaserScans back as
``mapserver.core.scan.Scan``: stamps to the nanosecond, x, y, angle_min, angle_increment,
range limits and pose_std exactly, yaw to ~1e-16 rad (through a quaternion; wrapped to
(-pi, pi]), ranges exactly as float32 with REP 117 classes kept (-inf comes back as NaN:
both invalid).
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import groupby
from operator import attrgetter, itemgetter
from pathlib import Path
from typing import Any

import orjson
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer

from fleet.unit import DriveLimits
from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.store.atomic import atomic_output
from scenarios.replay.foxglove_messages import (
    Message,
    decode_ranges,
    deletion,
    grid,
    laser_scan,
    log,
    object_entity,
    object_entity_id,
    planar_pose,
    poses_in_frame,
    scene_update,
    seconds_of,
    stamp_ns,
    unit_entity,
)
from scenarios.replay.foxglove_schemas import schema_text
from scenarios.replay.fused import (
    FUSED_SCHEMA,
    FUSED_SCHEMA_NAME,
    FUSED_TOPIC,
    MAP_SETTINGS_METADATA,
    fused_message,
    fused_scan,
    in_fusion_order,
    settings_metadata,
    settings_of,
)
from scenarios.replay.log import run_log
from scenarios.replay.map_truth_channel import (
    MAP_TRUTH_SCHEMA,
    MAP_TRUTH_TOPIC,
    map_truth_message,
    map_truth_schema_text,
)
from scenarios.run.record import RunRecord, ScanSample

REPLAY_FILENAME = "replay.mcap"
RUN_METADATA = "fleetmap.run"
OCCUPANCY_TOPIC = "/map/occupancy"
COSTMAP_TOPIC = "/map/costmap"
SCENE_TOPIC = "/scene"
LOG_TOPIC = "/log"
LIBRARY = "fleetmap"

_by_stamp = attrgetter("stamp")


def scan_topic(unit_id: str) -> str:
    return f"/units/{unit_id}/scan"


def plan_topic(unit_id: str) -> str:
    return f"/units/{unit_id}/plan"


class ReplayFileError(FleetmapError, ValueError):
    """A replay file is missing, not MCAP, or holds a scan that is not valid; the message
    names the file and what was wrong."""


@dataclass(frozen=True)
class _Channel:
    """A channel to write: topic, schema name and metadata (sorted key-value pairs)."""

    topic: str
    schema: str
    metadata: tuple[tuple[str, str], ...] = ()


_OCCUPANCY = _Channel(OCCUPANCY_TOPIC, "foxglove.Grid")
_COSTMAP = _Channel(COSTMAP_TOPIC, "foxglove.Grid")
_SCENE = _Channel(SCENE_TOPIC, "foxglove.SceneUpdate")
_LOG = _Channel(LOG_TOPIC, "foxglove.Log")
_FUSED = _Channel(FUSED_TOPIC, FUSED_SCHEMA_NAME)
_MAP_TRUTH = _Channel(MAP_TRUTH_TOPIC, MAP_TRUTH_SCHEMA)

_Item = tuple[int, _Channel, Message | bytes]  # (log time [ns], channel, message or its JSON)


def write_replay(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record`` as ``replay.mcap`` at ``path`` atomically; returns the path.

    ValueError if a stamp is negative or not finite, or a grid does not fit the geometry.
    """
    with atomic_output(path) as f:
        writer = Writer(f)
        writer.start(profile="", library=LIBRARY)
        writer.add_metadata(RUN_METADATA, _run_metadata(record))
        if record.fused is not None:
            writer.add_metadata(MAP_SETTINGS_METADATA, settings_metadata(record.fused.settings))
        schemas: dict[str, int] = {}
        channels: dict[_Channel, int] = {}
        streams = (
            _scene_objects(record),
            _grids(record),
            _scene_units(record),
            _scans(record),
            _plans(record),
            _log(record),
            _fused(record),
            _map_truth(record),
        )
        for ns, channel, message in heapq.merge(*streams, key=itemgetter(0)):
            if channel not in channels:
                if channel.schema not in schemas:
                    schemas[channel.schema] = writer.register_schema(
                        channel.schema, SchemaEncoding.JSONSchema, _schema_text(channel.schema)
                    )
                channels[channel] = writer.register_channel(
                    channel.topic,
                    MessageEncoding.JSON,
                    schemas[channel.schema],
                    dict(channel.metadata),
                )
            if isinstance(message, bytes):
                data = message
            else:
                data = orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY)
            writer.add_message(channels[channel], log_time=ns, data=data, publish_time=ns)
        writer.finish()
    return Path(path)


def read_scans(path: str | os.PathLike[str], until: float | None = None) -> list[Scan]:
    """The LaserScans of a replay (every ``foxglove.LaserScan`` channel written by
    ``write_replay``) in time order, those stamped after ``until`` [s] left out.

    Raises ReplayFileError naming the file for a missing or unreadable file or a bad scan.
    """
    until_ns = None if until is None else stamp_ns(until)
    scans = []
    try:
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
                if schema is None or schema.name != "foxglove.LaserScan":
                    continue
                if until_ns is not None and message.log_time > until_ns:
                    break
                scans.append(scan_of(channel, orjson.loads(message.data)))
    except (OSError, McapError, ValueError, KeyError, TypeError) as exc:
        raise ReplayFileError(f"{path}: not a readable fleetmap replay ({exc!r})") from None
    return scans


def read_fused_replay(
    path: str | os.PathLike[str], until: float | None = None
) -> tuple[dict[str, Any], list[Scan]] | None:
    """(the run's map settings, the scans its server fused in fusion order, those stamped
    after ``until`` [s] left out), or None for a replay without them (a run against an
    outside server, or one written before they were kept).

    Raises ReplayFileError naming the file for an unreadable file or a bad message.
    """
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            settings = next(
                (settings_of(r.metadata) for r in reader.iter_metadata()
                 if r.name == MAP_SETTINGS_METADATA),
                None,
            )  # fmt: skip
            if settings is None:
                return None
            items = (fused_scan(m.data) for _, _, m in reader.iter_messages([FUSED_TOPIC]))
            scans = in_fusion_order(items)
    except (OSError, McapError, ValueError, KeyError, TypeError) as exc:
        raise ReplayFileError(f"{path}: not a readable fleetmap replay ({exc!r})") from None
    if until is not None:
        scans = [scan for scan in scans if scan.stamp <= until]
    return settings, scans


def read_geometry(path: str | os.PathLike[str]) -> GridGeometry:
    """The map's grid geometry recorded in a replay's ``fleetmap.run`` metadata."""
    try:
        with open(path, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == RUN_METADATA:
                    m = record.metadata
                    return GridGeometry(
                        int(m["width"]),
                        int(m["height"]),
                        float(m["resolution"]),
                        float(m["origin_x"]),
                        float(m["origin_y"]),
                    )
    except (OSError, McapError, ValueError, KeyError) as exc:
        raise ReplayFileError(f"{path}: not a readable fleetmap replay ({exc!r})") from None
    raise ReplayFileError(f"{path}: no {RUN_METADATA!r} metadata record (not a fleetmap replay)")


# ------------------------------------------------------------------------------ streams
def _scene_objects(record: RunRecord) -> Iterator[_Item]:
    shown: set[str] = set()
    for sample in sorted(record.objects, key=_by_stamp):
        present = {object_entity_id(o.object_id) for o in sample.objects}
        gone = [deletion(sample.stamp, entity) for entity in sorted(shown - present)]
        entities = [object_entity(sample.stamp, o) for o in sample.objects]
        yield stamp_ns(sample.stamp), _SCENE, scene_update(entities, gone)
        shown = present


def _grids(record: RunRecord) -> Iterator[_Item]:
    for sample in sorted(record.grids, key=_by_stamp):
        ns = stamp_ns(sample.stamp)
        yield ns, _OCCUPANCY, grid(sample.stamp, record.geometry, sample.occupancy, "occupancy")
        yield ns, _COSTMAP, grid(sample.stamp, record.geometry, sample.costs, "cost")


def _scene_units(record: RunRecord) -> Iterator[_Item]:
    default = DriveLimits()
    radius = record.unit_radius or default.radius
    height = record.unit_height or default.height
    for stamp, samples in groupby(sorted(record.units, key=_by_stamp), key=_by_stamp):
        yield stamp_ns(stamp), _SCENE, scene_update(unit_entity(u, radius, height) for u in samples)


def _scans(record: RunRecord) -> Iterator[_Item]:
    for scan in sorted(record.scans, key=_by_stamp):
        yield stamp_ns(scan.stamp), _scan_channel(scan), laser_scan(scan)


def _plans(record: RunRecord) -> Iterator[_Item]:
    for plan in sorted(record.plans, key=_by_stamp):
        channel = _Channel(plan_topic(plan.unit_id), "foxglove.PosesInFrame")
        yield stamp_ns(plan.stamp), channel, poses_in_frame(plan)


def _fused(record: RunRecord) -> Iterator[_Item]:
    if record.fused is None:
        return
    for seq, scan in record.fused.scans():
        yield stamp_ns(scan.stamp), _FUSED, fused_message(seq, scan)


def _log(record: RunRecord) -> Iterator[_Item]:
    for line in run_log(record):
        yield stamp_ns(line.stamp), _LOG, log(line.stamp, line.level, line.name, line.message)


def _map_truth(record: RunRecord) -> Iterator[_Item]:
    """One ``/metrics/map_truth`` message per map read (``scenarios.replay.map_truth_channel``)."""
    for sample in sorted(record.map_truth, key=_by_stamp):
        yield stamp_ns(sample.stamp), _MAP_TRUTH, map_truth_message(sample)


def _schema_text(name: str) -> bytes:
    """A channel's schema text: the Foxglove schemas, and fleetmap's own
    ``fleetmap.FusedScan`` and ``fleetmap.MapTruth``."""
    if name == FUSED_SCHEMA_NAME:
        return orjson.dumps(FUSED_SCHEMA)
    if name == MAP_TRUTH_SCHEMA:
        return map_truth_schema_text()
    return schema_text(name)


# ------------------------------------------------------------------------------ scans
def _scan_channel(scan: ScanSample) -> _Channel:
    std = scan.pose_std
    metadata = {
        "unit_id": scan.unit_id,
        "range_min": repr(float(scan.range_min)),
        "range_max": repr(float(scan.range_max)),
        "angle_increment": repr(float(scan.angle_increment)),
        "pose_std_xy": "" if std is None else repr(float(std.xy)),
        "pose_std_yaw": "" if std is None else repr(float(std.yaw)),
    }
    return _Channel(scan_topic(scan.unit_id), "foxglove.LaserScan", tuple(sorted(metadata.items())))


def scan_of(channel: Channel, message: dict[str, Any]) -> Scan:
    """The Scan of one ``foxglove.LaserScan`` message (decoded JSON) on a channel made by
    ``_scan_channel``."""
    meta = channel.metadata
    x, y, yaw = planar_pose(message["pose"])
    body: dict[str, Any] = {
        "unit_id": meta["unit_id"],
        "stamp": seconds_of(message["timestamp"]),
        "frame": message["frame_id"],
        "pose": {"x": x, "y": y, "yaw": yaw},
        "angle_min": message["start_angle"],
        "angle_increment": float(meta["angle_increment"]),
        "range_min": float(meta["range_min"]),
        "range_max": float(meta["range_max"]),
        "ranges": decode_ranges(message["ranges"]),
    }
    if meta.get("pose_std_xy"):
        body["pose_std"] = {"xy": float(meta["pose_std_xy"]), "yaw": float(meta["pose_std_yaw"])}
    return Scan.from_dict(body)


def _run_metadata(record: RunRecord) -> dict[str, str]:
    g = record.geometry
    return {
        "scenario": record.scenario,
        "policy": record.policy,
        "seed": str(record.seed),
        "width": str(g.width),
        "height": str(g.height),
        "resolution": repr(float(g.resolution)),
        "origin_x": repr(float(g.origin_x)),
        "origin_y": repr(float(g.origin_y)),
    }
