"""The colours of the replay's costmap (``/map/costmap``): one RGBA per Nav2 cost value,
after RViz's "costmap" colour scheme for Nav2 costmaps (rviz_default_plugins, Map
display), so Foxglove draws the costmap as a Nav2 user expects (``colorMode:
rgba-fields`` in the shipped layout):

=======================  ======================  ===============================
cost                     colour                  RGBA (0-255)
=======================  ======================  ===============================
FREE 0                   transparent             (0, 0, 0, 0)
graded 1..252            blue to red             (r, 0, 255 - r, 255),
                                                 r = round(255 * cost / 252)
INSCRIBED 253            cyan                    (0, 255, 255, 255)
LETHAL 254               magenta                 (255, 0, 255, 255)
UNKNOWN 255              grey-green              (112, 137, 134, 255)
=======================  ======================  ===============================

Free cells are transparent, so the occupancy grid (or the floor) shows through them.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN


def costmap_rgba() -> np.ndarray:
    """(256, 4) uint8: the RGBA of each cost value (module docstring)."""
    palette = np.zeros((256, 4), dtype=np.uint8)
    graded = np.arange(1, INSCRIBED)
    red = np.round(255 * graded / (INSCRIBED - 1)).astype(np.uint8)
    palette[graded, 0] = red
    palette[graded, 2] = 255 - red
    palette[graded, 3] = 255
    palette[FREE] = (0, 0, 0, 0)
    palette[INSCRIBED] = (0, 255, 255, 255)
    palette[LETHAL] = (255, 0, 255, 255)
    palette[UNKNOWN] = (112, 137, 134, 255)
    return palette


COSTMAP_RGBA: Final = costmap_rgba()
