"""The Foxglove JSON schemas of the replay's channels (``schema_encoding = "jsonschema"``).

Foxglove identifies a channel's meaning by its schema *name* (``foxglove.LaserScan``,
``foxglove.Grid``, ``foxglove.SceneUpdate``, ``foxglove.PosesInFrame``, ``foxglove.Log``,
``foxglove.FrameTransforms``) and
reads the schema *text* for field types: notably ``contentEncoding: base64`` marks byte
fields (``Grid.data``), which it decodes to bytes.

The schemas are built here from their parts (time, Vector3, Pose, Color, ...) and match the
published Foxglove JSON schemas (``@foxglove/schemas`` 2.1.0, ``jsonschema`` export; generated
from github.com/foxglove/foxglove-sdk, MIT): the same titles, properties in the same order,
types, enums, ``required`` lists and ``contentEncoding``, with the ``description``
annotations left out (they change nothing a reader does). Nothing here is invented: a
message built for these schemas is a valid Foxglove message.
"""

from __future__ import annotations

from typing import Any, Final

Schema = dict[str, Any]

_NUMBER: Final[Schema] = {"type": "number"}
_STRING: Final[Schema] = {"type": "string"}
_BOOLEAN: Final[Schema] = {"type": "boolean"}
_UINT: Final[Schema] = {"type": "integer", "minimum": 0}
_NSEC: Final[Schema] = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
_BASE64: Final[Schema] = {"type": "string", "contentEncoding": "base64"}


def _record(title: str, **properties: Schema) -> Schema:
    """A Foxglove message type: every property is required, as in the published schemas."""
    required = list(properties)
    return {"title": title, "type": "object", "properties": properties, "required": required}


def _array(items: Schema) -> Schema:
    return {"type": "array", "items": items}


def _enum(title: str, *names: str) -> Schema:
    """A Foxglove enum: ``names[i]`` has the value ``i``."""
    return {"title": title, "oneOf": [{"title": n, "const": i} for i, n in enumerate(names)]}


TIME: Final[Schema] = {
    "type": "object",
    "title": "time",
    "properties": {"sec": _UINT, "nsec": _NSEC},
}
DURATION: Final[Schema] = {
    "type": "object",
    "title": "duration",
    "properties": {"sec": {"type": "integer"}, "nsec": _NSEC},
}

