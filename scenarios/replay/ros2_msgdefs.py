"""The ROS 2 message definitions a run's rosbag2 MCAP uses, as rosbag2 writes them.

An MCAP schema of the ``ros2`` profile (encoding ``ros2msg``) holds the full text of its
type: the type's own ``.msg`` fields, then each type it depends on, once, depth first,
dependencies in sorted order, each after a separator line of 80 ``=`` and a line
``MSG: pkg/Type`` (rosbag2's ``LocalMessageDefinitionSource``; the MCAP ``ros2``
profile). ``full_text("nav_msgs/msg/Path")`` builds it.

The fields are those of ROS 2 (Humble and later: ``common_interfaces``,
``rcl_interfaces/builtin_interfaces``), comments left out; field types name their
package in full (``nav_msgs/MapMetaData``, not ``MapMetaData``), which parsers read alike.
"""

from __future__ import annotations

from typing import Final

SEPARATOR: Final = "=" * 80

_PRIMITIVES: Final = frozenset(
    "bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 string"
    .split()
)  # fmt: skip

# type (pkg/Type) -> its field lines, "type name" or "type name default"
_FIELDS: Final[dict[str, tuple[str, ...]]] = {
    "builtin_interfaces/Time": ("int32 sec", "uint32 nanosec"),
    "std_msgs/Header": ("builtin_interfaces/Time stamp", "string frame_id"),
    "geometry_msgs/Point": ("float64 x", "float64 y", "float64 z"),
    "geometry_msgs/Vector3": ("float64 x", "float64 y", "float64 z"),
    "geometry_msgs/Quaternion": ("float64 x 0", "float64 y 0", "float64 z 0", "float64 w 1"),
    "geometry_msgs/Pose": ("geometry_msgs/Point position", "geometry_msgs/Quaternion orientation"),
    "geometry_msgs/PoseStamped": ("std_msgs/Header header", "geometry_msgs/Pose pose"),
    "geometry_msgs/Transform": (
        "geometry_msgs/Vector3 translation",
        "geometry_msgs/Quaternion rotation",
    ),
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header",
        "string child_frame_id",
        "geometry_msgs/Transform transform",
    ),
    "tf2_msgs/TFMessage": ("geometry_msgs/TransformStamped[] transforms",),
    "sensor_msgs/LaserScan": (
        "std_msgs/Header header",
        "float32 angle_min",
        "float32 angle_max",
        "float32 angle_increment",
        "float32 time_increment",
        "float32 scan_time",
        "float32 range_min",
        "float32 range_max",
        "float32[] ranges",
        "float32[] intensities",
    ),
    "nav_msgs/MapMetaData": (
        "builtin_interfaces/Time map_load_time",
        "float32 resolution",
        "uint32 width",
        "uint32 height",
        "geometry_msgs/Pose origin",
    ),
    "nav_msgs/OccupancyGrid": (
        "std_msgs/Header header",
        "nav_msgs/MapMetaData info",
        "int8[] data",
    ),
    "nav_msgs/Path": ("std_msgs/Header header", "geometry_msgs/PoseStamped[] poses"),
}

LASER_SCAN: Final = "sensor_msgs/msg/LaserScan"
OCCUPANCY_GRID: Final = "nav_msgs/msg/OccupancyGrid"
PATH: Final = "nav_msgs/msg/Path"
TF_MESSAGE: Final = "tf2_msgs/msg/TFMessage"


def _short(type_name: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` -> ``pkg/Type``."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    if len(parts) == 2:
        return type_name
    raise ValueError(f"type_name must be pkg/msg/Type or pkg/Type, got {type_name!r}")


def _own_text(short: str) -> str:
    try:
        return "".join(f"{line}\n" for line in _FIELDS[short])
    except KeyError:
        raise ValueError(f"no message definition for type {short!r}") from None


def _dependencies(short: str) -> list[str]:
    """The message types ``short``'s fields name, sorted, each once."""
    types = {line.split()[0].removesuffix("[]") for line in _FIELDS[short]}
    return sorted(t for t in types if t not in _PRIMITIVES)


def full_text(type_name: str) -> str:
    """The ``ros2msg`` schema text of ``type_name`` (``sensor_msgs/msg/LaserScan``) with
    every type it depends on (module docstring); ValueError for a type not defined here."""
    seen: set[str] = set()

    def text_of(short: str) -> str:
        text = _own_text(short)
        for dep in _dependencies(short):
            if dep not in seen:
                seen.add(dep)
                text += f"\n{SEPARATOR}\nMSG: {dep}\n{text_of(dep)}"
        return text

    return text_of(_short(type_name))
