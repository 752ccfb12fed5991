"""The world's objects for the replay's scene: walls, racks, pods, stations, totes,
pallets and people as ``ObjectState`` samples (``record.objects``), taken whenever the
world changed (an object added, moved or removed), at most once every ``every_s`` [s].

``replay_mcap`` turns each sample into a ``foxglove.SceneUpdate`` with an entity per
object (``object/<id>``) at its pose then and a deletion for each object gone since the
sample before.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet.layout import DEFAULT_HEIGHT_M, Obstacle
from fleet.shapes import Box
from scenarios.run.record import ObjectsSample, ObjectState

if TYPE_CHECKING:
    from scenarios.run.episode import Episode


def object_state(obstacle: Obstacle) -> ObjectState:
    """An obstacle as a scene object: a box's centre, sides and yaw, or a cylinder's
    centre and diameter (as both sizes) [m], and its height [m]."""
    shape = obstacle.shape
    height = DEFAULT_HEIGHT_M[obstacle.kind] if obstacle.height is None else obstacle.height
    if isinstance(shape, Box):
        return ObjectState(obstacle.id, obstacle.kind.value, shape.x, shape.y,
                           shape.size_x, shape.size_y, shape.yaw, height, False)  # fmt: skip
    diameter = 2.0 * shape.radius
    return ObjectState(obstacle.id, obstacle.kind.value, shape.x, shape.y,
                       diameter, diameter, 0.0, height, True)  # fmt: skip


class ObjectRecorder:
    """Appends the world's objects to ``record.objects`` when the world's revision has
    changed since the last sample (and at the first look)."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self._revision: int | None = None

    def observe(self, episode: Episode) -> None:
        world = episode.world
        if world is None or world.revision == self._revision:
            return
        self._revision = world.revision
        objects = tuple(object_state(o) for _, o in sorted(world.obstacles.items()))
        episode.record.objects.append(ObjectsSample(episode.report.now, objects))

    def finish(self, episode: Episode) -> None:
        return None
