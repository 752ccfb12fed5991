"""A run as a rosbag2 MCAP: ``fleetmap export ros2`` (docs/replay.md, "ROS 2 bag").

Read from the run's ``replay.mcap`` (``scenarios.replay.mcap``), one message at a time in
log time order, and written as the MCAP ``ros2`` profile that rosbag2's MCAP storage
plugin reads and writes: schemas ``pkg/msg/Type`` in ``ros2msg`` with their full text
(``ros2_msgdefs``), CDR messages (encoded by ``mcap-ros2-support``), each channel's
``offered_qos_profiles`` in the plugin's YAML, log and publish time the run's sim time
[ns], as are the header stamps (``ros2_messages``):

=====================  ==========================  ======================================
topic                  type                        one message per
=====================  ==========================  ======================================
``/<unit>/scan``       sensor_msgs/msg/LaserScan   scan the run's server fused (every
                                                   one; the sampled LaserScans when the
                                                   replay has no fused scans)
``/tf``                tf2_msgs/msg/TFMessage      such scan: map -> ``<unit>/base_link``
                                                   at the pose the scan was sent with
``/<unit>/plan``       nav_msgs/msg/Path           plan the unit made
``/map``               nav_msgs/msg/OccupancyGrid  map sample: occupancy percent (-1
                                                   unknown, 0..100) as the server served it
``/costmap``           nav_msgs/msg/OccupancyGrid  costmap sample through Nav2's
                                                   cost-to-occupancy table (costvalues)
=====================  ==========================  ======================================

QoS as ROS 2 publishers of these topics offer: ``/map`` and ``/costmap`` reliable,
transient local, keep last 1 (map_server, Nav2's costmap publisher); the others reliable,
volatile, keep last 10 (``/tf`` 100). The profiles are written with numeric policies, the
form rosbag2 reads from a file without a ``rosbag2`` metadata record (every distro since
Humble); none is written, and no ``metadata.yaml``: ``ros2 bag info FILE.mcap`` and
``ros2 bag play FILE.mcap`` read the file alone. The replay's ``fleetmap.run`` metadata
record (scenario, policy, seed, grid) is copied.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Final

import orjson
import yaml
from mcap.exceptions import McapError
from mcap.reader import McapReader, make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer
from mcap_ros2._dynamic import EncoderFunction, serialize_dynamic

from mapserver.core.costvalues import costs_to_occupancy
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.store.atomic import atomic_output
from scenarios.replay.foxglove_messages import grid_values
from scenarios.replay.fused import FUSED_TOPIC, fused_scan
from scenarios.replay.mcap import (
    COSTMAP_TOPIC,
    LIBRARY,
    OCCUPANCY_TOPIC,
    RUN_METADATA,
    ReplayFileError,
    read_geometry,
    scan_of,
)
from scenarios.replay.ros2_messages import Message, laser_scan, occupancy_grid, path, tf_message
from scenarios.replay.ros2_msgdefs import LASER_SCAN, OCCUPANCY_GRID, PATH, TF_MESSAGE, full_text

ROS2_FILENAME: Final = "run.ros2.mcap"
PROFILE: Final = "ros2"
MAP: Final = "/map"
COSTMAP: Final = "/costmap"
TF: Final = "/tf"

_Item = tuple[str, str, Message]  # (topic, type, message)


def ros2_scan_topic(unit_id: str) -> str:
    return f"/{unit_id}/scan"


def ros2_plan_topic(unit_id: str) -> str:
    return f"/{unit_id}/plan"


def qos_profiles(depth: int, transient_local: bool = False) -> str:
    """A channel's ``offered_qos_profiles``: one reliable, keep-last ``depth`` profile,
    transient local or volatile, automatic liveliness, durations unspecified (0), in
    rosbag2's YAML with numeric policies (rmw's enums: keep last 1, reliable 1, transient
    local 1, volatile 2, automatic 1)."""
    unspecified = {"sec": 0, "nsec": 0}
    profile = {
        "history": 1,
        "depth": depth,
        "reliability": 1,
        "durability": 1 if transient_local else 2,
        "deadline": unspecified,
        "lifespan": unspecified,
        "liveliness": 1,
        "liveliness_lease_duration": unspecified,
        "avoid_ros_namespace_conventions": False,
    }
    return yaml.safe_dump([profile], sort_keys=False)


def _qos_of(topic: str) -> str:
    if topic in (MAP, COSTMAP):
        return qos_profiles(1, transient_local=True)
    return qos_profiles(100 if topic == TF else 10)


def default_output(run_dir: Path) -> Path:
    return run_dir / ROS2_FILENAME


def export_ros2(replay: str | os.PathLike[str], out: str | os.PathLike[str]) -> Counter[str]:
    """Write the rosbag2 MCAP of the run whose ``replay.mcap`` is ``replay`` at ``out``
    (atomically); returns the number of messages per topic.

    Raises ReplayFileError naming ``replay`` when it is not a readable fleetmap replay;
    OSError when ``out`` cannot be written.
    """
    geometry = read_geometry(replay)
    with open(replay, "rb") as source, atomic_output(out) as sink:
        bag = _BagWriter(sink)
        try:
            reader = make_reader(source)
            for record in reader.iter_metadata():
                if record.name == RUN_METADATA:
                    bag.writer.add_metadata(RUN_METADATA, record.metadata)
            for ns, items in _translated(reader, geometry):
                for topic, type_name, message in items:
                    bag.write(topic, type_name, message, ns)
        except (McapError, ValueError, KeyError, TypeError) as exc:
            raise ReplayFileError(f"{replay}: not a readable fleetmap replay ({exc!r})") from None
        bag.finish()
    return bag.counts


def _translated(reader: McapReader, geometry: GridGeometry) -> Iterator[tuple[int, list[_Item]]]:
    """(log time [ns], the ROS 2 messages) of each replay message that has any: the fused
    scans when the replay has them, else its sampled LaserScans (ValueError for a replay
    without a summary, which would not say which)."""
    summary = reader.get_summary()
    if summary is None:
        raise ValueError("no summary section (an unfinished replay?)")
    fused = any(c.topic == FUSED_TOPIC for c in summary.channels.values())
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        ns, name, topic = message.log_time, schema.name if schema else "", channel.topic
        if topic == FUSED_TOPIC:
            yield ns, _scan_items(ns, fused_scan(message.data)[1])
        elif name == "foxglove.LaserScan" and not fused:
            yield ns, _scan_items(ns, scan_of(channel, orjson.loads(message.data)))
        elif topic == OCCUPANCY_TOPIC:
            values = grid_values(orjson.loads(message.data))
            yield ns, [(MAP, OCCUPANCY_GRID, occupancy_grid(ns, geometry, values))]
        elif topic == COSTMAP_TOPIC:
            occupancy = costs_to_occupancy(grid_values(orjson.loads(message.data), "cost"))
            yield ns, [(COSTMAP, OCCUPANCY_GRID, occupancy_grid(ns, geometry, occupancy))]
        elif name == "foxglove.PosesInFrame":
            unit_id = topic.removeprefix("/units/").removesuffix("/plan")
            poses = orjson.loads(message.data)["poses"]
            yield ns, [(ros2_plan_topic(unit_id), PATH, path(ns, poses))]


def _scan_items(ns: int, scan: Scan) -> list[_Item]:
    return [
        (ros2_scan_topic(scan.unit_id), LASER_SCAN, laser_scan(ns, scan)),
        (TF, TF_MESSAGE, tf_message(ns, scan)),
    ]


class _BagWriter:
    """An MCAP writer of the ``ros2`` profile: a schema per type and a channel per topic,
    registered on first use; counts the messages per topic."""

    def __init__(self, sink: IO[bytes]) -> None:
        self.writer = Writer(sink)
        self.writer.start(profile=PROFILE, library=LIBRARY)
        self.counts: Counter[str] = Counter()
        self._schemas: dict[str, int] = {}
        self._encoders: dict[str, EncoderFunction] = {}
        self._channels: dict[str, int] = {}

    def write(self, topic: str, type_name: str, message: Message, ns: int) -> None:
        if type_name not in self._schemas:
            text = full_text(type_name)
            self._schemas[type_name] = self.writer.register_schema(
                type_name, SchemaEncoding.ROS2, text.encode()
            )
            self._encoders[type_name] = serialize_dynamic(type_name, text)[type_name]
        if topic not in self._channels:
            self._channels[topic] = self.writer.register_channel(
                topic,
                MessageEncoding.CDR,
                self._schemas[type_name],
                {"offered_qos_profiles": _qos_of(topic)},
            )
        data = self._encoders[type_name](message)
        self.writer.add_message(self._channels[topic], log_time=ns, data=data, publish_time=ns)
        self.counts[topic] += 1

    def finish(self) -> None:
        self.writer.finish()
