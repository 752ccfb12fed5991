"""Pydantic models of the HTTP API (docs/http-api.md), for the OpenAPI schema and replies.

Scan bodies are documented with ``ScanIn`` but validated by ``Scan.from_dict``, the one
validator of scans, so errors read the same from every source.

Strings a route stores or echoes (``unit_id``, a unit state's ``reason``) follow the one
rule of ``mapserver.core.text`` (``UnitId``, ``Reason``), as ``Scan.from_dict`` does.

Numbers in request bodies are strict: an integer is a number, ``true`` is not (pydantic
would otherwise read it as 1.0); booleans are only ``true``/``false``.

These models are the one definition of the wire format: the server's routes answer with
them and ``MapClient`` validates every JSON reply with them (strictly, so a reply that
sends ``"3"`` for a number breaks the contract). They import only pydantic, numpy and the
pure core, so the client loads no server code.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from mapserver.core.geometry import GridGeometry
from mapserver.core.patch import Patch
from mapserver.core.text import MAX_ID_CHARS, text_problem

Number = Annotated[float, Field(strict=True)]  # int or float; not a bool, not a string
Finite = Annotated[float, Field(allow_inf_nan=False, strict=True)]
Flag = Annotated[bool, Field(strict=True)]  # true or false; not 1, not "yes"
MAX_QUERY_ITEMS = 100_000
MAX_UNITS_PER_POST = 1024
MAX_PATH_POINTS = 10_000
MAX_UNIT_ID_CHARS = MAX_ID_CHARS
MAX_REASON_CHARS = 200


def _clean_text(max_chars: int) -> BeforeValidator:
    """A validator holding a string field to ``mapserver.core.text``'s rule (at most
    ``max_chars`` printable characters), run before pydantic's own so that a lone
    surrogate or a megabyte is refused with that rule's reason; a value that is not a
    string is left to the field's type (``Input should be a valid string``)."""

    def check(value: Any) -> Any:
        problem = text_problem(value, max_chars) if isinstance(value, str) else None
        if problem is not None:
            raise PydanticCustomError("clean_text", "{problem}", {"problem": problem})
        return value

    return BeforeValidator(check)


UnitId = Annotated[
    str,
    Field(
        min_length=1,
        max_length=MAX_UNIT_ID_CHARS,
        description=f"1 to {MAX_UNIT_ID_CHARS} printable characters (docs/http-api.md)",
    ),
    _clean_text(MAX_UNIT_ID_CHARS),
]
"""A unit's id: the one rule of ``mapserver.core.text``, as ``Scan.from_dict`` applies it."""
Reason = Annotated[str, Field(max_length=MAX_REASON_CHARS), _clean_text(MAX_REASON_CHARS)]


class _ScanPart(BaseModel):
    """A part of a scan body: no other keys (``scan_fields`` refuses them, 422)."""

    model_config = ConfigDict(extra="forbid")


class PoseIn(_ScanPart):
    x: Number = Field(description="[m] sensor x in the map frame")
    y: Number = Field(description="[m] sensor y in the map frame")
    yaw: Number = Field(ge=-1e6, le=1e6, description="[rad] counter-clockwise from +x")


class PoseStdIn(_ScanPart):
    xy: Number = Field(0.0, ge=0, le=1e3, description="[m] position standard deviation")
    yaw: Number = Field(0.0, ge=0, le=1e3, description="[rad] heading standard deviation")


class ScanIn(_ScanPart):
    """One planar LiDAR scan (docs/http-api.md 2.1); ranges follow REP 117."""

    unit_id: UnitId
    stamp: Number = Field(description="[s] time used for freshness and decay")
    frame: Literal["map"] = "map"
    pose: PoseIn
    pose_std: PoseStdIn | None = None
    angle_min: Number = Field(ge=-1e6, le=1e6, description="[rad] first beam, relative to pose.yaw")
    angle_increment: Number = Field(gt=0, description="[rad] between beams")
    range_min: Number = Field(ge=0, description="[m]")
    range_max: Number = Field(gt=0, description="[m]")
    ranges: list[Number | None] = Field(
        min_length=1,
        description="[m] per beam: a return, > range_max or Infinity for no return, null invalid",
    )


class ScanBatchIn(_ScanPart):
    scans: list[ScanIn] = Field(min_length=1)


class ScanAck(BaseModel):
    """A durable scan: its journal sequence number and a map version that includes it."""

    seq: int = Field(description="the scan's journal sequence number")
    map_version: int = Field(description="a map version that includes the scan")


class ScanBatchAck(BaseModel):
    acks: list[ScanAck]


class ErrorOut(BaseModel):
    detail: str = Field(description="what was wrong: the field and its value")


class Origin(BaseModel):
    x: float
    y: float
    yaw: float


