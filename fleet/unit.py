"""A kinematic differential-drive unit that follows a path of waypoints.

Pure kinematics (no physics engine): the simulation puts the unit's body where ``step``
says. The unit is a unicycle (a differential drive seen from its centre): it moves along
its heading at speed ``v`` [m/s] and turns at rate ``w`` [rad/s], with

- ``0 <= v <= max_speed`` (no reversing) and ``|v' - v| <= max_accel * dt`` per step;
- ``|w| <= max_turn_rate``.

Controller: turn, then drive (as grid-aisle robots do). Each step it turns toward the
current waypoint as far as the turn rate allows; it drives only while its heading is
within ``align_tolerance`` of the waypoint's bearing. A waypoint where the path turns by
more than ``align_tolerance`` (and the last one) is a stop: the speed follows the
discrete braking profile that lands exactly there (``stopping_speed``: from ``k a dt``
the speed drops by ``a dt`` per step and the last step covers the remainder); the unit
stops on it and turns in place toward the next one. A waypoint on a
straight run is passed without slowing. Motion per step: turn by ``w dt``, then move
``v dt`` along the mean heading of the step.

``halt()`` is a bumper stop: the path is dropped and the unit stands still at once
(the one deceleration not bounded by ``max_accel``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from fleet.shapes import wrap_angle
from mapserver.scan import Pose2D

WAYPOINT_TOLERANCE_M = 0.01
"""[m] a stop waypoint is reached when the unit is this close to it."""


@dataclass(frozen=True)
class DriveLimits:
    """A drive unit's body and motion limits.

    radius: [m] footprint radius (a cylinder); height: [m] of the body.
    max_speed: [m/s]; max_accel: [m/s^2] for speeding up and slowing down;
    max_turn_rate: [rad/s]; align_tolerance: [rad] largest heading error it drives with.
    """

    radius: float = 0.3
    height: float = 0.4
    max_speed: float = 1.5
    max_accel: float = 1.0
    max_turn_rate: float = 1.5
    align_tolerance: float = 0.1

    def __post_init__(self) -> None:
        for name in ("radius", "height", "max_speed", "max_accel", "max_turn_rate"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"{name} must be positive and finite, got {value!r}")
        if not 0 < self.align_tolerance < math.pi / 2:
            raise ValueError(
                f"align_tolerance must be in (0, pi/2) rad, got {self.align_tolerance!r}"
            )


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
            raise ValueError(f"unit_id must be a non-empty string, got {unit_id!r}")
        self.unit_id = unit_id
        self.limits = limits or DriveLimits()
        self.pose = pose
        self.speed = 0.0  # [m/s]
        self.turn_rate = 0.0  # [rad/s]
        self._path: list[tuple[float, float]] = []

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

    def halt(self) -> None:
        """Bumper stop: drop the path and stand still now."""
        self._path = []
        self.speed = 0.0
        self.turn_rate = 0.0

    def step(self, dt: float) -> Pose2D:
        """Advance ``dt`` [s] under the controller (module docstring); returns the new pose."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        lim = self.limits
        x, y, yaw = self.pose.x, self.pose.y, self.pose.yaw
        self._drop_reached(x, y)
        target_speed, turn, stop, aligned = 0.0, 0.0, True, False
        if self._path:
            tx, ty = self._path[0]
            error = wrap_angle(math.atan2(ty - y, tx - x) - yaw)
            turn = max(-lim.max_turn_rate, min(lim.max_turn_rate, error / dt))
            stop = self._is_stop(0)
            aligned = abs(error) <= lim.align_tolerance
            if aligned:
                heading = yaw + turn * dt / 2
                target_speed = min(lim.max_speed, self._stopping_speed(x, y, heading, stop, dt))
        dv = lim.max_accel * dt
        speed = max(0.0, min(target_speed, self.speed + dv), self.speed - dv)
        heading = yaw + turn * dt / 2
        distance = speed * dt
        if aligned and stop:  # arrive on a stop, not past it (the closest approach)
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
        self._drop_passed(x, y, stop)
        return self.pose

    # ------------------------------------------------------------------ internals
    def _is_stop(self, i: int) -> bool:
        """True when the unit must stop at waypoint i: the last, or a turn of the path
        sharper than ``align_tolerance``."""
        if i + 1 >= len(self._path):
            return True
        (ax, ay), (bx, by) = self._path[i], self._path[i + 1]
        px, py = self._path[i - 1] if i > 0 else (self.pose.x, self.pose.y)
        if (ax, ay) == (px, py) or (ax, ay) == (bx, by):
            return True
        turn = wrap_angle(math.atan2(by - ay, bx - ax) - math.atan2(ay - py, ax - px))
        return abs(turn) > self.limits.align_tolerance

    def _ahead(self, x: float, y: float, heading: float) -> float:
        """[m] how far along ``heading`` from (x, y) the target waypoint's closest approach is."""
        tx, ty = self._path[0]
        return (tx - x) * math.cos(heading) + (ty - y) * math.sin(heading)

    def _stopping_speed(self, x: float, y: float, heading: float, stop: bool, dt: float) -> float:
        """[m/s] the speed that still stops at the next stop waypoint: the target itself
        (``stop``; where driving along ``heading`` stops), else the first stop along the
        path."""
        if stop:
            return stopping_speed(max(self._ahead(x, y, heading), 0.0), self.limits.max_accel, dt)
        distance, px, py = 0.0, x, y
        for i, (wx, wy) in enumerate(self._path):
            distance += math.hypot(wx - px, wy - py)
            if self._is_stop(i):
                break
            px, py = wx, wy
        return stopping_speed(distance, self.limits.max_accel, dt)

    def _drop_reached(self, x: float, y: float) -> None:
        """Drop leading waypoints within ``WAYPOINT_TOLERANCE_M`` of (x, y)."""
        while self._path and math.hypot(self._path[0][0] - x, self._path[0][1] - y) <= (
            WAYPOINT_TOLERANCE_M
        ):
            self._path.pop(0)

    def _drop_passed(self, x0: float, y0: float, stop: bool) -> None:
        """After moving from (x0, y0): drop the target if reached, or if it is not a
        ``stop`` and was passed."""
        if not self._path:
            return
        tx, ty = self._path[0]
        x, y = self.pose.x, self.pose.y
        if math.hypot(tx - x, ty - y) <= WAYPOINT_TOLERANCE_M:
            self._path.pop(0)
        elif not stop:
            # passed: the target now lies behind the unit's travel direction
            if (tx - x) * (x - x0) + (ty - y) * (y - y0) < 0:
                self._path.pop(0)
