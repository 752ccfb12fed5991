"""An analytic planar world of axis-aligned boxes, a LiDAR ray caster and a warehouse.

Pure numpy, no physics engine: the exact answer that the PyBullet LiDAR and the map
server are checked against, and a fast source of realistic scans for benchmarks and
sample files.

- ``BoxWorld``: the union of axis-aligned rectangles ``[xmin, ymin, xmax, ymax]`` [m]
  in the ``map`` frame. ``cast`` shoots planar rays with the slab test (Kay and Kajiya,
  *Ray tracing complex scenes*, SIGGRAPH 1986; Williams et al., *An efficient and robust
  ray-box intersection algorithm*, JGT 2005), vectorised over all beams x all boxes in
  bounded chunks.
- ``warehouse_layout``: perimeter walls, back-to-back rack rows split by cross-aisles,
  a staging area with loose pallets, and the grid of lane centre lines units drive on.
- ``sample_scans``: ``mapserver.core.scan.Scan`` objects from units patrolling those lanes,
  with REP 117 ranges (no return beyond ``range_max`` is ``+inf``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mapserver.core.errors import FieldError
from mapserver.core.scan import Pose2D, Scan

CHUNK_ELEMENTS = 1 << 18
"""Beams x boxes (or points x boxes) per vectorised chunk: ~2 MB per float64 temporary."""


class BoxWorld:
    """A static planar world: the union of axis-aligned boxes (walls, racks, pallets).

    boxes: (n, 4) array of ``[xmin, ymin, xmax, ymax]`` [m] with ``xmin < xmax`` and
        ``ymin < ymax``; boxes may touch or overlap; n may be 0 (an empty world).
    """

    def __init__(self, boxes: np.ndarray) -> None:
        b = np.array(boxes, dtype=np.float64)
        if b.ndim != 2 or b.shape[1] != 4:
            raise ValueError(f"boxes must have shape (n, 4), got {b.shape}")
        bad = np.flatnonzero(
            ~(np.isfinite(b).all(axis=1) & (b[:, 0] < b[:, 2]) & (b[:, 1] < b[:, 3]))
        )
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"boxes[{i}] must be finite with xmin < xmax and ymin < ymax, got {b[i].tolist()}"
            )
        b.setflags(write=False)
        self.boxes = b

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    def distance(self, x: float | np.ndarray, y: float | np.ndarray) -> np.ndarray:
        """Euclidean distance [m] from each point (x, y) [m] to the nearest box.

        0 inside or on a box, ``inf`` in an empty world. x and y broadcast; the result has
        their broadcast shape (a 0-d array for scalars).
        """
        px, py = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        out = np.full(px.shape, np.inf)
        flat_x, flat_y, flat_out = px.ravel(), py.ravel(), out.reshape(-1)
        step = max(1, CHUNK_ELEMENTS // max(1, len(self)))
        for start in range(0, flat_x.size if len(self) else 0, step):
            sl = slice(start, start + step)
            flat_out[sl] = _gaps(flat_x[sl], flat_y[sl], self.boxes).min(axis=1)
        return out

    def is_free(
        self, x: float | np.ndarray, y: float | np.ndarray, clearance: float = 0.0
    ) -> np.ndarray:
        """True where point (x, y) [m] is farther than ``clearance`` [m] from every box.

        Boolean array of the broadcast shape of x and y (0-d for scalars, so ``if
        world.is_free(x, y, 0.5):`` works). The world has no outer bound of its own: walls
        are boxes like any other.
        """
        if not clearance >= 0:
            raise FieldError("clearance", clearance, "must be >= 0 m")
        return self.distance(x, y) > clearance

    def cast(self, x: float, y: float, angles: np.ndarray, range_max: float) -> np.ndarray:
        """Ranges [m] of planar rays from sensor (x, y) [m] along world-frame ``angles`` [rad].

        Each ray returns the distance to the first box it meets, or ``+inf`` when no box
        lies within ``range_max`` [m] (REP 117 "no return"). A hit at exactly
        ``range_max`` is a return. A sensor inside or on a box reads 0 on every beam that
        starts into it. Rays grazing a box along an edge miss it. The result has the
        shape of ``angles``.
        """
        if not range_max > 0:
            raise FieldError("range_max", range_max, "must be a positive number of metres")
        a = np.asarray(angles, dtype=np.float64)
        out = np.full(a.size, np.inf)
        near = self.boxes[_gaps(np.array([x]), np.array([y]), self.boxes)[0] <= range_max]
        if len(near) == 0:
            return out.reshape(a.shape)
        flat = a.ravel()
        with np.errstate(divide="ignore"):
            inv_dx = 1.0 / np.cos(flat)
            inv_dy = 1.0 / np.sin(flat)
        # Slab offsets of each box from the sensor, (1, n).
        x0, x1 = near[None, :, 0] - x, near[None, :, 2] - x
        y0, y1 = near[None, :, 1] - y, near[None, :, 3] - y
        step = max(1, CHUNK_ELEMENTS // len(near))
        for start in range(0, flat.size, step):
            sl = slice(start, start + step)
            ix, iy = inv_dx[sl, None], inv_dy[sl, None]
            # 0 * inf = NaN marks a ray parallel to a slab and on its boundary: fmin/fmax
            # skip the NaN, which turns that slab into a miss (a grazing ray).
            with np.errstate(invalid="ignore"):
                tx0, tx1 = x0 * ix, x1 * ix
                ty0, ty1 = y0 * iy, y1 * iy
                t_near = np.maximum(np.fmin(tx0, tx1), np.fmin(ty0, ty1))
                t_far = np.minimum(np.fmax(tx0, tx1), np.fmax(ty0, ty1))
            hit = (t_near <= t_far) & (t_far >= 0.0)
            out[sl] = np.where(hit, np.maximum(t_near, 0.0), np.inf).min(axis=1)
        out[out > range_max] = np.inf
        return out.reshape(a.shape)


def _gaps(px: np.ndarray, py: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(m, n) distances [m] from each of m points to each of n boxes (0 inside)."""
    gx = np.maximum(np.maximum(boxes[None, :, 0] - px[:, None], px[:, None] - boxes[None, :, 2]), 0)
    gy = np.maximum(np.maximum(boxes[None, :, 1] - py[:, None], py[:, None] - boxes[None, :, 3]), 0)
    return np.hypot(gx, gy)


