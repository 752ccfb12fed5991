"""CARMEN logs (``FLASER``, ``RLASER``, ``ROBOTLASER1``; plain or gzip) as a recording.

A CARMEN log is text, one message a line, the message's name first (docs/recordings.md
"CARMEN logs"). The laser messages read here, as CARMEN's own reader parses them
(CARMEN ``src/logtools/readlog.c``: ``carmen_string_to_robot_laser_message_orig`` for
the old ``FLASER``/``RLASER``, ``carmen_string_to_robot_laser_message`` for
``ROBOTLASER1``)::

    FLASER n r_1 .. r_n  x y theta  odom_x odom_y odom_theta  ipc_timestamp host logger_timestamp
    ROBOTLASER1 laser_type start_angle fov angular_resolution maximum_range accuracy
        remission_mode n r_1 .. r_n  m v_1 .. v_m  x y theta  robot_x robot_y robot_theta
        tv rv forward_safety_dist side_safety_dist turn_axis  ipc_timestamp host logger_timestamp

``x y theta`` is the laser's pose in the map frame [m, m, rad] (the corrected pose in a
SLAM-corrected log), used here; the odometry/robot pose is not. The stamp is
``ipc_timestamp`` [s]. Other lines (``PARAM``, ``ODOM``, ``SYNC``, comments) are skipped.

Beam geometry of ``FLASER``/``RLASER``, which carry only the beam count: CARMEN's
``carmen_laser_guess_fov`` / ``carmen_laser_guess_angle_increment`` (readlog.c) give,
with the first beam at -pi/2 (``config.start_angle = -M_PI / 2.0``):

- 181 beams: 1 deg apart, -90 .. +90 deg (fov 180 deg); 180 beams: 1 deg apart,
  -90 .. +89 deg (fov 179 deg, "last beam ignored");
- 361 beams: 0.5 deg apart, -90 .. +90 deg; 360 beams: 0.5 deg, -90 .. +89.5 deg;
- 401/400 beams: 0.25 deg apart, fov 100/99.75 deg; CARMEN still starts them at -90
  deg, which leaves them off-centre, so here they are centred on the heading (GMapping's
  ``CarmenConfiguration::computeSensorMap``, openslam_gmapping ``log/carmenconfiguration.cpp``,
  centres every layout);
- any other count: a fov of 180 deg, ``n - 1`` equal steps, -90 .. +90 deg.

GMapping lays out 180 beams symmetrically instead (-90 .. -1 and +1 .. +90 deg, no beam
straight ahead), which no evenly spaced scan can hold; CARMEN's layout is the sensor's
(a SICK LMS at 1 deg gives 181 readings; CARMEN's 180-beam logs dropped the last) and is
used. The Intel log (``../shared/realdata/README.md``) is such a 180-beam log.

Ranges: CARMEN's old messages take the maximum range as 80 m (readlog.c:
``config.maximum_range = 80.0``); ``ROBOTLASER1`` carries its own. A SICK LMS 2xx
reports no echo with its largest codes, which CARMEN logs hold as 81.83 or 81.91 m; so a
range at or beyond ``min(maximum_range, 81.83 m)`` is no return (``+inf``, REP 117), a
range <= 0 is invalid (NaN), and everything else is a return.
"""

from __future__ import annotations

import gzip
import io
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import IO

import numpy as np

from mapserver.core.scan import Scan
from mapserver.store.recordings.base import Recording, RecordingError
from mapserver.store.recordings.scan_build import build_scan
from mapserver.store.recordings.stamp_order import StampOrder
from mapserver.store.recordings.tf_buffer import PlanarPose

log = logging.getLogger(__name__)

OLD_LASERS = ("FLASER", "RLASER")
ROBOT_LASERS = ("ROBOTLASER1",)
MESSAGE_NAMES = frozenset(
    {"PARAM", "SYNC", "ODOM", "TRUEPOS", "NEFF", "RAWLASER1", "RAWLASER2", "RAWLASER3",
     "RAWLASER4", "ROBOTLASER2", "LASER3", "LASER4", "LASER5", "SONAR", "BUMPER",
     "GPSNMEA", "NMEAGGA", "NMEARMC", "IMU", *OLD_LASERS, *ROBOT_LASERS}
)  # fmt: skip
"""Names a CARMEN log's lines begin with (sniffing a file without a CARMEN suffix)."""

CARMEN_SUFFIXES = (".log", ".clf", ".gfs")
OLD_MAX_RANGE = 80.0  # [m] readlog.c's maximum_range for FLASER/RLASER
REORDER_S = 5.0  # [s] how far back a logged stamp may go and still be put in order
SICK_NO_RETURN = 81.83  # [m] the smallest of the SICK LMS "no echo" codes CARMEN logs hold
GZIP_MAGIC = b"\x1f\x8b"