class MapMeta(BaseModel):
    """``GET /v1/map/meta`` (docs/http-api.md 2.2): geometry, version, stamp and settings.

    ``origin`` is the outer corner of cell (0, 0) [m] and its yaw [rad]; ``stamp`` [s] is
    the map's now (null before any scan); ``sensor_model``, ``decay``, ``inflation`` and
    ``thresholds`` are the server's settings as sent.
    """

    resolution: float = Field(description="[m/cell]")
    width: int = Field(description="[cells]")
    height: int = Field(description="[cells]")
    origin: Origin
    frame: str
    stamp: float | None = Field(description="[s] the map's now: the latest scan stamp")
    version: int
    policy: str
    sensor_model: dict
    decay: dict
    inflation: dict
    thresholds: dict

    @property
    def geometry(self) -> GridGeometry:
        """The grid's size, resolution and origin [m] (the origin's yaw is not part of it)."""
        return GridGeometry(self.width, self.height, self.resolution, self.origin.x, self.origin.y)


class GridJson(BaseModel):
    info: MapMeta
    data: list[int] = Field(description="row-major, row 0 at the origin's y")


class AgeGridJson(BaseModel):
    info: MapMeta
    data: list[float | None] = Field(
        description="[s] evidence age per cell, row-major, row 0 at the origin's y; "
        "null where never observed"
    )


Cost = Annotated[int, Field(ge=0, le=255)]


class PatchOut(BaseModel):
    """The current costs of the box (x0, y0) .. (x0 + width - 1, y0 + height - 1) [cells]."""

    x0: int = Field(ge=0)
    y0: int = Field(ge=0)
    width: int = Field(ge=1)
    height: int = Field(ge=1)
    data: list[Cost] = Field(description="row-major Nav2 costs, width * height values")

    @model_validator(mode="after")
    def _fills_its_box(self) -> PatchOut:
        if len(self.data) != self.width * self.height:
            need = self.width * self.height
            raise ValueError(f"data must hold width * height = {need} values, not {len(self.data)}")
        return self

    def to_patch(self) -> Patch:
        """The patch with its costs as a uint8 (height, width) array."""
        data = np.array(self.data, dtype=np.uint8).reshape(self.height, self.width)
        return Patch(self.x0, self.y0, self.width, self.height, data)


class CostmapUpdates(BaseModel):
    """``GET /v1/costmap/updates``: the patches that bring a copy from ``since`` to ``version``;
    ``full`` (and no patches) when the server no longer holds the asked version."""

    version: int
    stamp: float | None = Field(None, description="[s] the map's stamp at that version")
    full: bool = Field(False, description="true: the version is too old, read the full costmap")
    patches: list[PatchOut] = []


class CellsIn(BaseModel):
    points: list[tuple[Finite, Finite]] = Field(
        max_length=MAX_QUERY_ITEMS, description="[[x, y], ...] [m]"
    )
    at: Finite | None = Field(None, description="[s] evaluate decay at this stamp")


class CellOut(BaseModel):
    """One queried point (docs/http-api.md 2.4): x, y [m] as asked; p_occ (None when unknown
    or outside); cost 0..255 (None outside); last_observed [s] and age = at - last_observed
    [s] (None if never observed)."""

    x: float
    y: float
    state: Literal["free", "occupied", "unknown", "outside"]
    p_occ: float | None
    cost: int | None
    last_observed: float | None
    age: float | None


class CellsOut(BaseModel):
    cells: list[CellOut]


class SegmentsIn(BaseModel):
    segments: list[tuple[Finite, Finite, Finite, Finite]] = Field(
        max_length=MAX_QUERY_ITEMS, description="[[x0, y0, x1, y1], ...] [m]"
    )


class SegmentOut(BaseModel):
    """One queried segment (docs/http-api.md 2.5)."""

    max_cost: int | None = Field(description="highest known cost on the segment")
    blocked: bool = Field(description="a lethal or inscribed cell lies on it")
    unknown_fraction: float
    first_blocked: list[float] | None = Field(description="[x, y] of the first blocked cell")


class SegmentsOut(BaseModel):
    segments: list[SegmentOut]


class Health(BaseModel):
    status: Literal["ok"]
    version: int


class _StrictModel(BaseModel):
    """Validated as sent: no extra fields, no coercion (a number is not a string)."""

    model_config = ConfigDict(extra="forbid", strict=True)


class ClockIn(_StrictModel):
    """``PUT /v1/clock``: a simulation declares its clock (docs/map-time.md)."""

    now: float = Field(description="[s] the simulation's time now (its stamps' clock)")


class DeclaredClock(BaseModel):
    now: float = Field(description="[s] the declared clock, as last declared")
    age_s: float = Field(description="[s] of wall time since it was declared")


class ClockOut(BaseModel):
    """What "now" is for the map's clock rule (docs/map-time.md)."""

    reference: Literal["wall", "declared", "simulated"] = Field(
        description="the clock stamps are judged against now"
    )
    now: float = Field(description="[s] that clock's reading now")
    wall: float = Field(description="[s] the server's wall clock, epoch seconds")
    map_stamp: float | None = Field(description="[s] the newest stamp the map accepted")
    declared: DeclaredClock | None = Field(description="the declared simulation clock, if fresh")
    max_lead_s: float = Field(description="[s] how far a stamp may lead `now`")