@dataclass(frozen=True)
class Warehouse:
    """A warehouse floor: its geometry and the lane grid that units drive on.

    world: walls, racks and pallets.
    width, height: [m] the floor ``[0, width] x [0, height]``; the walls lie inside it.
    lane_x: [m] ascending x of the vertical lanes' centre lines (the two perimeter aisles
        and every cross-aisle).
    lane_y: [m] ascending y of the horizontal lanes' centre lines (the staging aisle, the
        aisles between rack rows, the top aisle).
    kinds: what each box of ``world`` is, in order: ``"wall"``, ``"rack"`` or ``"pallet"``
        (empty when unknown).

    Every crossing of a ``lane_x`` and a ``lane_y`` line is a junction, and the straight
    run between two neighbouring junctions keeps at least half an aisle of clearance from
    every box.
    """

    world: BoxWorld
    width: float
    height: float
    lane_x: tuple[float, ...]
    lane_y: tuple[float, ...]
    kinds: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kinds and len(self.kinds) != len(self.world):
            raise ValueError(
                f"kinds must name each of the {len(self.world)} boxes, got {len(self.kinds)} kinds"
            )


# Perimeter wall thickness [m]. Odd on purpose: it offsets every wall and rack face from
# the cell boundaries of the usual grid resolutions (0.025, 0.05, 0.1 m), where the cell
# a hit lands in would hinge on floating-point rounding rather than on the map.
WALL_M = 0.33
PALLET_BAND_M = 3.0  # depth of the pallet band along the bottom wall, below the staging aisle [m]
PALLET_M = (1.2, 0.8)  # EUR pallet footprint, x by y [m]
PALLET_SLOT_M = 2.0  # spacing of pallet slots along the staging area [m]
PALLET_FILL = 0.4  # probability that a pallet slot is occupied


