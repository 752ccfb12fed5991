"""The DUFOMap agreement benchmark's helpers (``tests/benchmarks/dufomap_agreement.py``):
the agreement maths on hand-made labels, exact; fleetmap's two labellings on a wall and a
person who steps once into space seen free; DUFOMap's on the same scans where ``dufomap``
(the ``bench`` extra) is installed; and the one-line errors of a missing peer or file.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from conftest import make_scan

from mapserver.store.recordings.grid_fit import fit_grid
from tests.benchmarks import dufomap_agreement as bench

T, F = True, False


def test_agreement_counts_points_labelled_alike_and_scores_dynamic():
    reference = [T, T, T, F, F, F, F, F, T, F]
    labels = [T, T, F, T, F, F, F, F, F, F]  # 2 true positives, 1 false, 2 missed, 5 alike
    assert bench.agreement(reference, labels) == bench.Agreement(
        points=10, agreement=0.7, precision=2 / 3, recall=0.5, f1=4 / 7
    )


def test_agreement_of_identical_labels_is_one():
    labels = [T, F, F, T]
    assert bench.agreement(labels, labels) == bench.Agreement(4, 1.0, 1.0, 1.0, 1.0)


def test_scores_without_dynamic_labels_are_nan_not_zero():
    scores = bench.agreement([F, F, T], [F, F, F])
    assert (scores.agreement, scores.recall, scores.f1) == (2 / 3, 0.0, 0.0)
    assert math.isnan(scores.precision)  # nothing labelled dynamic: no precision
    nothing = bench.agreement([F, F], [F, F])
    assert nothing.agreement == 1.0
    assert all(math.isnan(v) for v in (nothing.precision, nothing.recall, nothing.f1))


def test_agreement_refuses_labels_of_other_points():
    with pytest.raises(ValueError, match="3 labels for 2 reference labels"):
        bench.agreement([T, F], [T, F, F])


def test_dynamic_share_counts_only_the_selected_points():
    labels = np.array([T, T, F, F, T])
    near = np.array([T, T, T, F, F])
    assert bench.dynamic_share(labels, near) == 2 / 3
    assert bench.dynamic_share(labels, ~near) == 0.5
    assert math.isnan(bench.dynamic_share(labels, np.zeros(5, bool)))


WALL, PERSON = 3.0, 1.0  # [m] along the beams
BEAMS, PERSON_BEAMS = 21, slice(9, 12)


def wall_and_person() -> tuple[list, np.ndarray]:
    """15 scans of a wall, one with a person in front of it (in space the first 15 saw
    free), 5 more of the wall; and per return whether it is the person."""
    scans, person = [], []
    for k in range(21):
        ranges = np.full(BEAMS, WALL)
        if k == 15:
            ranges[PERSON_BEAMS] = PERSON
        scans.append(make_scan(ranges, stamp=0.1 * k, angle_min=-0.1))
        person.append(ranges == PERSON)
    return scans, np.concatenate(person)


def test_fleetmap_calls_the_person_transient_and_keeps_the_wall():
    scans, person = wall_and_person()
    labels = bench.fleetmap_labels(scans, fit_grid(scans, 0.05))
    assert labels.at_fusion.tolist() == person.tolist()  # its cells were void already
    assert labels.at_end.tolist() == person.tolist()  # the wall is kept as structure
    assert labels.fuse_s > 0


def test_dufomap_labels_the_person_dynamic_and_the_wall_static():
    dufomap = pytest.importorskip("dufomap", reason="the DUFOMap peer needs the bench extra")
    scans, person = wall_and_person()
    labels = bench.dufomap_labels(scans, 0.05, module=dufomap)
    assert labels.dynamic.tolist() == person.tolist()
    assert bench.return_ranges(scans).size == person.size


def test_the_benchmark_names_the_fix_when_dufomap_is_missing(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "dufomap", None)  # import dufomap raises, as uninstalled
    assert bench.main(["missing.bag"]) == 2
    err = capsys.readouterr().err
    assert (
        err
        == f"error: the DUFOMap peer needs dufomap, which is not installed: {bench.INSTALL_HINT}\n"
    )


def test_the_benchmark_names_the_fix_when_the_recording_is_missing(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(bench, "load_dufomap", lambda: sys)  # any module: never used
    assert bench.main([str(tmp_path / "missing.bag")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: no recording at {tmp_path / 'missing.bag'}: ")
    assert "leg_tracker" in err and err.count("\n") == 1
