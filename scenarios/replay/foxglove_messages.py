"""Foxglove messages (JSON-encoded, for the schemas of ``foxglove_schemas``) from a run's
record: scans, grids, frame transforms, scene entities, planned paths and log lines.

Everything is in the one ``map`` frame (x right, y up, z up from the floor) [m, rad];
timestamps are sim time as ``{"sec", "nsec"}``.

LaserScan ranges are strict JSON numbers (a reader such as Foxglove parses with
``JSON.parse``, which has no Infinity or NaN), mapped so that REP 117 classes survive and
Foxglove draws only returns:

=====================  ==================  ====================================
range (float32)        written as          read back (``decode_ranges``)
=====================  ==================  ====================================
finite                 the same float32    the same value
+inf (no return)       +FLT_MAX (3.4e38)   +inf
NaN, -inf (invalid)    -FLT_MAX            NaN
=====================  ==================  ====================================

+FLT_MAX is above any ``range_max`` (REP 117: no return) and -FLT_MAX below any
``range_min`` (invalid), so a reader that knows only REP 117 classes every beam right; in
Foxglove such points lie 1e38 m away, far beyond the camera. -inf comes back as NaN: both
are invalid beams. ``range_min``, ``range_max``, ``angle_increment`` and ``pose_std``, which
``foxglove.LaserScan`` has no field for, travel in the channel's metadata (see
``replay_mcap``).
"""

from __future__ import annotations

import base64
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import numpy as np

from mapserver.core.geometry import GridGeometry
from scenarios.replay.costmap_palette import COSTMAP_RGBA
from scenarios.replay.foxglove_schemas import LOG_LEVELS, NUMERIC_TYPES
from scenarios.run.record import ObjectState, PlanSample, ScanSample, UnitSample

Message = dict[str, Any]
Rgba = tuple[float, float, float, float]

FRAME_ID: Final = "map"
NS_PER_S: Final = 1_000_000_000
FLT_MAX: Final = float(np.finfo(np.float32).max)

INFO: Final = LOG_LEVELS.index("INFO")
WARNING: Final = LOG_LEVELS.index("WARNING")
ERROR: Final = LOG_LEVELS.index("ERROR")

_GRID_TYPES: Final = {
    np.dtype(np.uint8): NUMERIC_TYPES.index("UINT8"),
    np.dtype(np.int8): NUMERIC_TYPES.index("INT8"),
}

UNIT_COLORS: Final[dict[str, Rgba]] = {
    "frozen": (0.84, 0.15, 0.16, 1.0),
    "moving": (0.17, 0.63, 0.17, 1.0),
    "idle": (0.45, 0.55, 0.70, 1.0),
}
OBJECT_COLORS: Final[dict[str, Rgba]] = {
    "pod": (0.60, 0.42, 0.25, 1.0),
    "rack": (0.60, 0.42, 0.25, 1.0),
    "tote": (1.00, 0.50, 0.05, 1.0),
    "person": (0.58, 0.40, 0.74, 1.0),
    "wall": (0.55, 0.55, 0.55, 1.0),
}
OTHER_OBJECT_COLOR: Final[Rgba] = (0.30, 0.70, 0.70, 1.0)
_WHITE: Final[Rgba] = (1.0, 1.0, 1.0, 1.0)


# ------------------------------------------------------------------------------ time
def stamp_ns(stamp: float) -> int:
    """Sim time [s] as integer nanoseconds; ValueError for a negative or non-finite stamp."""
    if not (math.isfinite(stamp) and stamp >= 0):
        raise ValueError(f"stamp must be a finite, non-negative sim time [s], got {stamp!r}")
    return round(stamp * NS_PER_S)


