"""A small TF buffer: the frames of a recording's ``/tf`` and ``/tf_static``, looked up
at a stamp, as ROS's tf2 does (docs/recordings.md "Frames").

A transform ``parent -> child`` (``geometry_msgs/TransformStamped``: ``header.frame_id``
is the parent, ``child_frame_id`` the child) gives the child frame's pose in the parent:
a point p in the child is ``R p + t`` in the parent. Frames form a tree: each child has
one parent. ``lookup(target, source, stamp)`` composes the chain from ``source`` up to
the common ancestor and down to ``target`` and returns the pose of ``source`` in
``target`` at ``stamp`` [s].

Dynamic edges keep a bounded history (``history_s`` of recording time) and are
interpolated at the stamp: linear in translation, spherical (slerp) in rotation. tf2
does the same and never extrapolates; here a stamp may lie at most ``tolerance`` [s]
outside an edge's samples (then the nearest sample is used). Static edges hold one
transform forever. Everything is pure numpy; full 3D quaternions are composed and only
the result is projected to the plane (``planar_pose``).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from mapserver.core.errors import FleetmapError


@dataclass(frozen=True)
class Transform:
    """A rigid transform: ``translation`` (x, y, z) [m] and unit quaternion ``rotation``
    (x, y, z, w), as ``geometry_msgs/Transform``."""

    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]

    @staticmethod
    def identity() -> Transform:
        return Transform((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))

    @staticmethod
    def planar(x: float, y: float, yaw: float) -> Transform:
        """The transform of a pose in the plane: (x, y) [m], yaw [rad] about +z."""
        return Transform((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))

    def matrix(self) -> np.ndarray:
        """The 3 x 3 rotation matrix of ``rotation`` (normalised first)."""
        x, y, z, w = _unit(self.rotation)
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )

    def compose(self, other: Transform) -> Transform:
        """``self * other``: ``other`` expressed in ``self``'s parent (a -> b then b -> c
        gives a -> c)."""
        t = np.array(self.translation) + self.matrix() @ np.array(other.translation)
        rotation = _quat_multiply(_unit(self.rotation), _unit(other.rotation))
        return Transform(tuple(t.tolist()), rotation)

    def inverse(self) -> Transform:
        x, y, z, w = _unit(self.rotation)
        conjugate = (-x, -y, -z, w)
        t = -(Transform((0.0, 0.0, 0.0), conjugate).matrix() @ np.array(self.translation))
        return Transform(tuple(t.tolist()), conjugate)


def interpolate(a: Transform, b: Transform, share: float) -> Transform:
    """The transform ``share`` (0 at ``a``, 1 at ``b``) of the way from a to b: linear in
    translation, slerp in rotation (the shorter arc)."""
    ta, tb = np.array(a.translation), np.array(b.translation)
    t = ta + share * (tb - ta)
    return Transform(tuple(t.tolist()), slerp(a.rotation, b.rotation, share))


def slerp(qa: tuple, qb: tuple, share: float) -> tuple[float, float, float, float]:
    """Spherical linear interpolation of unit quaternions (x, y, z, w) along the shorter
    arc (Shoemake, "Animating rotation with quaternion curves", SIGGRAPH 1985)."""
    a, b = np.array(_unit(qa)), np.array(_unit(qb))
    dot = float(a @ b)
    if dot < 0.0:  # q and -q are the same rotation: take the shorter way
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly equal: linear, then normalised, avoids dividing by sin(0)
        q = a + share * (b - a)
    else:
        theta = math.acos(dot)
        q = (math.sin((1 - share) * theta) * a + math.sin(share * theta) * b) / math.sin(theta)
    return _unit(tuple(q.tolist()))


MAX_TILT = math.radians(10.0)
"""[rad] how far a laser's scan plane may tilt from level (either way up) and still be
read as a 2D scan: past it the beams do not sweep the floor plan (cos 10° = 0.985, so a
return at 10 m lands at most 0.15 m short of where a level beam would)."""


@dataclass(frozen=True)
class PlanarPose:
    """A sensor's pose projected to the map plane: x, y [m], yaw [rad] of its x axis,
    and ``mirrored``: the sensor hangs upside down, so its beams sweep clockwise in the
    map (``apply`` reverses them)."""

    x: float
    y: float
    yaw: float
    mirrored: bool


class TiltError(FleetmapError, ValueError):
    """The sensor's scan plane is tilted past MAX_TILT; ``tilt`` [rad] says how far."""

    def __init__(self, tilt: float) -> None:
        self.tilt = tilt
        super().__init__(
            f"the laser's scan plane is tilted {math.degrees(tilt):.1f} degrees from level "
            f"(at most {math.degrees(MAX_TILT):.0f} either way up): it does not scan the "
            "floor plan"
        )