def warehouse_layout(
    width_m: float = 100.0,
    height_m: float = 50.0,
    seed: int = 0,
    *,
    aisle_m: float = 3.0,
    rack_depth_m: float = 1.0,
    cross_aisle_every_m: float = 20.0,
) -> Warehouse:
    """A rack warehouse on the floor ``[0, width_m] x [0, height_m]`` [m].

    Layout, bottom to top: a ``WALL_M`` wall; a ``PALLET_BAND_M`` band of loose pallets;
    the ``aisle_m`` staging aisle; rows of racks running along x,
    each row two ``rack_depth_m`` racks back to back, rows ``aisle_m`` apart; a top aisle
    at least ``aisle_m`` wide; the top wall. Along x: a wall, an ``aisle_m`` perimeter
    aisle, rack blocks cut by ``aisle_m`` cross-aisles about every ``cross_aisle_every_m``,
    a perimeter aisle, a wall. Racks and walls are fixed; ``seed`` places the pallets.
    """
    for name, value in (
        ("width_m", width_m),
        ("height_m", height_m),
        ("aisle_m", aisle_m),
        ("rack_depth_m", rack_depth_m),
        ("cross_aisle_every_m", cross_aisle_every_m),
    ):
        if not (math.isfinite(value) and value > 0):
            raise FieldError(name, value, "must be a positive number of metres")
    rng = np.random.default_rng(seed)
    row_m = 2 * rack_depth_m
    y_first = WALL_M + PALLET_BAND_M + aisle_m  # bottom of the first rack row
    rows = math.floor((height_m - WALL_M - y_first) / (row_m + aisle_m))
    x_left, x_right = WALL_M + aisle_m, width_m - WALL_M - aisle_m  # the racks' x span
    span = x_right - x_left
    blocks = max(1, round(span / cross_aisle_every_m))
    block_m = (span - (blocks - 1) * aisle_m) / blocks
    if rows < 1 or block_m < rack_depth_m:
        raise ValueError(
            f"a {width_m} m x {height_m} m floor is too small for one rack row with "
            f"{aisle_m} m aisles and {rack_depth_m} m racks"
        )

    boxes = [
        (0.0, 0.0, width_m, WALL_M),
        (0.0, height_m - WALL_M, width_m, height_m),
        (0.0, 0.0, WALL_M, height_m),
        (width_m - WALL_M, 0.0, width_m, height_m),
    ]
    block_x0 = [x_left + k * (block_m + aisle_m) for k in range(blocks)]
    row_y0 = [y_first + k * (row_m + aisle_m) for k in range(rows)]
    for y0 in row_y0:
        for x0 in block_x0:
            boxes.append((x0, y0, x0 + block_m, y0 + rack_depth_m))
            boxes.append((x0, y0 + rack_depth_m, x0 + block_m, y0 + row_m))
    racks = len(boxes) - 4

    # Pallets: 0.3 m clear of the wall and of the staging aisle.
    px, py = PALLET_M
    band_y0, band_y1 = WALL_M + 0.3, WALL_M + PALLET_BAND_M - 0.3
    for x0 in np.arange(WALL_M + 0.3, width_m - WALL_M - 0.3 - px, PALLET_SLOT_M):
        if rng.random() < PALLET_FILL:
            y0 = rng.uniform(band_y0, band_y1 - py)
            boxes.append((float(x0), y0, float(x0) + px, y0 + py))

    lane_x = (
        WALL_M + aisle_m / 2,
        *(x0 - aisle_m / 2 for x0 in block_x0[1:]),
        width_m - WALL_M - aisle_m / 2,
    )
    lane_y = (y_first - aisle_m / 2, *(y0 + row_m + aisle_m / 2 for y0 in row_y0))
    return Warehouse(
        world=BoxWorld(np.array(boxes)),
        width=float(width_m),
        height=float(height_m),
        lane_x=tuple(float(v) for v in lane_x),
        lane_y=tuple(float(v) for v in lane_y),
        kinds=("wall",) * 4 + ("rack",) * racks + ("pallet",) * (len(boxes) - 4 - racks),
    )


