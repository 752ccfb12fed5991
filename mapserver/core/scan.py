"""One LiDAR scan (docs/http-api.md 2.1) and its validation.

Range semantics follow ROS REP 117:

- a finite value in ``[range_min, range_max]`` is a *return*: free cells along the beam
  and an occupied endpoint;
- a value ``> range_max`` (including ``+Infinity``) is *no return*: free cells out to the
  clearing range, no endpoint;
- ``null``, NaN, negative values, ``-Infinity`` and values ``< range_min`` are *invalid*
  and dropped: they change nothing.

``Scan.from_dict`` is the one validator for scans from any source (a JSONL file, an HTTP
body, binary or JSON, a journal replayed); every error names the field and the offending
value, quoted bounded. ``unit_id`` follows the rule of identifiers (``mapserver.core.text``:
1 to 64 printable characters).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from mapserver.core.errors import FleetmapError
from mapserver.core.text import MAX_ID_CHARS, quote, text_problem

MAP_FRAME = "map"
DEFAULT_MAX_BEAMS = 16384
FULL_TURN = 2 * math.pi + 1e-9  # [rad] a scan's beams span at most one turn

# Beam classes, as returned by ``classify_ranges``.
BEAM_INVALID = 0
BEAM_RETURN = 1
BEAM_NO_RETURN = 2


MAX_POSE_STD = 1e3
"""Largest ``pose_std.xy`` [m] and ``pose_std.yaw`` [rad] accepted: a deviation beyond
it says nothing about where the sensor was, and its square would overflow the fusion's
pose weighting (1e200 did: one scan could then stop the whole server)."""


MAX_ANGLE = 1e6
"""Largest ``|pose.yaw|`` and ``|angle_min|`` [rad] accepted: unwrapped headings of a
unit that has turned many times are fine, but past this a float64 angle has lost its
meaning (and at 1.7e308 their sum is infinite: the beams have no direction)."""


class ScanError(FleetmapError, ValueError):
    """A scan field is missing or invalid; ``field`` is its dotted path, ``value`` the value."""

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        self.reason = reason
        super().__init__(f"{field}: {reason}, got {quote(value)}")


@dataclass(frozen=True)
class Pose2D:
    """Sensor pose in the map frame: x, y [m], yaw [rad] counter-clockwise from +x."""

    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class PoseStd:
    """Localisation uncertainty: xy [m] position std, yaw [rad] heading std (both >= 0)."""

    xy: float = 0.0
    yaw: float = 0.0


@dataclass(frozen=True, eq=False)
class Scan:
    """A planar LiDAR scan taken at ``pose`` at time ``stamp`` [s].

    Beam i points at ``pose.yaw + angle_min + i * angle_increment`` [rad] and measured
    ``ranges[i]`` [m] (float64 holding float32 values, the binary wire's and the
    journal's precision; NaN where the input was null).
    """

    unit_id: str
    stamp: float
    pose: Pose2D
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    pose_std: PoseStd | None = None
    frame: str = MAP_FRAME

    @property
    def beam_count(self) -> int:
        return int(self.ranges.shape[0])

    def beam_classes(self) -> np.ndarray:
        """Per-beam class (BEAM_RETURN, BEAM_NO_RETURN or BEAM_INVALID) by REP 117."""
        return classify_ranges(self.ranges, self.range_min, self.range_max)

    def digest(self) -> bytes:
        """16 bytes that identify the scan's content (every field, ranges bit for bit
        with every NaN alike): equal digests, equal scans. Tells a retry of an
        acknowledged scan from another scan at the same stamp. Computed once (a scan is
        immutable)."""
        return self._digest

    @cached_property
    def _digest(self) -> bytes:
        header = json.dumps(self.to_dict(with_ranges=False), sort_keys=True).encode()
        ranges = np.where(np.isnan(self.ranges), np.nan, self.ranges).astype("<f8")
        return hashlib.blake2b(header + b"\0" + ranges.tobytes(), digest_size=16).digest()

    def journal_record(self) -> dict[str, Any]:
        """The scan as it is journaled: its validated fields only (unknown fields of the
        posted body are not kept), ``ranges`` as the float64 array."""
        return {**self.to_dict(with_ranges=False), "ranges": self.ranges}

    def to_dict(self, with_ranges: bool = True) -> dict[str, Any]:
        """The docs/http-api.md 2.1 JSON object (NaN ranges as null, no-return as Infinity);
        without ``ranges`` when ``with_ranges`` is False (callers that encode them)."""
        out: dict[str, Any] = {
            "unit_id": self.unit_id,
            "stamp": self.stamp,
            "frame": self.frame,
            "pose": {"x": self.pose.x, "y": self.pose.y, "yaw": self.pose.yaw},
            "angle_min": self.angle_min,
            "angle_increment": self.angle_increment,
            "range_min": self.range_min,
            "range_max": self.range_max,
        }
        if with_ranges:
            out["ranges"] = json_ranges(self.ranges)
        if self.pose_std is not None:
            out["pose_std"] = {"xy": self.pose_std.xy, "yaw": self.pose_std.yaw}
        return out

    @classmethod
    def from_dict(
        cls, data: Any, max_beams: int = DEFAULT_MAX_BEAMS, float32_ranges: bool = True
    ) -> Scan:
        """Validate a docs/http-api.md 2.1 scan object; raises ScanError naming the bad field.

        Ranges are rounded to float32 here, once (the binary wire's precision and what the
        journal stores), so the scan fused live, its digest and the journaled one agree
        and a replay rebuilds the map bit for bit; a range beyond float32 becomes
        +-inf. ``float32_ranges=False`` keeps float64 ranges: only for the records of
        schema-3 journals, which stored float64 and were fused unrounded."""
        if not isinstance(data, Mapping):
            raise ScanError("scan", data, "must be a JSON object")
        unit_id = data.get("unit_id")
        problem = text_problem(unit_id, MAX_ID_CHARS)
        if problem is not None:
            raise ScanError("unit_id", unit_id, problem)
        frame = data.get("frame", MAP_FRAME)
        if frame != MAP_FRAME:
            raise ScanError("frame", frame, f"must be {MAP_FRAME!r}, the only frame")
        stamp = _finite(data, "stamp")
        pose_data = _object(data, "pose")
        pose = Pose2D(
            x=_finite(pose_data, "x", "pose."),
            y=_finite(pose_data, "y", "pose."),
            yaw=_finite(pose_data, "yaw", "pose.", -MAX_ANGLE, maximum=MAX_ANGLE),
        )
        pose_std = None
        if data.get("pose_std") is not None:
            std_data = _object(data, "pose_std")
            pose_std = PoseStd(
                xy=_finite(std_data, "xy", "pose_std.", 0.0, 0.0, MAX_POSE_STD),
                yaw=_finite(std_data, "yaw", "pose_std.", 0.0, 0.0, MAX_POSE_STD),
            )
        angle_min = _finite(data, "angle_min", minimum=-MAX_ANGLE, maximum=MAX_ANGLE)
        angle_increment = _finite(data, "angle_increment")
        if not angle_increment > 0:
            raise ScanError("angle_increment", angle_increment, "must be positive")
        range_min = _finite(data, "range_min", minimum=0.0)
        range_max = _finite(data, "range_max")
        if not range_max > range_min:
            raise ScanError("range_max", range_max, f"must be greater than range_min ({range_min})")
        ranges = _ranges(data.get("ranges"), max_beams)
        if float32_ranges:
            with np.errstate(over="ignore"):
                ranges = ranges.astype(np.float32).astype(np.float64)
        if (len(ranges) - 1) * angle_increment > FULL_TURN:
            raise ScanError(
                "ranges",
                f"<{len(ranges)} beams>",
                f"must fit in one turn at angle_increment {angle_increment} rad "
                f"(at most {int(FULL_TURN / angle_increment) + 1} beams)",
            )
        return cls(
            unit_id=unit_id,
            stamp=stamp,
            pose=pose,
            angle_min=angle_min,
            angle_increment=angle_increment,
            range_min=range_min,
            range_max=range_max,
            ranges=ranges,
            pose_std=pose_std,
            frame=frame,
        )


def json_ranges(ranges: np.ndarray) -> list[float | None]:
    """Ranges [m] as the docs/http-api.md 2.1 JSON list: each a float, NaN (invalid) as
    null (``Infinity``, no return, stays a float: JSON encoders decide how to write it)."""
    return [None if r != r else r for r in ranges.tolist()]


def classify_ranges(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """REP 117 class of each range [m]: BEAM_RETURN, BEAM_NO_RETURN or BEAM_INVALID (uint8)."""
    r = np.asarray(ranges, dtype=np.float64)
    classes = np.full(r.shape, BEAM_INVALID, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        classes[(r >= range_min) & (r <= range_max)] = BEAM_RETURN
        classes[r > range_max] = BEAM_NO_RETURN
    return classes


def _is_number(value: Any) -> bool:
    """A JSON number that fits a float64 (booleans are not numbers; an integer such as
    10**400, which JSON allows, is beyond float range and refused like infinity)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    return isinstance(value, float) or abs(value) <= _LARGEST_FLOAT_INT