def foxglove_time(ns: int) -> dict[str, int]:
    """Integer nanoseconds as a Foxglove ``time`` object."""
    return {"sec": ns // NS_PER_S, "nsec": ns % NS_PER_S}


def seconds_of(time: Mapping[str, int]) -> float:
    """A Foxglove ``time`` object as seconds (one rounding: ns / 1e9)."""
    return (int(time["sec"]) * NS_PER_S + int(time["nsec"])) / NS_PER_S


# ------------------------------------------------------------------------------ poses
def pose(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> Message:
    """A ``foxglove.Pose`` at (x, y, z) [m] turned ``yaw`` [rad] about +z."""
    return {
        "position": {"x": float(x), "y": float(y), "z": float(z)},
        "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)},
    }


def planar_pose(message: Mapping[str, Any]) -> tuple[float, float, float]:
    """(x, y [m], yaw [rad] in (-pi, pi]) of a ``foxglove.Pose`` turned about +z only."""
    position, q = message["position"], message["orientation"]
    yaw = math.remainder(2.0 * math.atan2(float(q["z"]), float(q["w"])), math.tau)
    return float(position["x"]), float(position["y"]), yaw


def _color(rgba: Rgba) -> dict[str, float]:
    r, g, b, a = rgba
    return {"r": r, "g": g, "b": b, "a": a}


# ------------------------------------------------------------------------------ scans
def encode_ranges(ranges: np.ndarray) -> np.ndarray:
    """Ranges [m] as float32 with +inf -> +FLT_MAX and NaN, -inf -> -FLT_MAX (module doc)."""
    r = np.array(ranges, dtype=np.float32)
    r[np.isposinf(r)] = FLT_MAX
    r[np.isnan(r) | np.isneginf(r)] = -FLT_MAX
    return r


def decode_ranges(values: Sequence[float] | np.ndarray) -> np.ndarray:
    """The inverse of ``encode_ranges``: float64 ranges [m], +inf no return, NaN invalid."""
    r = np.asarray(values, dtype=np.float32).astype(np.float64)
    r[r >= FLT_MAX] = math.inf
    r[r <= -FLT_MAX] = math.nan
    return r


def laser_scan(scan: ScanSample) -> Message:
    """A ``foxglove.LaserScan`` at the scan's pose: beam i at bearing ``start_angle + i *
    angle_increment`` [rad] from the pose's heading; ranges encoded by ``encode_ranges``."""
    ranges = encode_ranges(scan.ranges)
    return {
        "timestamp": foxglove_time(stamp_ns(scan.stamp)),
        "frame_id": FRAME_ID,
        "pose": pose(scan.x, scan.y, yaw=scan.yaw),
        "start_angle": float(scan.angle_min),
        "end_angle": float(scan.angle_min + (len(ranges) - 1) * scan.angle_increment),
        "ranges": ranges,
        "intensities": [],
    }


# ------------------------------------------------------------------------------ grids
def grid(stamp: float, geometry: GridGeometry, planes: Mapping[str, np.ndarray]) -> Message:
    """A ``foxglove.Grid`` of uint8 or int8 fields, one per plane (name -> (height, width)
    values), packed cell by cell in the order given (a cell is one byte per field); row 0
    at the origin's y (as Foxglove's y-major rows from ``pose``), cells ``resolution`` [m]."""
    arrays = []
    for name, values in planes.items():
        arr = np.asarray(values)
        if arr.shape != geometry.shape:
            raise ValueError(f"{name} grid has shape {arr.shape}, the map is {geometry.shape}")
        if arr.dtype not in _GRID_TYPES:
            raise TypeError(f"{name} grid must be uint8 or int8, got dtype {arr.dtype}")
        arrays.append(arr)
    cells = np.stack([a.view(np.uint8) for a in arrays], axis=-1)  # (height, width, fields)
    return {
        "timestamp": foxglove_time(stamp_ns(stamp)),
        "frame_id": FRAME_ID,
        "pose": pose(geometry.origin_x, geometry.origin_y),
        "column_count": geometry.width,
        "cell_size": {"x": geometry.resolution, "y": geometry.resolution},
        "row_stride": geometry.width * len(arrays),
        "cell_stride": len(arrays),
        "fields": [
            {"name": name, "offset": i, "type": _GRID_TYPES[a.dtype]}
            for i, (name, a) in enumerate(zip(planes, arrays, strict=True))
        ],
        "data": base64.b64encode(np.ascontiguousarray(cells).tobytes()).decode("ascii"),
    }


def grid_values(message: Mapping[str, Any], name: str | None = None) -> np.ndarray:
    """The (rows, column_count) values of field ``name`` (or of the only field, when
    ``name`` is None) of a ``foxglove.Grid`` made by ``grid``, in its dtype (uint8 or
    int8); ValueError for another layout, type or a missing field."""
    fields = message["fields"]
    if name is None and len(fields) != 1:
        raise ValueError(f"a grid of {len(fields)} fields needs a field name")
    matching = [f for f in fields if name is None or f["name"] == name]
    if not matching:
        raise ValueError(f"the grid has no field {name!r}")
    (field,) = matching
    dtypes = {index: dtype for dtype, index in _GRID_TYPES.items()}
    stride = int(message["cell_stride"])
    if field["type"] not in dtypes or stride != len(fields) or not 0 <= field["offset"] < stride:
        raise ValueError(f"not a one-byte-per-field grid: field {field!r}")
    width = int(message["column_count"])
    if message["row_stride"] != width * stride:
        raise ValueError(f"row_stride {message['row_stride']!r} is not {width} x {stride}")
    raw = np.frombuffer(base64.b64decode(message["data"], validate=True), np.uint8)
    cells = raw.reshape(-1, width, stride)[..., field["offset"]]
    return np.ascontiguousarray(cells).view(dtypes[field["type"]])


def costmap_grid(stamp: float, geometry: GridGeometry, costs: np.ndarray) -> Message:
    """The costmap as a ``foxglove.Grid`` of five uint8 fields: ``red``, ``green``,
    ``blue``, ``alpha`` (the cost's colour, ``costmap_palette``: Foxglove draws them as
    they are) and ``cost`` (the Nav2 cost value itself)."""
    rgba = COSTMAP_RGBA[np.asarray(costs, dtype=np.uint8)]
    planes = {name: rgba[..., i] for i, name in enumerate(("red", "green", "blue", "alpha"))}
    return grid(stamp, geometry, {**planes, "cost": costs})


# ------------------------------------------------------------------------------ frames
def base_link(unit_id: str) -> str:
    """The frame of a unit's body: ``<unit>/base_link``."""
    return f"{unit_id}/base_link"


def frame_transforms(samples: Iterable[UnitSample]) -> Message:
    """A ``foxglove.FrameTransforms`` with each unit's pose as the transform ``map`` ->
    ``<unit>/base_link`` (translation x, y [m], z 0; rotation ``yaw`` [rad] about +z)."""
    transforms = []
    for sample in samples:
        p = pose(sample.x, sample.y, yaw=sample.yaw)
        transforms.append(
            {
                "timestamp": foxglove_time(stamp_ns(sample.stamp)),
                "parent_frame_id": FRAME_ID,
                "child_frame_id": base_link(sample.unit_id),
                "translation": p["position"],
                "rotation": p["orientation"],
            }
        )
    return {"transforms": transforms}


# ------------------------------------------------------------------------------ scene
def unit_entity_id(unit_id: str) -> str:
    return f"unit/{unit_id}"


def object_entity_id(object_id: str) -> str:
    return f"object/{object_id}"


def unit_state(sample: UnitSample) -> str:
    """``frozen``, ``moving`` or ``idle``: the key of UNIT_COLORS."""
    return "frozen" if sample.frozen else "moving" if sample.moving else "idle"


def unit_entity(sample: UnitSample, radius: float, height: float) -> Message:
    """A drive unit as a cylinder (radius, height [m]) coloured by state, an arrow along its
    heading and its id as a label."""
    ns = stamp_ns(sample.stamp)
    color = UNIT_COLORS[unit_state(sample)]
    arrow = {
        "pose": pose(sample.x, sample.y, height + 0.01, sample.yaw),
        "shaft_length": 0.6 * radius,
        "shaft_diameter": 0.15 * radius,
        "head_length": 0.4 * radius,
        "head_diameter": 0.4 * radius,
        "color": _color(_WHITE),
    }
    label = {
        "pose": pose(sample.x, sample.y, height + 0.3),
        "billboard": True,
        "font_size": 14.0,
        "scale_invariant": True,
        "color": _color(_WHITE),
        "text": sample.unit_id,
    }
    metadata = {"unit": sample.unit_id, "state": unit_state(sample), "task": sample.task or ""}
    return _entity(
        ns,
        unit_entity_id(sample.unit_id),
        metadata,
        cylinders=[_cylinder(sample.x, sample.y, 0.0, 2 * radius, 2 * radius, height, color)],
        arrows=[arrow],
        texts=[label],
    )


def object_entity(stamp: float, obj: ObjectState) -> Message:
    """A world object as a cube (a box) or a cylinder (``round``) of its footprint and
    height [m], standing on the floor, coloured by kind (OBJECT_COLORS)."""
    color = OBJECT_COLORS.get(obj.kind, OTHER_OBJECT_COLOR)
    metadata = {"object": obj.object_id, "kind": obj.kind}
    ns, entity_id = stamp_ns(stamp), object_entity_id(obj.object_id)
    if obj.round:
        shape = _cylinder(obj.x, obj.y, obj.yaw, obj.size_x, obj.size_y, obj.height, color)
        return _entity(ns, entity_id, metadata, cylinders=[shape])
    cube = {
        "pose": pose(obj.x, obj.y, obj.height / 2, obj.yaw),
        "size": {"x": obj.size_x, "y": obj.size_y, "z": obj.height},
        "color": _color(color),
    }
    return _entity(ns, entity_id, metadata, cubes=[cube])


def deletion(stamp: float, entity_id: str) -> Message:
    """A ``foxglove.SceneEntityDeletion`` of the entity ``entity_id`` (MATCHING_ID)."""
    return {"timestamp": foxglove_time(stamp_ns(stamp)), "type": 0, "id": entity_id}


def scene_update(entities: Iterable[Message], deletions: Iterable[Message] = ()) -> Message:
    """A ``foxglove.SceneUpdate``: deletions are applied before the entities are added."""
    return {"deletions": list(deletions), "entities": list(entities)}


def _cylinder(x: float, y: float, yaw: float, sx: float, sy: float, h: float, c: Rgba) -> Message:
    return {
        "pose": pose(x, y, h / 2, yaw),
        "size": {"x": sx, "y": sy, "z": h},
        "bottom_scale": 1.0,
        "top_scale": 1.0,
        "color": _color(c),
    }


_PRIMITIVE_KINDS: Final = (
    "arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"
)  # fmt: skip


def _entity(ns: int, entity_id: str, metadata: Mapping[str, str], **primitives: list) -> Message:
    """A ``foxglove.SceneEntity`` that lives until replaced or deleted; all primitive lists
    the schema requires, empty unless given."""
    entity: Message = {
        "timestamp": foxglove_time(ns),
        "frame_id": FRAME_ID,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": k, "value": v} for k, v in metadata.items()],
    }
    for kind in _PRIMITIVE_KINDS:
        entity[kind] = primitives.get(kind, [])
    return entity


# ------------------------------------------------------------------------------ plans
def poses_in_frame(plan: PlanSample) -> Message:
    """A ``foxglove.PosesInFrame`` of the plan's path, each pose heading to the next point
    (the last keeps the heading before it); an empty path clears the drawn one."""
    points = plan.path
    headings = [
        math.atan2(y1 - y0, x1 - x0) for (x0, y0), (x1, y1) in zip(points, points[1:], strict=False)
    ]
    if points:
        headings.append(headings[-1] if headings else 0.0)
    return {
        "timestamp": foxglove_time(stamp_ns(plan.stamp)),
        "frame_id": FRAME_ID,
        "poses": [pose(x, y, yaw=h) for (x, y), h in zip(points, headings, strict=True)],
    }


# ------------------------------------------------------------------------------ log
def log(stamp: float, level: int, name: str, message: str) -> Message:
    """A ``foxglove.Log`` line from ``name`` (a unit id, or ``scenario``) at ``level``."""
    return {
        "timestamp": foxglove_time(stamp_ns(stamp)),
        "level": level,
        "message": message,
        "name": name,
        "file": "",
        "line": 0,
    }
