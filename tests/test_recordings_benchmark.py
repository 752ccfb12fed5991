"""The recordings benchmark's OctoMap peer (``tests/benchmarks/recordings.py``): it
inserts a recording's scans where pyoctomap (the ``bench`` extra) is installed, and is
skipped without it."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_scan

from scenarios.evaluate.octomap_peer import octomap_installed
from tests.benchmarks import recordings as bench


@pytest.mark.skipif(not octomap_installed(), reason="pyoctomap (the bench extra) not installed")
def test_octomap_inserts_the_scans_and_gives_a_rate():
    scans = [make_scan(np.full(90, 2.0), x=1.0 + 0.1 * k, stamp=float(k)) for k in range(3)]
    rate = bench.octomap_rate(scans)
    assert rate is not None and rate > 0


def test_without_pyoctomap_the_peer_is_left_out(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "pyoctomap", None)  # its import fails
    monkeypatch.delitem(__import__("sys").modules, "tests.benchmarks.fusion", raising=False)
    assert bench.octomap_rate([make_scan(np.full(90, 2.0))]) is None