_LARGEST_FLOAT_INT = int(np.finfo(np.float64).max)


def _object(data: Mapping, name: str) -> Mapping:
    value = data.get(name)
    if not isinstance(value, Mapping):
        raise ScanError(name, value, "must be a JSON object")
    return value


def _finite(
    data: Mapping,
    name: str,
    prefix: str = "",
    minimum: float | None = None,
    default: float | None = None,
    maximum: float | None = None,
) -> float:
    value = data.get(name, default)
    if not _is_number(value) or not math.isfinite(value):
        raise ScanError(prefix + name, value, "must be a finite number")
    if minimum is not None and value < minimum:
        raise ScanError(prefix + name, value, f"must be >= {minimum}")
    if maximum is not None and value > maximum:
        raise ScanError(prefix + name, value, f"must be <= {maximum:g}")
    return float(value)


def _ranges(value: Any, max_beams: int) -> np.ndarray:
    if not isinstance(value, list | tuple | np.ndarray):
        raise ScanError("ranges", value, "must be a list of numbers or nulls")
    if len(value) == 0:
        raise ScanError("ranges", value, "must hold at least one beam")
    if len(value) > max_beams:
        raise ScanError("ranges", f"<{len(value)} beams>", f"must hold at most {max_beams} beams")
    if isinstance(value, np.ndarray):
        return value.astype(np.float64, copy=True)
    types = set(map(type, value))
    if not types <= _RANGE_TYPES or (int in types and not all(map(_is_range, value))):
        for i, r in enumerate(value):
            if not _is_range(r):
                raise ScanError(f"ranges[{i}]", r, "must be a number (within float range) or null")
    return np.array(value, dtype=np.float64)  # None becomes NaN: invalid, dropped


def _is_range(value: Any) -> bool:
    return value is None or (type(value) in _RANGE_TYPES and _is_number(value))


_RANGE_TYPES = {float, int, type(None)}
