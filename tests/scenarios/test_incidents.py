"""Collision incidents (``scenarios.score.incidents``): contacts grouped per unit, thing and
cause within 2 s, on hand-made contact streams (no simulator)."""

import numpy as np
import pytest

from fleet.sim import CollisionEvent
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from scenarios.score.incidents import (
    INCIDENT_GAP_S,
    IncidentTracker,
    collision_counts,
    contact_cells,
    cost_class,
)


def bump(t, unit="u4", other="rack-1", cause="fleet"):
    return CollisionEvent(t, unit, other, "rack", 19.129, 5.059, cause)


def test_a_unit_wedged_against_a_rack_retrying_every_0_6_s_is_one_incident():
    """The moved_pod seed 2 wedge under binary: 121 contacts 0.6 s apart, 108.3-179.9 s."""
    tracker = IncidentTracker()
    times = [round(108.3 + 0.6 * k, 1) for k in range(120)] + [179.9]
    for t in times:
        tracker.observe(t, [bump(t)], held=())
    (incident,) = tracker.incidents
    assert (incident.start, incident.end, incident.contacts) == (108.3, 179.9, 121)
    assert incident.duration == pytest.approx(71.6)
    assert collision_counts(tracker.incidents) == {
        "collisions": 1, "scenario_collisions": 0, "collision_seconds": 71.6,
        "collision_contacts": 121,
    }  # fmt: skip


def test_contacts_further_apart_than_the_gap_or_with_another_thing_are_new_incidents():
    assert INCIDENT_GAP_S == 2.0
    tracker = IncidentTracker()
    tracker.observe(1.0, [bump(1.0)], ())
    tracker.observe(3.0, [bump(3.0)], ())  # 2.0 s later: the same incident
    tracker.observe(5.1, [bump(5.1)], ())  # 2.1 s later: a new one
    tracker.observe(5.1, [bump(5.1, other="rack-2"), bump(5.1, unit="u1")], ())
    tracker.observe(5.2, [bump(5.2, cause="scenario")], ())
    spans = [(i.unit_id, i.other_id, i.cause, i.start, i.end, i.contacts)
             for i in tracker.incidents]  # fmt: skip
    assert spans == [
        ("u4", "rack-1", "fleet", 1.0, 3.0, 2),
        ("u4", "rack-1", "fleet", 5.1, 5.1, 1),
        ("u4", "rack-2", "fleet", 5.1, 5.1, 1),
        ("u1", "rack-1", "fleet", 5.1, 5.1, 1),
        ("u4", "rack-1", "scenario", 5.2, 5.2, 1),
    ]
    counts = collision_counts(tracker.incidents)
    assert (counts["collisions"], counts["scenario_collisions"]) == (4, 1)


def test_a_contact_held_step_after_step_lasts_until_it_ends():
    """A tote dropped onto a standing unit at 4.0 s, overlapping it until 6.5 s."""
    tracker = IncidentTracker()
    tote = CollisionEvent(4.0, "u2", "tote-1", "tote", 1.5, 4.0, "scenario")
    begun = tracker.observe(4.0, [tote], held=[("u2", "tote-1")])
    for k in range(1, 26):
        tracker.observe(4.0 + 0.1 * k, [], held=[("u2", "tote-1")])
    tracker.observe(6.6, [], held=[])
    assert begun == tracker.incidents
    (incident,) = tracker.incidents
    assert (incident.start, incident.end, incident.contacts) == (4.0, pytest.approx(6.5), 1)
    assert collision_counts(tracker.incidents)["collision_seconds"] == 0.0  # the scenario's


def test_a_new_incident_gets_the_plan_its_unit_was_driving():
    tracker = IncidentTracker()
    seen = []
    tracker.observe(1.0, [bump(1.0)], (), plan=lambda e: seen.append(e.time) or "plan")
    tracker.observe(1.5, [bump(1.5)], (), plan=lambda e: seen.append(e.time) or "plan")
    assert seen == [1.0] and tracker.incidents[0].plan == "plan"


def test_contact_cells_are_the_touched_things_cells_under_the_body():
    geometry = GridGeometry(20, 20, 0.1)
    # a rack face at x = 1.0 (the rack is x >= 1.0); a unit of radius 0.3 at x = 0.7
    cells = contact_cells(geometry, 0.7, 1.0, 0.3, lambda xs, ys: np.maximum(1.0 - xs, 0.0))
    # the rack's cells (centres x = 1.05) within 0.4 m: y 0.85 .. 1.15
    assert sorted(cells) == [(10, 8), (10, 9), (10, 10), (10, 11)]
    # a wall with no thickness on the cell edge x = 1.0: no centre inside, the nearest
    # cells (centres 0.05 m off it) on both sides: x 0.95, y 0.75 .. 1.25; x 1.05
    thin = contact_cells(geometry, 0.7, 1.0, 0.3, lambda xs, ys: np.abs(xs - 1.0))
    assert sorted(thin) == [(9, r) for r in range(7, 13)] + [(10, r) for r in range(8, 12)]


def test_cost_classes_name_the_nav2_costs():
    assert [cost_class(v) for v in (FREE, 1, 252, INSCRIBED, LETHAL, UNKNOWN)] == [
        "free", "inflated", "inflated", "inscribed", "lethal", "unknown",
    ]  # fmt: skip
