"""OctoMap as the peer ``fleetmap evaluate`` measures beside fleetmap's policies.

OctoMap's classic update (Hornung et al., *OctoMap*, Autonomous Robots 2013) used in 2D:
an ``OcTree`` whose voxels are the grid's cells (the same resolution; one layer of
voxels, z in [0, resolution)), each scan's returns inserted as a point cloud at the
layer's mid height from the sensor's origin with ``insertPointCloud`` and ``max_range``
= the scan's ``range_max``, as ``octomap_server`` inserts a laser projected to a cloud.
Occupancy is read back at the centres of the grid's cells and classified by fleetmap's
thresholds. ``pyoctomap`` (the ``bench`` extra) is imported only when the peer is made.

The sensor model is fleetmap's where OctoMap has the setting: ``p_hit``, ``p_miss``,
the clamps (``setClampingThresMin/Max`` as probabilities) and the occupied threshold.
What differs, by OctoMap's design:

- no decay: the update is fleetmap's clamped log-odds without fading;
- no-return beams are not inserted (a projected cloud has no point for them): they
  clear nothing, where fleetmap clears out to ``no_return_range`` (``binary``: to
  range_max);
- rays are cast in 3D (a DDA through every voxel a ray touches) where fleetmap steps
  Bresenham cells, so cells grazed near a surface get other counts of misses;
- no fill between beams, no glancing-face guard, no pose-uncertainty weighting;
- pyoctomap hands OctoMap float32 coordinates; a grid whose origin is not a whole
  number of cells is read at its cell centres from voxels that straddle them.
"""

from __future__ import annotations

import importlib

import numpy as np

from mapserver.core.belief import CellState
from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import BEAM_RETURN, Scan
from mapserver.core.sensor_model import SensorModel, sigmoid

PEER_NAME = "octomap"
INSTALL_HINT = "pip install 'fleetmap[bench]'"


class PeerMissing(FleetmapError, ModuleNotFoundError):
    """The OctoMap peer was asked for but ``pyoctomap`` is not installed; the message
    names the extra to install."""


def octomap_installed() -> bool:
    """Whether ``pyoctomap`` can be imported."""
    try:
        importlib.import_module("pyoctomap")
    except ImportError:
        return False
    return True


def octree(model: SensorModel, resolution: float):
    """An ``OcTree`` of voxels ``resolution`` [m] with fleetmap's sensor model (OctoMap
    takes probabilities, not log-odds). PeerMissing names the extra to install."""
    try:
        pyoctomap = importlib.import_module("pyoctomap")
    except ImportError:
        raise PeerMissing(
            f"the OctoMap peer needs pyoctomap, which is not installed: {INSTALL_HINT}"
        ) from None
    tree = pyoctomap.OcTree(resolution)
    tree.setProbHit(model.p_hit)
    tree.setProbMiss(model.p_miss)
    tree.setClampingThresMin(sigmoid(model.clamp_min))  # -5 log-odds = p 0.0067
    tree.setClampingThresMax(sigmoid(model.clamp_max))  # +5 log-odds = p 0.9933
    tree.setOccupancyThres(model.occupied_threshold)
    return tree


def return_cloud(scan: Scan, z: float) -> np.ndarray:
    """(n, 3) endpoints [m] of the scan's returns at height ``z`` [m], in the map frame."""
    returns = np.flatnonzero(scan.beam_classes() == BEAM_RETURN)
    r = scan.ranges[returns]
    angles = scan.pose.yaw + scan.angle_min + scan.angle_increment * returns
    x = scan.pose.x + r * np.cos(angles)
    y = scan.pose.y + r * np.sin(angles)
    return np.column_stack((x, y, np.full(r.size, z)))


class OctoMapPeer:
    """OctoMap on the grid's cells (see the module); a ``MapUnderTest``.

    ``fuse`` builds the scan's cloud and inserts it (both timed, as fleetmap's ``fuse``
    turns a scan into its kernel's input) with ``lazy_eval``: inner nodes are never
    brought up to date, as only leaves (voxels) are read.
    """

    name = PEER_NAME

    def __init__(self, geometry: GridGeometry, model: SensorModel) -> None:
        self.geometry = geometry
        self.model = model
        self.tree = octree(model, geometry.resolution)
        self.z = geometry.resolution / 2  # [m] the middle of voxel layer 0

    def fuse(self, scan: Scan) -> None:
        cloud = return_cloud(scan, self.z)
        if len(cloud):
            origin = np.array([scan.pose.x, scan.pose.y, self.z])
            self.tree.insertPointCloud(cloud, origin, max_range=scan.range_max, lazy_eval=True)

    def states_of(self, cells: np.ndarray, stamp: float) -> np.ndarray:
        """States read at the cells' centres (``stamp`` is unused: OctoMap never fades)."""
        g = self.geometry
        cells = np.asarray(cells, dtype=np.int64)
        xs = g.origin_x + (cells % g.width + 0.5) * g.resolution
        ys = g.origin_y + (cells // g.width + 0.5) * g.resolution
        log_odds = np.full(cells.size, np.nan)
        for i, (x, y) in enumerate(zip(xs.tolist(), ys.tolist(), strict=True)):
            node = self.tree.search(np.array([x, y, self.z]))
            if node is not None:
                log_odds[i] = node.getLogOdds()
        return self._classify(log_odds)

    def final_states(self, stamp: float) -> np.ndarray:
        """Every cell's state, from the tree's leaves of layer 0 (one pass over them)."""
        g = self.geometry
        log_odds = np.full(g.shape, np.nan)
        for leaf in self.tree.begin_leafs():
            x, y, z = leaf.getCoordinate()
            if not 0.0 <= z < g.resolution:
                continue
            col = int(np.floor((x - g.origin_x) / g.resolution))
            row = int(np.floor((y - g.origin_y) / g.resolution))
            if 0 <= col < g.width and 0 <= row < g.height:
                log_odds[row, col] = leaf.current_node.getLogOdds()
        return self._classify(log_odds)

    def _classify(self, log_odds: np.ndarray) -> np.ndarray:
        """NaN (no node: never observed) unknown; else by fleetmap's thresholds."""
        m = self.model
        states = np.full(log_odds.shape, CellState.UNKNOWN, dtype=np.uint8)
        with np.errstate(invalid="ignore"):
            states[log_odds > m.l_occupied] = CellState.OCCUPIED
            states[log_odds < m.l_free] = CellState.FREE
        return states