class PlanIn(BaseModel):
    start: tuple[Finite, Finite] = Field(description="[x, y] [m]")
    goal: tuple[Finite, Finite] = Field(description="[x, y] [m]")
    algorithm: Literal["astar", "dijkstra"] = "astar"
    allow_unknown: Flag = True
    unit_id: UnitId | None = Field(None, description="who asks (for logs)")


class PlanOut(BaseModel):
    """``POST /v1/plan`` (docs/http-api.md 2.6); ``path`` is empty when none was found."""

    found: bool
    path: list[list[float]] = Field(description="[[x, y], ...] cell centres [m]")
    length: float = Field(description="[m] along the path")
    cost: float = Field(description="sum of step length [m] x NavFn cell weight")
    min_clearance: float | None = Field(description="[m] to the nearest lethal cell")
    expanded: int
    planning_ms: float
    map_version: int


class UnitPose(_StrictModel):
    x: Finite = Field(description="[m] unit centre in the map frame")
    y: Finite = Field(description="[m] unit centre in the map frame")
    yaw: Finite = Field(description="[rad] heading, counter-clockwise from +x")


Point = Annotated[list[Finite], Field(min_length=2, max_length=2, description="[x, y] [m]")]


Activity = Literal["moving", "waiting", "frozen", "broken_down", "dwelling", "idle"]
"""What a unit is doing (``UnitState.activity``): driving or turning (``moving``),
standing for traffic, a lane or node another unit holds (``waiting``), standing with no
admissible path or lane (``frozen``), broken down (``broken_down``), at a stop of its
trip (``dwelling``), or parked without a task (``idle``)."""
ACTIVITIES: tuple[str, ...] = Activity.__args__


class UnitState(_StrictModel):
    """A unit as its fleet last published it (a project extension, for the viewer).

    ``activity`` is optional (older fleets do not send it). When it is sent without
    ``frozen``, ``frozen`` follows from it; when both are sent they must agree: ``frozen``
    is true exactly when ``activity`` is ``"frozen"``.
    """

    unit_id: UnitId
    stamp: Finite = Field(description="[s] time of this state, as scan stamps")
    pose: UnitPose
    path: list[Point] = Field(
        default_factory=list,
        max_length=MAX_PATH_POINTS,
        description="the unit's planned path [[x, y], ...] [m], empty when it has none",
    )
    frozen: bool = Field(False, description="no admissible path or lane: the unit waits")
    reason: Reason | None = Field(None, description="why the unit is frozen or waits")
    activity: Activity | None = Field(
        None,
        description="what the unit is doing: moving, waiting (for traffic), frozen, "
        "broken_down, dwelling (at a stop) or idle (no task); null when not reported",
    )

    @model_validator(mode="before")
    @classmethod
    def _frozen_from_activity(cls, data: Any) -> Any:
        """``frozen`` left out beside an ``activity``: it follows from the activity."""
        if isinstance(data, dict) and "frozen" not in data and "activity" in data:
            return {**data, "frozen": data["activity"] == "frozen"}
        return data

    @field_validator("activity")
    @classmethod
    def _activity_agrees_with_frozen(cls, activity: str | None, info: ValidationInfo):
        frozen = info.data.get("frozen")
        if activity is not None and isinstance(frozen, bool) and frozen != (activity == "frozen"):
            message = "must be 'frozen' exactly when frozen is true (frozen is {frozen})"
            raise PydanticCustomError("activity_frozen", message, {"frozen": str(frozen).lower()})
        return activity

    @classmethod
    def of(
        cls,
        unit_id: str,
        stamp: float,
        pose: Any,
        path: Iterable[Iterable[float]] = (),
        frozen: bool | None = None,
        reason: str | None = None,
        activity: str | None = None,
    ) -> UnitState:
        """The state of a unit at ``pose`` (anything with ``x``, ``y`` [m] and ``yaw``
        [rad], e.g. ``Pose2D``) with ``path`` as (x, y) pairs [m]; checked as on the wire.
        ``frozen`` None: ``activity == "frozen"``."""
        fields: dict[str, Any] = {"reason": reason, "activity": activity}
        if frozen is not None or activity is None:
            fields["frozen"] = bool(frozen)
        return cls.model_validate(
            {
                "unit_id": unit_id,
                "stamp": stamp,
                "pose": UnitPose(x=pose.x, y=pose.y, yaw=pose.yaw),
                "path": [list(point) for point in path],
                **fields,
            }
        )


class UnitsIn(_StrictModel):
    units: list[UnitState] = Field(min_length=1, max_length=MAX_UNITS_PER_POST)


class UnitsAck(BaseModel):
    accepted: int = Field(description="unit states taken from this post")
    tracked: int = Field(description="units the server now holds a state for")


class UnitsOut(BaseModel):
    units: list[UnitState] = Field(description="the latest state of each unit, by unit_id")
