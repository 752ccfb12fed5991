"""A costmap patch: the costs of one box of cells, as the server sends them and a client
applies them (``GET /v1/costmap/updates``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Patch:
    """Costs of the box (x0, y0) .. (x0 + width - 1, y0 + height - 1) [cells], row-major."""

    x0: int
    y0: int
    width: int
    height: int
    data: np.ndarray  # uint8 (height, width)

    def apply_to(self, costs: np.ndarray) -> None:
        """Write this patch into a (H, W) cost array in place."""
        costs[self.y0 : self.y0 + self.height, self.x0 : self.x0 + self.width] = self.data