def beam_angles(beams: int, fov: float) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` [rad] of ``beams`` beams spread over ``fov`` [rad].

    The beams are centred on the sensor's heading: beam i points at
    ``angle_min + i * angle_increment`` from it, with ``angle_min = -fov / 2`` and
    ``angle_increment = fov / beams`` (so a full circle holds no duplicate beam).
    """
    if isinstance(beams, bool) or not isinstance(beams, int | np.integer) or beams < 1:
        raise FieldError("beams", beams, "must be a positive integer")
    if not (0 < fov <= 2 * math.pi):
        raise FieldError("fov", fov, "must be in (0, 2 pi] rad")
    return -fov / 2, fov / beams


def scan_at(
    world: BoxWorld,
    pose: Pose2D,
    stamp: float,
    *,
    unit_id: str = "u1",
    beams: int = 1080,
    fov: float = 2 * math.pi,
    range_min: float = 0.05,
    range_max: float = 20.0,
    range_noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> Scan:
    """One scan of ``world`` from sensor ``pose`` at ``stamp`` [s].

    beams: number of beams over ``fov`` [rad], centred on the heading: beam i points at
        ``pose.yaw - fov / 2 + i * fov / beams``.
    range_min, range_max: [m] the sensor's limits; beyond ``range_max`` a beam reads
        ``+inf``. Returns closer than ``range_min`` are reported as measured (REP 117
        makes them invalid).
    range_noise: [m] standard deviation of gaussian noise added to returns (kept >= 0);
        needs ``rng`` when positive.
    """
    angle_min, increment = beam_angles(beams, fov)
    if not 0 <= range_min < range_max:
        raise FieldError("range_min", range_min, f"must be in [0, range_max = {range_max}) m")
    if not range_noise >= 0:
        raise FieldError("range_noise", range_noise, "must be >= 0 m")
    angles = pose.yaw + angle_min + increment * np.arange(beams)
    ranges = world.cast(pose.x, pose.y, angles, range_max)
    if range_noise > 0:
        if rng is None:
            raise ValueError("range_noise > 0 needs an rng")
        hits = np.isfinite(ranges)
        ranges[hits] = np.maximum(ranges[hits] + rng.normal(0.0, range_noise, hits.sum()), 0.0)
    return Scan(
        unit_id=unit_id,
        stamp=float(stamp),
        pose=pose,
        angle_min=angle_min,
        angle_increment=increment,
        range_min=range_min,
        range_max=range_max,
        ranges=ranges,
    )


def sample_scans(
    warehouse: Warehouse,
    n_scans: int,
    beams: int = 1080,
    range_max: float = 20.0,
    seed: int = 0,
    *,
    units: int = 4,
    rate_hz: float = 10.0,
    speed: float = 1.5,
    range_noise: float = 0.0,
) -> list[Scan]:
    """``n_scans`` scans from ``units`` units patrolling the warehouse lanes, by stamp.

    Each unit starts at a random junction and drives at ``speed`` [m/s] along the lane
    grid, turning at random at every junction (it reverses only at a dead end), heading
    along its direction of travel. Each scans at ``rate_hz`` [Hz]; unit k's j-th scan is
    stamped ``(j + k / units) / rate_hz`` [s], so stamps strictly increase across the
    fleet. Units do not see each other. Same arguments and seed, same scans.
    """
    if n_scans < 0:
        raise FieldError("n_scans", n_scans, "must be >= 0")
    if units < 1:
        raise FieldError("units", units, "must be a positive integer")
    for name, value in (("rate_hz", rate_hz), ("speed", speed)):
        if not (math.isfinite(value) and value > 0):
            raise FieldError(name, value, "must be positive and finite")
    if len(warehouse.lane_x) * len(warehouse.lane_y) < 2:
        raise ValueError("the warehouse needs at least two lane junctions to patrol")
    rng = np.random.default_rng(seed)
    rounds = -(-n_scans // units)
    tracks = [_patrol(warehouse, rng, speed / rate_hz, rounds) for _ in range(units)]
    scans = []
    for j in range(rounds):
        for k in range(min(units, n_scans - j * units)):
            scans.append(
                scan_at(
                    warehouse.world,
                    tracks[k][j],
                    (j + k / units) / rate_hz,
                    unit_id=f"u{k + 1}",
                    beams=beams,
                    range_max=range_max,
                    range_noise=range_noise,
                    rng=rng,
                )
            )
    return scans


def _patrol(
    warehouse: Warehouse, rng: np.random.Generator, step: float, count: int
) -> list[Pose2D]:
    """``count`` poses ``step`` [m] apart along a random walk over the lane junctions."""
    nx, ny = len(warehouse.lane_x), len(warehouse.lane_y)
    node = (int(rng.integers(nx)), int(rng.integers(ny)))
    prev = node
    target = node
    pos = np.array([warehouse.lane_x[node[0]], warehouse.lane_y[node[1]]])
    heading = 0.0
    poses = []
    for _ in range(count):
        left = step if poses else 0.0
        while True:
            if target == node:
                i, j = node
                options = [
                    n
                    for n in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))
                    if 0 <= n[0] < nx and 0 <= n[1] < ny and n != prev
                ] or [prev]
                target = options[int(rng.integers(len(options)))]
            goal = np.array([warehouse.lane_x[target[0]], warehouse.lane_y[target[1]]])
            gap = float(np.hypot(*(goal - pos)))
            if gap > 0:
                heading = math.atan2(goal[1] - pos[1], goal[0] - pos[0])
            if left < gap:
                pos = pos + (goal - pos) * (left / gap)
                break
            left -= gap
            pos = goal
            prev, node = node, target
        poses.append(Pose2D(float(pos[0]), float(pos[1]), heading))
    return poses
