"""The maps ``fleetmap evaluate`` measures: one interface, a fleetmap grid per policy.

A ``MapUnderTest`` fuses scans one at a time and answers two reads in the grid's cells:
the states (``CellState``) of some cells at a stamp, and the whole grid's. The OctoMap
peer (``octomap_peer.py``) is one too.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel


class MapUnderTest(Protocol):
    """A map ``evaluate`` fuses the recording into and reads."""

    name: str

    def fuse(self, scan: Scan) -> None:
        """Fuse one scan (the only call timed for the map's speed)."""

    def states_of(self, cells: np.ndarray, stamp: float) -> np.ndarray:
        """``CellState`` (uint8) of the cells at flat indices ``cells``, at ``stamp`` [s]."""

    def final_states(self, stamp: float) -> np.ndarray:
        """``CellState`` (uint8, (height, width)) of every cell at ``stamp`` [s]."""


class FleetmapMap:
    """fleetmap's ``BeliefGrid`` under one policy, named for it."""

    def __init__(
        self, geometry: GridGeometry, model: SensorModel, policy: Policy, decay: DecayParams
    ) -> None:
        self.name = policy.value
        self.belief = BeliefGrid(geometry, model, policy, decay)

    def fuse(self, scan: Scan) -> None:
        self.belief.fuse(scan)

    def states_of(self, cells: np.ndarray, stamp: float) -> np.ndarray:
        return self.belief.sample(cells, stamp).states

    def final_states(self, stamp: float) -> np.ndarray:
        return self.belief.states_at(stamp)


def parse_policies(text: str) -> list[Policy]:
    """``decay,binary,sticky`` -> the policies, in order, each once; ValueError (a
    ``FieldError`` naming the choices) for an unknown name, ValueError for none."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise ValueError(f"--policies names no policy, got {text!r}")
    return list(dict.fromkeys(Policy.parse(name) for name in names))