def open_text(path: Path) -> IO[str]:
    """The file as text, gunzipped when it starts with gzip's magic bytes (whatever its
    suffix)."""
    with path.open("rb") as handle:
        gzipped = handle.read(2) == GZIP_MAGIC
    raw = gzip.open(path, "rb") if gzipped else path.open("rb")
    return io.TextIOWrapper(raw, encoding="ascii", errors="replace")


def is_carmen_log(path: Path) -> bool:
    """A file with a CARMEN suffix (``.log``, ``.clf``, ``.gfs``, each optionally
    ``.gz``), or whose first lines are CARMEN messages or comments."""
    if not path.is_file():
        return False
    suffixes = [s.lower() for s in path.suffixes[-2:]]
    if suffixes and suffixes[-1] == ".gz":
        suffixes.pop()
    if suffixes and suffixes[-1] in CARMEN_SUFFIXES:
        return True
    try:
        with open_text(path) as handle:
            words = [line.split(maxsplit=1)[0] for line in _head(handle, 20) if line.strip()]
    except (OSError, EOFError, gzip.BadGzipFile):
        return False
    return bool(words) and all(w.startswith("#") or w in MESSAGE_NAMES for w in words)


def _head(handle: IO[str], count: int) -> list[str]:
    lines = []
    for line in handle:
        lines.append(line)
        if len(lines) == count:
            break
    return lines


def _message_name(line: str) -> str:
    """A line's first word (its message's name), "" for a blank line."""
    words = line.split(None, 1)
    return words[0] if words else ""


def _stamp_field(line: str) -> float | None:
    """A laser line's ipc_timestamp (None when it is not a number: the full parse names it)."""
    words = line.rsplit(None, 3)
    try:
        return float(words[-3])
    except (IndexError, ValueError):
        return None


def carmen_beam_layout(count: int) -> tuple[float, float]:
    """(angle_min, angle_increment) [rad] of an old FLASER/RLASER with ``count`` beams,
    as CARMEN guesses them (module docstring)."""
    if count in (180, 181):
        return -math.pi / 2, math.pi / 180
    if count in (360, 361):
        return -math.pi / 2, math.pi / 360
    if count in (400, 401):
        increment = math.pi / 720
        return -(count - 1) * increment / 2, increment
    return -math.pi / 2, math.pi / max(count - 1, 1)


@dataclass(frozen=True)
class LaserLine:
    """One laser message: its geometry, ranges [m] and the laser's pose and stamp."""

    stamp: float
    pose: PlanarPose
    angle_min: float
    angle_increment: float
    range_max: float
    ranges: np.ndarray


class _Fields:
    """The tokens of one line, read in order; errors name file:line, message and field."""

    def __init__(self, where: str, name: str, tokens: list[str]) -> None:
        self.where, self.name, self.tokens, self.at = where, name, tokens, 1

    def _fail(self, field: str, problem: str) -> RecordingError:
        return RecordingError(f"{self.where}: {self.name} field {field!r}: {problem}")

    def number(self, field: str) -> float:
        if self.at >= len(self.tokens):
            raise self._fail(field, f"missing (the line ends after {len(self.tokens)} fields)")
        token = self.tokens[self.at]
        self.at += 1
        try:
            value = float(token)
        except ValueError:
            raise self._fail(field, f"expected a number, got {token!r}") from None
        if not math.isfinite(value):
            raise self._fail(field, f"expected a finite number, got {token!r}")
        return value

    def count(self, field: str) -> int:
        value = self.number(field)
        if value != int(value) or value < 0:
            raise self._fail(field, f"expected a count >= 0, got {value!r}")
        return int(value)

    def numbers(self, field: str, n: int) -> np.ndarray:
        chunk = self.tokens[self.at : self.at + n]
        if len(chunk) < n:
            raise self._fail(f"{field}[{len(chunk)}]", f"missing ({n} expected)")
        try:
            values = np.array(chunk, dtype=np.float64)
        except ValueError:
            for i, token in enumerate(chunk):
                try:
                    float(token)
                except ValueError:
                    raise self._fail(f"{field}[{i}]", f"expected a number, got {token!r}") from None
            raise
        self.at += n
        return values

    def pose(self, prefix: str) -> PlanarPose:
        x, y, theta = (self.number(f"{prefix}{axis}") for axis in ("x", "y", "theta"))
        return PlanarPose(x, y, theta, mirrored=False)


def parse_old_laser(fields: _Fields) -> LaserLine:
    """FLASER / RLASER (module docstring): beams by CARMEN's guess, max range 80 m."""
    count = fields.count("num_readings")
    ranges = fields.numbers("ranges", count)
    pose = fields.pose("laser_")
    fields.pose("odom_")  # the odometry pose: read for its format, not used
    stamp = fields.number("ipc_timestamp")
    angle_min, increment = carmen_beam_layout(count)
    return LaserLine(stamp, pose, angle_min, increment, OLD_MAX_RANGE, ranges)


