"""A kinematic differential-drive unit that follows a path of waypoints.

Pure kinematics (no physics engine): the simulation puts the unit's body where ``step``
says. The unit is a unicycle (a differential drive seen from its centre): it moves along
its heading at speed ``v`` [m/s] and turns at rate ``w`` [rad/s], with

- ``0 <= v <= max_speed`` (no reversing) and ``|v' - v| <= max_accel * dt`` per step;
- ``|w| <= max_turn_rate``.

Controller: a regulated pure pursuit, after Macenski, Singh, Martin and Gines,
*Regulated Pure Pursuit for Robot Path Tracking* (Autonomous Robots 47, 2023; Nav2's
``RegulatedPurePursuitController``), with stops where a path demands them:

- *Tracking.* The carrot is the point ``lookahead`` [m] along the path from the unit,
  ``lookahead = clamp(v * lookahead_time, min_lookahead, max_lookahead)``, never past
  the next stop. The unit steers on the arc through it, curvature
  ``kappa = 2 sin(e) / D`` (``e`` the heading error to the carrot, ``D`` its distance),
  turning at ``w = v kappa``.
- *Regulation.* The speed is the least of ``max_speed``, the curvature limit
  ``max_turn_rate / |kappa|`` (so the arc fits the turn rate) and the braking profile
  that lands on the next stop.
- *Rotate to heading.* With ``|e| > rotate_to_heading`` [rad] the unit slows to a stand
  and turns in place (as RPP's ``use_rotate_to_heading``); a standing unit turns in
  place until ``|e| <= align_tolerance`` before it drives off.
- *Corners.* A waypoint where the path turns by more than ``CORNER_RAD`` holds the
  carrot until the unit has passed it (pure pursuit would cut inside the corner, toward
  what the path goes around), and the speed there is held so the swing outside it stays
  within ``CORNER_ERROR_M``.
- *Stops.* A waypoint where the path turns by more than ``rotate_to_heading``, and the
  last one, is a stop: within ``lookahead`` of it the unit drives straight at it, turning
  toward it and driving only while its heading is within ``align_tolerance``, its speed
  on the discrete braking profile that lands exactly there (``stopping_speed``: from
  ``k a dt`` the speed drops by ``a dt`` per step and the last step covers the remainder).
  Waypoints on a straight run or a gentle bend are passed without stopping.

Motion per step: turn by ``w dt``, then move ``v dt`` along the mean heading of the step.

``halt()`` is a bumper stop: the path is dropped and the unit stands still at once
(the one deceleration not bounded by ``max_accel``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from fleet.shapes import wrap_angle
from mapserver.core.errors import FieldError
from mapserver.core.scan import Pose2D

WAYPOINT_TOLERANCE_M = 0.01
"""[m] a stop waypoint is reached when the unit is this close to it."""
CORNER_RAD = 0.15
"""[rad] a waypoint where the path turns by more than this is a corner: the carrot stops
there until the unit has passed it, so the unit does not cut inside it."""
CORNER_ERROR_M = 0.05
"""[m] how far outside a corner the unit may swing: its speed there is held to
``max_turn_rate * CORNER_ERROR_M / (1 - cos(turn))``."""


@dataclass(frozen=True)
class DriveLimits:
    """A drive unit's body, motion limits and path-tracking settings.

    radius: [m] footprint radius (a cylinder); height: [m] of the body.
    max_speed: [m/s]; max_accel: [m/s^2] for speeding up and slowing down;
    max_turn_rate: [rad/s]; align_tolerance: [rad] largest heading error it drives with
    on the final approach to a stop; rotate_to_heading: [rad] heading error to the
    carrot above which it turns in place, and the sharpest path turn it drives through
    (Nav2 RPP's ``rotate_to_heading_min_angle``); lookahead_time [s], min_lookahead and
    max_lookahead [m]: the carrot's distance (module docstring).
    """

    radius: float = 0.3
    height: float = 0.4
    max_speed: float = 1.5
    max_accel: float = 1.0
    max_turn_rate: float = 1.5
    align_tolerance: float = 0.1
    rotate_to_heading: float = 1.0  # [rad] = 57 deg: a 90 deg corner cut in two is driven
    lookahead_time: float = 1.0
    min_lookahead: float = 0.4
    max_lookahead: float = 1.2

    def __post_init__(self) -> None:
        for name in (
            "radius", "height", "max_speed", "max_accel", "max_turn_rate",
            "lookahead_time", "min_lookahead", "max_lookahead",
        ):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise FieldError(name, value, "must be positive and finite")
        if not 0 < self.align_tolerance < math.pi / 2:
            raise FieldError("align_tolerance", self.align_tolerance, "must be in (0, pi/2) rad")
        if not self.align_tolerance <= self.rotate_to_heading < math.pi:
            raise FieldError(
                "rotate_to_heading", self.rotate_to_heading, "must be in [align_tolerance, pi) rad"
            )
        if self.max_lookahead < self.min_lookahead:
            raise FieldError(
                "max_lookahead",
                self.max_lookahead,
                f"must be >= min_lookahead ({self.min_lookahead!r} m)",
            )

    def lookahead(self, speed: float) -> float:
        """[m] the carrot's distance at ``speed`` [m/s]."""
        return min(self.max_lookahead, max(self.min_lookahead, speed * self.lookahead_time))


def corner_speed(limits: DriveLimits, turn: float) -> float:
    """[m/s] the speed the unit passes a corner turning by ``turn`` [rad] at: max_speed on
    a bend up to ``CORNER_RAD``, else held so that at full turn rate it swings at most
    ``CORNER_ERROR_M`` outside the corner."""
    if turn <= CORNER_RAD:
        return limits.max_speed
    return min(limits.max_speed, limits.max_turn_rate * CORNER_ERROR_M / (1.0 - math.cos(turn)))


def stopping_speed(distance: float, accel: float, dt: float) -> float:
    """[m/s] the highest speed from which braking by ``accel * dt`` [m/s] per step of
    ``dt`` [s] covers exactly ``distance`` [m] and then stands still (module docstring).

    From speed ``k a dt`` the steps run at ``k, k - 1, ..., k - n`` (``n = floor(k)``)
    times ``a dt`` and cover ``a dt^2 (n + 1)(k - n / 2)``; this inverts that.
    """
    unit = accel * dt
    u = max(distance, 0.0) / (unit * dt)  # the distance in units of a dt^2
    n = math.floor(math.sqrt(0.25 + 2 * u) - 0.5)
    return unit * (u / (n + 1) + n / 2)


class DriveUnit:
    """A unit ``unit_id`` at ``pose`` with ``limits``, standing still with no path."""

    def __init__(self, unit_id: str, pose: Pose2D, limits: DriveLimits | None = None) -> None:
        if not isinstance(unit_id, str) or not unit_id.strip():
            raise FieldError("unit_id", unit_id, "must be a non-empty string")
        self.unit_id = unit_id
        self.limits = limits or DriveLimits()
        self.pose = pose
        self.speed = 0.0  # [m/s]
        self.turn_rate = 0.0  # [rad/s]
        self._path: list[tuple[float, float]] = []
        self._anchor = (pose.x, pose.y)  # where the path's current segment starts [m]

    @property
    def path(self) -> tuple[tuple[float, float], ...]:
        """The waypoints [m] still ahead, the current target first."""
        return tuple(self._path)

    @property
    def idle(self) -> bool:
        """True when the unit has no path and stands still."""
        return not self._path and self.speed == 0.0

    def follow(self, path: Iterable[Sequence[float]]) -> None:
        """Drive through ``path`` [(x, y) m], replacing any path it had."""
        points = []
        for i, point in enumerate(path):
            values = tuple(point)
            if len(values) != 2 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in values
            ):
                raise ValueError(f"path[{i}] must be two finite numbers (x, y) [m], got {point!r}")
            points.append((float(values[0]), float(values[1])))
        self._path = points
        self._anchor = (self.pose.x, self.pose.y)

    def halt(self) -> None:
        """Bumper stop: drop the path and stand still now."""
        self._path = []
        self.speed = 0.0
        self.turn_rate = 0.0

    def step(self, dt: float) -> Pose2D:
        """Advance ``dt`` [s] under the controller (module docstring); returns the new pose."""
        if not (math.isfinite(dt) and dt > 0):
            raise FieldError("dt", dt, "must be a positive number of seconds")
        lim = self.limits
        x, y, yaw = self.pose.x, self.pose.y, self.pose.yaw
        self._drop_reached(x, y)
        dv = lim.max_accel * dt
        target_speed, turn, final, aligned = 0.0, 0.0, False, False
        if self._path:
            stop_at, to_stop, corner_at, to_corner, pass_speed = self._ahead_on_path(x, y)
            sx, sy = self._path[stop_at]  # the last stretch is driven straight at the stop:
            to_stop = min(to_stop, math.hypot(sx - x, sy - y))  # brake for the shorter way
            lookahead = lim.lookahead(self.speed)
            final = stop_at == 0 and to_stop <= lookahead
            if final:  # straight at the stop
                tx, ty = self._path[0]
                error = wrap_angle(math.atan2(ty - y, tx - x) - yaw)
                turn = _clamp(error / dt, lim.max_turn_rate)
                aligned = abs(error) <= lim.align_tolerance
                if aligned:
                    heading = yaw + turn * dt / 2
                    braking = stopping_speed(
                        max(self._ahead(x, y, heading), 0.0), lim.max_accel, dt
                    )
                    target_speed = min(lim.max_speed, braking)
            else:
                cx, cy = self._carrot(x, y, min(lookahead, to_corner), corner_at)
                error = wrap_angle(math.atan2(cy - y, cx - x) - yaw)
                standing = self.speed == 0.0
                if abs(error) > (lim.align_tolerance if standing else lim.rotate_to_heading):
                    if self.speed <= dv:  # slow to a stand, then rotate to heading
                        turn = _clamp(error / dt, lim.max_turn_rate)
                else:
                    curvature = 2.0 * math.sin(error) / max(math.hypot(cx - x, cy - y), 1e-9)
                    target_speed = min(
                        lim.max_speed,
                        stopping_speed(to_stop, lim.max_accel, dt),
                        math.sqrt(pass_speed**2 + 2 * lim.max_accel * to_corner),
                        lim.max_turn_rate / abs(curvature) if curvature else math.inf,
                    )
                    speed = max(0.0, min(target_speed, self.speed + dv), self.speed - dv)
                    turn = _clamp(speed * curvature, lim.max_turn_rate)
        speed = max(0.0, min(target_speed, self.speed + dv), self.speed - dv)
        heading = yaw + turn * dt / 2
        distance = speed * dt
        if aligned and final:  # arrive on the stop, not past it (the closest approach)
            ahead = self._ahead(x, y, heading)
            if ahead > 0:
                distance = min(distance, ahead)
        self.pose = Pose2D(
            x + distance * math.cos(heading),
            y + distance * math.sin(heading),
            wrap_angle(yaw + turn * dt),
        )
        self.speed = distance / dt
        self.turn_rate = turn
        self._drop_passed(x, y)
        return self.pose

    # ------------------------------------------------------------------ internals
    def _turn_at(self, i: int) -> float:
        """[rad] how much the path turns at waypoint i (pi at the last, or where two
        waypoints coincide)."""
        if i + 1 >= len(self._path):
            return math.pi
        (ax, ay), (bx, by) = self._path[i], self._path[i + 1]
        px, py = self._path[i - 1] if i > 0 else self._anchor
        if (ax, ay) == (px, py) or (ax, ay) == (bx, by):
            return math.pi
        return abs(wrap_angle(math.atan2(by - ay, bx - ax) - math.atan2(ay - py, ax - px)))

    def _is_stop(self, i: int) -> bool:
        """True when the unit must stop at waypoint i: the last, or a turn of the path
        sharper than ``rotate_to_heading``."""
        return self._turn_at(i) > self.limits.rotate_to_heading

    def _ahead_on_path(self, x: float, y: float) -> tuple[int, float, int, float, float]:
        """One walk along the path from (x, y): the first stop waypoint (index, distance
        [m]) and the first corner (``CORNER_RAD``) up to it (index, distance [m], the
        speed [m/s] the unit may pass it at; the stop itself, at 0, when there is none)."""
        corner: tuple[int, float, float] | None = None
        distance, px, py = 0.0, x, y
        for i, (wx, wy) in enumerate(self._path):
            distance += math.hypot(wx - px, wy - py)
            turn = self._turn_at(i)
            if turn > self.limits.rotate_to_heading:  # a stop (the last one always is)
                return (i, distance, *(corner or (i, distance, 0.0)))
            if corner is None and turn > CORNER_RAD:
                corner = (i, distance, corner_speed(self.limits, turn))
            px, py = wx, wy
        raise AssertionError("the last waypoint is always a stop")

    def _carrot(self, x: float, y: float, reach: float, stop_at: int) -> tuple[float, float]:
        """The point ``reach`` [m] along the path from (x, y), no farther than waypoint
        ``stop_at``."""
        px, py = x, y
        for wx, wy in self._path[: stop_at + 1]:
            step = math.hypot(wx - px, wy - py)
            if step >= reach and step > 0:
                f = reach / step
                return px + f * (wx - px), py + f * (wy - py)
            reach -= step
            px, py = wx, wy
        return px, py

    def _ahead(self, x: float, y: float, heading: float) -> float:
        """[m] how far along ``heading`` from (x, y) the target waypoint's closest approach is."""
        tx, ty = self._path[0]
        return (tx - x) * math.cos(heading) + (ty - y) * math.sin(heading)

    def _pop(self) -> None:
        self._anchor = self._path.pop(0)

    def _drop_reached(self, x: float, y: float) -> None:
        """Drop leading waypoints within ``WAYPOINT_TOLERANCE_M`` of (x, y)."""
        while self._path and math.hypot(self._path[0][0] - x, self._path[0][1] - y) <= (
            WAYPOINT_TOLERANCE_M
        ):
            self._pop()

    def _drop_passed(self, x0: float, y0: float) -> None:
        """After moving from (x0, y0): drop the target if reached, or if it is not a stop
        and the unit is past it (along its outgoing segment, or behind the travel)."""
        if not self._path:
            return
        tx, ty = self._path[0]
        x, y = self.pose.x, self.pose.y
        if math.hypot(tx - x, ty - y) <= WAYPOINT_TOLERANCE_M:
            self._pop()
        elif not self._is_stop(0):
            nx, ny = self._path[1]
            beyond = (x - tx) * (nx - tx) + (y - ty) * (ny - ty) >= 0
            behind = (tx - x) * (x - x0) + (ty - y) * (y - y0) < 0
            if beyond or behind:
                self._pop()


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))