def planar_pose(transform: Transform) -> PlanarPose:
    """Project a sensor's 3D pose to the map plane; TiltError when its z axis is more
    than MAX_TILT from vertical (up or down)."""
    r = transform.matrix()
    up = float(np.clip(r[2, 2], -1.0, 1.0))  # the sensor's z axis, its map z component
    tilt = math.acos(abs(up))
    if tilt > MAX_TILT:
        raise TiltError(tilt)
    x, y, _ = transform.translation
    return PlanarPose(x, y, math.atan2(r[1, 0], r[0, 0]), mirrored=up < 0)


class TfLookupError(FleetmapError, LookupError):
    """A transform cannot be found at a stamp. ``kind``: ``"no_chain"`` (the frames are
    not connected), ``"ahead"`` (a transform later than the stamp has not arrived yet:
    wait), ``"behind"`` (the stamp is older than the history kept). ``parent`` and
    ``child`` name the edge (or the two unconnected frames), ``stamp`` [s] the time."""

    def __init__(self, kind: str, parent: str, child: str, stamp: float, detail: str) -> None:
        self.kind, self.parent, self.child, self.stamp = kind, parent, child, stamp
        super().__init__(detail)


class _Edge:
    """One parent -> child edge: a static transform, or dynamic samples in stamp order."""

    def __init__(self, parent: str, static: bool) -> None:
        self.parent = parent
        self.static = static
        self.stamps: deque[float] = deque()
        self.transforms: deque[Transform] = deque()

    def add(self, stamp: float, transform: Transform, history_s: float) -> None:
        if self.static:
            self.stamps, self.transforms = deque([stamp]), deque([transform])
            return
        if self.stamps and stamp < self.stamps[-1]:  # out of order: insert in place
            i = bisect.bisect_right(self.stamps, stamp)
            self.stamps.insert(i, stamp)
            self.transforms.insert(i, transform)
        else:
            self.stamps.append(stamp)
            self.transforms.append(transform)
        while len(self.stamps) > 2 and self.stamps[1] < self.stamps[-1] - history_s:
            self.stamps.popleft()
            self.transforms.popleft()

    def at(self, child: str, stamp: float, tolerance: float) -> Transform:
        """The edge's transform at ``stamp``, interpolated between its two bracketing
        samples; TfLookupError ``ahead``/``behind`` outside them by more than
        ``tolerance`` [s]."""
        if self.static:
            return self.transforms[0]
        first, last = self.stamps[0], self.stamps[-1]
        if stamp > last:
            if stamp - last > tolerance:
                raise TfLookupError(
                    "ahead", self.parent, child, stamp,
                    f"no transform {self.parent} -> {child} at or after stamp {stamp:.6f} s "
                    f"yet (the latest is at {last:.6f} s)",
                )  # fmt: skip
            return self.transforms[-1]
        if stamp < first:
            if first - stamp > tolerance:
                raise TfLookupError(
                    "behind", self.parent, child, stamp,
                    f"stamp {stamp:.6f} s is older than the kept transforms {self.parent} -> "
                    f"{child} (from {first:.6f} s)",
                )  # fmt: skip
            return self.transforms[0]
        i = bisect.bisect_left(self.stamps, stamp)
        if self.stamps[i] == stamp:
            return self.transforms[i]
        t0, t1 = self.stamps[i - 1], self.stamps[i]
        return interpolate(self.transforms[i - 1], self.transforms[i], (stamp - t0) / (t1 - t0))