_VECTOR2 = _record("foxglove.Vector2", x=_NUMBER, y=_NUMBER)
_VECTOR3 = _record("foxglove.Vector3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
_POINT3 = _record("foxglove.Point3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
_QUATERNION = _record("foxglove.Quaternion", x=_NUMBER, y=_NUMBER, z=_NUMBER, w=_NUMBER)
_POSE = _record("foxglove.Pose", position=_VECTOR3, orientation=_QUATERNION)
_COLOR = _record("foxglove.Color", r=_NUMBER, g=_NUMBER, b=_NUMBER, a=_NUMBER)
_KEY_VALUE = _record("foxglove.KeyValuePair", key=_STRING, value=_STRING)

NUMERIC_TYPES: Final = (
    "UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64"
)  # fmt: skip
LOG_LEVELS: Final = ("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL")

_PACKED_FIELD = _record(
    "foxglove.PackedElementField",
    name=_STRING,
    offset=_UINT,
    type=_enum("foxglove.NumericType", *NUMERIC_TYPES),
)

LASER_SCAN: Final = _record(
    "foxglove.LaserScan",
    timestamp=TIME,
    frame_id=_STRING,
    pose=_POSE,
    start_angle=_NUMBER,
    end_angle=_NUMBER,
    ranges=_array(_NUMBER),
    intensities=_array(_NUMBER),
)

GRID: Final = _record(
    "foxglove.Grid",
    timestamp=TIME,
    frame_id=_STRING,
    pose=_POSE,
    column_count=_UINT,
    cell_size=_VECTOR2,
    row_stride=_UINT,
    cell_stride=_UINT,
    fields=_array(_PACKED_FIELD),
    data=_BASE64,
)

POSES_IN_FRAME: Final = _record(
    "foxglove.PosesInFrame", timestamp=TIME, frame_id=_STRING, poses=_array(_POSE)
)

LOG: Final = _record(
    "foxglove.Log",
    timestamp=TIME,
    level=_enum("foxglove.LogLevel", *LOG_LEVELS),
    message=_STRING,
    name=_STRING,
    file=_STRING,
    line=_UINT,
)

_SCENE_ENTITY = _record(
    "foxglove.SceneEntity",
    timestamp=TIME,
    frame_id=_STRING,
    id=_STRING,
    lifetime=DURATION,
    frame_locked=_BOOLEAN,
    metadata=_array(_KEY_VALUE),
    arrows=_array(
        _record(
            "foxglove.ArrowPrimitive",
            pose=_POSE,
            shaft_length=_NUMBER,
            shaft_diameter=_NUMBER,
            head_length=_NUMBER,
            head_diameter=_NUMBER,
            color=_COLOR,
        )
    ),
    cubes=_array(_record("foxglove.CubePrimitive", pose=_POSE, size=_VECTOR3, color=_COLOR)),
    spheres=_array(_record("foxglove.SpherePrimitive", pose=_POSE, size=_VECTOR3, color=_COLOR)),
    cylinders=_array(
        _record(
            "foxglove.CylinderPrimitive",
            pose=_POSE,
            size=_VECTOR3,
            bottom_scale=_NUMBER,
            top_scale=_NUMBER,
            color=_COLOR,
        )
    ),
    lines=_array(
        _record(
            "foxglove.LinePrimitive",
            type=_enum("foxglove.LineType", "LINE_STRIP", "LINE_LOOP", "LINE_LIST"),
            pose=_POSE,
            thickness=_NUMBER,
            scale_invariant=_BOOLEAN,
            points=_array(_POINT3),
            color=_COLOR,
            colors=_array(_COLOR),
            indices=_array(_UINT),
        )
    ),
    triangles=_array(
        _record(
            "foxglove.TriangleListPrimitive",
            pose=_POSE,
            points=_array(_POINT3),
            color=_COLOR,
            colors=_array(_COLOR),
            indices=_array(_UINT),
        )
    ),
    texts=_array(
        _record(
            "foxglove.TextPrimitive",
            pose=_POSE,
            billboard=_BOOLEAN,
            font_size=_NUMBER,
            scale_invariant=_BOOLEAN,
            color=_COLOR,
            text=_STRING,
        )
    ),
    models=_array(
        _record(
            "foxglove.ModelPrimitive",
            pose=_POSE,
            scale=_VECTOR3,
            color=_COLOR,
            override_color=_BOOLEAN,
            url=_STRING,
            media_type=_STRING,
            data=_BASE64,
        )
    ),
)

SCENE_UPDATE: Final = _record(
    "foxglove.SceneUpdate",
    deletions=_array(
        _record(
            "foxglove.SceneEntityDeletion",
            timestamp=TIME,
            type=_enum("foxglove.SceneEntityDeletionType", "MATCHING_ID", "ALL"),
            id=_STRING,
        )
    ),
    entities=_array(_SCENE_ENTITY),
)

FRAME_TRANSFORMS: Final = _record(
    "foxglove.FrameTransforms",
    transforms=_array(
        _record(
            "foxglove.FrameTransform",
            timestamp=TIME,
            parent_frame_id=_STRING,
            child_frame_id=_STRING,
            translation=_VECTOR3,
            rotation=_QUATERNION,
        )
    ),
)

SCHEMAS: Final[dict[str, Schema]] = {
    s["title"]: s for s in (LASER_SCAN, GRID, SCENE_UPDATE, POSES_IN_FRAME, LOG, FRAME_TRANSFORMS)
}
"""The six schemas by name (``foxglove.LaserScan``, ...)."""
