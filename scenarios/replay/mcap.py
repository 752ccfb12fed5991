"""``replay.mcap``: a run for Foxglove (docs/files.md), and its scans back for ``fleetmap replay``.

Every message is JSON with a JSON schema, stamped with sim time in nanoseconds (log and
publish time alike), written in time order: the viewing channels of ``replay_channels``
(scans, plans, occupancy and coloured costmap, scene, ``/tf``, log, ``/metrics``,
``/metrics/map_truth``), built there from the record, and ``/fleetmap/scans``
(``fleetmap.FusedScan``, every scan the run's server fused, exactly: ``replay_fused``).

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
from operator import attrgetter, itemgetter
from pathlib import Path
from typing import Any

import orjson
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel as McapChannel
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer

from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.store.atomic import atomic_output
from scenarios.replay.channels import (
    COSTMAP_TOPIC,
    LOG_TOPIC,
    OCCUPANCY_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    Channel,
    Item,
    SceneObjects,
    encode,
    grid_items,
    log_items,
    map_truth_items,
    metrics_items,
    plan_items,
    plan_topic,
    scan_items,
    scan_topic,
    schema_text,
    unit_items,
)
from scenarios.replay.foxglove_messages import decode_ranges, planar_pose, seconds_of, stamp_ns
from scenarios.replay.fused import (
    FUSED_SCHEMA_NAME,
    FUSED_TOPIC,
    MAP_SETTINGS_METADATA,
    fused_scan,
    in_fusion_order,
    settings_metadata,
    settings_of,
)
from scenarios.replay.fused_worker import fused_items
from scenarios.replay.log import run_log
from scenarios.run.record import RunRecord

__all__ = [
    "COSTMAP_TOPIC", "LOG_TOPIC", "OCCUPANCY_TOPIC", "REPLAY_FILENAME", "SCENE_TOPIC",
    "TF_TOPIC", "ReplayFileError", "plan_topic", "read_fused_replay", "read_geometry",
    "read_scans", "scan_topic", "write_replay",
]  # fmt: skip

REPLAY_FILENAME = "replay.mcap"
RUN_METADATA = "fleetmap.run"
LIBRARY = "fleetmap"

_by_stamp = attrgetter("stamp")


class ReplayFileError(FleetmapError, ValueError):
    """A replay file is missing, not MCAP, or holds a scan that is not valid; the message
    names the file and what was wrong."""


_FUSED = Channel(FUSED_TOPIC, FUSED_SCHEMA_NAME)


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
        channels: dict[Channel, int] = {}
        streams = (*viewing_items(record), _fused(record))
        for ns, channel, message in heapq.merge(*streams, key=itemgetter(0)):
            if channel not in channels:
                if channel.schema not in schemas:
                    schemas[channel.schema] = writer.register_schema(
                        channel.schema, SchemaEncoding.JSONSchema, schema_text(channel.schema)
                    )
                channels[channel] = writer.register_channel(
                    channel.topic,
                    MessageEncoding.JSON,
                    schemas[channel.schema],
                    dict(channel.metadata),
                )
            data = encode(message)
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
def viewing_items(record: RunRecord) -> tuple[Iterator[Item], ...]:
    """The viewing channels' items of a finished run (``replay_channels``), one stream per
    kind, each in time order (the freezes scored: ``/metrics`` with its verdicts)."""

    def ordered(items):
        return sorted(items, key=_by_stamp)

    return (
        SceneObjects().items(ordered(record.objects)),
        grid_items(ordered(record.grids), record.geometry),
        unit_items(ordered(record.units), record.unit_radius, record.unit_height),
        scan_items(ordered(record.scans)),
        plan_items(ordered(record.plans)),
        log_items(run_log(record)),
        metrics_items(ordered(record.counters), record.freezes),
        map_truth_items(ordered(record.map_truth)),
    )


def _fused(record: RunRecord) -> Iterator[Item]:
    if record.fused is None:
        return
    for ns, message in fused_items(record.fused):
        yield ns, _FUSED, message


# ------------------------------------------------------------------------------ scans
def scan_of(channel: McapChannel, message: dict[str, Any]) -> Scan:
    """The Scan of one LaserScan message on a channel made by ``replay_channels.scan_channel``."""
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