def parse_robot_laser(fields: _Fields) -> LaserLine:
    """ROBOTLASER1 (module docstring): the message's own start angle, resolution, range."""
    fields.number("laser_type")
    angle_min = fields.number("start_angle")
    fields.number("fov")
    increment = fields.number("angular_resolution")
    range_max = fields.number("maximum_range")
    fields.number("accuracy")
    fields.number("remission_mode")
    ranges = fields.numbers("ranges", fields.count("num_readings"))
    fields.numbers("remissions", fields.count("num_remissions"))
    pose = fields.pose("laser_pose_")
    fields.pose("robot_pose_")
    for name in ("tv", "rv", "forward_safety_dist", "side_safety_dist", "turn_axis"):
        fields.number(name)
    stamp = fields.number("ipc_timestamp")
    if not range_max > 0:
        raise fields._fail("maximum_range", f"must be > 0 m, got {range_max!r}")
    return LaserLine(stamp, pose, angle_min, increment, range_max, ranges)


PARSERS = {"FLASER": parse_old_laser, "RLASER": parse_old_laser, "ROBOTLASER1": parse_robot_laser}


def rep117_ranges(ranges: np.ndarray, range_max: float) -> np.ndarray:
    """CARMEN ranges [m] as REP 117 ones: at or past ``min(range_max, SICK_NO_RETURN)``
    -> +inf (no return), <= 0 -> NaN (invalid)."""
    out = ranges.astype(np.float64, copy=True)
    out[out >= min(range_max, SICK_NO_RETURN)] = math.inf
    out[out <= 0] = math.nan
    return out


class CarmenLogRecording(Recording):
    """A CARMEN log's laser scans, streamed line by line. When the log holds
    ``ROBOTLASER1`` lines those are read (newer logs write them beside the old
    messages for the same readings), else ``FLASER`` and ``RLASER``. ``start``/``end``
    count from the first laser message's ipc_timestamp. Scans are put in stamp order
    within REORDER_S; one stamped earlier still is skipped, counted in a warning."""

    def __iter__(self) -> Iterator[Scan]:
        order: StampOrder[Scan] = StampOrder(REORDER_S)
        for scan in self._scans():
            yield from order.push(scan.stamp, scan)
        yield from order.flush()
        if order.late:
            log.warning(
                "%s: skipped %d scans stamped more than %g s before a scan logged above them",
                self.path, order.late, REORDER_S,
            )  # fmt: skip

    def _scans(self) -> Iterator[Scan]:
        """The scans in the log's order, within ``start``/``end``."""
        kinds = self._kinds
        unit_id = self.unit_id()
        first: float | None = None
        with open_text(self.path) as handle:
            for number, line in enumerate(handle, start=1):
                name = _message_name(line)
                if name not in kinds:
                    continue
                where = f"{self.path}:{number}"
                laser = PARSERS[name](_Fields(where, name, line.split()))
                first = laser.stamp if first is None else first
                offset = laser.stamp - first
                if self.options.end is not None and offset > self.options.end + REORDER_S:
                    break
                if not self.options.within(offset):
                    continue
                yield build_scan(
                    where, unit_id, laser.stamp, laser.pose, laser.angle_min,
                    laser.angle_increment, 0.0, laser.range_max,
                    rep117_ranges(laser.ranges, laser.range_max),
                )  # fmt: skip

    @cached_property
    def _survey(self) -> dict[str, int]:
        """How many lines of each laser message the log holds; sets ``_span_s``, the
        seconds between their first and last ipc_timestamp (one quick pass; the stamp is
        the third field from the end of every laser message)."""
        counts = dict.fromkeys(PARSERS, 0)
        first = last = None
        with open_text(self.path) as handle:
            for line in handle:
                name = _message_name(line)
                if name in counts:
                    counts[name] += 1
                    stamp = _stamp_field(line)
                    first = stamp if first is None else first
                    last = stamp if stamp is not None else last
        self._span_s = None if first is None or last is None else max(last - first, 0.0)
        return counts

    @property
    def _kinds(self) -> tuple[str, ...]:
        survey = self._survey
        if not any(survey.values()):
            raise RecordingError(
                f"{self.path}: a CARMEN log without laser messages (FLASER, RLASER or ROBOTLASER1)"
            )
        return ROBOT_LASERS if survey["ROBOTLASER1"] else OLD_LASERS

    def scan_count(self) -> int | None:
        return sum(self._survey[kind] for kind in self._kinds)

    def duration(self) -> float | None:
        return self._span_s if self._survey else None

    def describe(self) -> str:
        kinds = "/".join(k for k in self._kinds if self._survey[k])
        return f"{self.path}: CARMEN log, {self.scan_count()} {kinds} scans, laser poses as logged"