class TfBuffer:
    """Transforms by child frame (a tree), dynamic ones kept for ``history_s`` [s] of
    recording time."""

    def __init__(self, history_s: float = 30.0) -> None:
        self.history_s = history_s
        self._edges: dict[str, _Edge] = {}

    def add(
        self, parent: str, child: str, stamp: float, transform: Transform, static: bool
    ) -> None:
        """Record ``parent -> child`` at ``stamp`` [s]; a new parent for a child replaces
        the old edge (tf2 keeps the latest parent too). Leading slashes (ROS 1's
        ``/base_link``) are dropped, as tf2 does."""
        parent, child = strip_frame(parent), strip_frame(child)
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent or edge.static != static:
            edge = self._edges[child] = _Edge(parent, static)
        edge.add(stamp, transform, self.history_s)

    def frames(self) -> set[str]:
        """Every frame named by an edge."""
        return set(self._edges) | {edge.parent for edge in self._edges.values()}

    def roots(self) -> list[str]:
        """The frames with no parent (``map``, or ``odom`` in a bag without SLAM)."""
        return sorted({e.parent for e in self._edges.values() if e.parent not in self._edges})

    def static_root(self, frame: str) -> str:
        """The highest frame reached from ``frame`` through static edges only (a laser's
        ``base_link``); ``frame`` itself when its own edge is not static."""
        frame = strip_frame(frame)
        seen = {frame}
        while (edge := self._edges.get(frame)) is not None and edge.static:
            frame = edge.parent
            if frame in seen:
                break
            seen.add(frame)
        return frame

    def lookup(self, target: str, source: str, stamp: float, tolerance: float = 0.0) -> Transform:
        """The pose of frame ``source`` in frame ``target`` at ``stamp`` [s]; raises
        TfLookupError (no chain, or an edge ahead/behind by more than ``tolerance`` [s])."""
        target, source = strip_frame(target), strip_frame(source)
        up_source = self._path_to_root(source)
        up_target = self._path_to_root(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            raise TfLookupError(
                "no_chain", target, source, stamp,
                f"no chain of transforms from frame {target!r} to frame {source!r} at stamp "
                f"{stamp:.6f} s ({self._describe_roots(target, source)})",
            )  # fmt: skip
        return (
            self._chain(up_target, common, stamp, tolerance)
            .inverse()
            .compose(self._chain(up_source, common, stamp, tolerance))
        )

    def _path_to_root(self, frame: str) -> list[str]:
        path = [frame]
        while (edge := self._edges.get(path[-1])) is not None and edge.parent not in path:
            path.append(edge.parent)
        return path

    def _chain(self, path: list[str], ancestor: str, stamp: float, tolerance: float) -> Transform:
        """The pose of ``path[0]`` in ``ancestor`` (a frame on ``path``)."""
        result = Transform.identity()
        for child in path[: path.index(ancestor)]:
            result = self._edges[child].at(child, stamp, tolerance).compose(result)
        return result

    def _describe_roots(self, target: str, source: str) -> str:
        known = self.frames()
        missing = [f"{f!r} is in no transform" for f in (target, source) if f not in known]
        roots = ", ".join(self.roots()) or "none"
        return "; ".join(missing + [f"the root frames are: {roots}"])


def strip_frame(frame: str) -> str:
    """A frame id without its leading slash (ROS 1's ``/map`` is tf2's ``map``)."""
    return frame.lstrip("/")


def _unit(q: tuple) -> tuple[float, float, float, float]:
    norm = math.sqrt(sum(v * v for v in q))
    if not norm > 0 or not math.isfinite(norm):
        raise ValueError(f"rotation quaternion must be finite and non-zero, got {q!r}")
    x, y, z, w = (v / norm for v in q)
    return (x, y, z, w)


def _quat_multiply(a: tuple, b: tuple) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )
