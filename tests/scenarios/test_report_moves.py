"""``report.png`` marks a moved object where it stood and where it went
(``scenarios.score.report``): the event's triangle at the new place, a hollow one at the
old place with its label, and a dashed arrow from the old place to the new."""

from matplotlib.figure import Figure
from matplotlib.text import Annotation

from mapserver.core.geometry import GridGeometry
from scenarios.run.record import EventRecord, ObjectsSample, ObjectState, RunRecord, UnitSample
from scenarios.score.report import _draw_map, _draw_timeline

OLD, NEW = (24.0, 16.33), (12.0, 1.8)  # pod-9 of moved_pod, before and after t = 60 s


def moved_pod_record(samples: bool = True) -> RunRecord:
    record = RunRecord("moved_pod", "dual", 0, GridGeometry(400, 300, 0.1))
    pod = ObjectState("pod-9", "pod", *OLD, 1.2, 1.2, 0.0, 2.0, False)
    wall = ObjectState("wall-dead-end", "wall", 37.5, 16.33, 0.33, 2.0, 0.0, 2.0, False)
    if samples:
        record.objects += [
            ObjectsSample(0.0, (pod, wall)),
            ObjectsSample(60.0, (ObjectState("pod-9", "pod", *NEW, 1.2, 1.2, 0, 2, False), wall)),
        ]
    record.events.append(EventRecord(60.0, "move", "pod-9", *NEW, "pod-9 moves to the band"))
    return record


def drawn(record: RunRecord):
    ax = Figure().add_subplot()
    _draw_map(ax, record)
    texts = {t.get_text(): t for t in ax.texts}
    arrows = [t for t in ax.texts if isinstance(t, Annotation) and t.arrow_patch is not None]
    hollow = [
        c.get_offsets().tolist()
        for c in ax.collections
        if len(c.get_offsets()) and len(c.get_facecolor()) == 0
    ]
    return texts, arrows, hollow


def test_a_moved_object_is_marked_where_it_stood_and_where_it_went():
    texts, arrows, hollow = drawn(moved_pod_record())
    assert texts["E1 move pod-9"].xy == NEW
    assert texts["E1 pod-9 stood here"].xy == OLD  # the sample before the move, not at it
    (arrow,) = arrows
    assert (arrow.xyann, arrow.xy) == (OLD, NEW)  # from the old place to the new
    assert hollow == [[list(OLD)]]


def test_without_a_sample_before_the_move_only_the_new_place_is_marked():
    texts, arrows, hollow = drawn(moved_pod_record(samples=False))
    assert set(texts) == {"E1 move pod-9", "no map recorded"} and not arrows and not hollow


def timeline_labels(units: int):
    record = RunRecord("fleet", "dual", 0, GridGeometry(400, 300, 0.1))
    record.units += [UnitSample(0.0, f"u{k}", 1.0, 1.0, 0.0, False, False, None) for k in
                     range(1, units + 1)]  # fmt: skip
    ax = Figure().add_subplot()
    _draw_timeline(ax, record, 60.0)
    return [t.get_text() for t in ax.get_yticklabels()], ax.get_ylabel()


def test_the_timeline_names_every_unit_of_a_small_fleet_and_every_kth_of_a_large_one():
    names, label = timeline_labels(12)
    assert names == [f"u{k}" for k in range(1, 13)] and label == ""
    names, label = timeline_labels(1000)  # thousand_units: every 25th, in natural order
    assert names == [f"u{k}" for k in range(1, 1001, 25)] and len(names) == 40
    assert label == "1000 units, one in 25 named"
    names, label = timeline_labels(100)  # hundred_units: every 3rd
    assert names[:3] == ["u1", "u4", "u7"] and len(names) == 34
    assert label == "100 units, one in 3 named"  # not "every 3th"
