"""Snapshots: due by scans or by time, but saving them takes at most
``journal.snapshot_max_share`` of the wall time (``mapserver.service.snapshot_schedule``)."""

import time

import numpy as np
import pytest
from conftest import make_scan
from server_helpers import small_settings

from mapserver.service.map_service import MapService
from mapserver.service.settings import SettingsError, load_settings
from mapserver.service.snapshot_schedule import SnapshotSchedule

SCHEDULE = SnapshotSchedule(every_scans=2000, every_seconds=60.0, max_share=0.1)


@pytest.mark.parametrize(
    ("scans", "seconds", "last_save", "due"),
    [
        (1999, 59.9, 0.0, False),  # neither rule yet
        (2000, 0.5, 0.0, True),  # the scan rule
        (1, 60.0, 0.0, True),  # the time rule
        (0, 600.0, 0.0, False),  # nothing to save
        (2000, 19.9, 2.0, False),  # a 2 s save: the next no sooner than 20 s after it began
        (2000, 20.0, 2.0, True),
        (10, 20.0, 2.0, False),  # the share alone never makes one due
        (1, 60.0, 7.0, False),  # a 7 s save holds even the time rule to 70 s
        (1, 70.0, 7.0, True),
    ],
)
def test_a_snapshot_is_due_by_scans_or_time_within_the_share(scans, seconds, last_save, due):
    assert SCHEDULE.due(scans, seconds, last_save) is due


def test_a_share_of_one_allows_back_to_back_saves():
    schedule = SnapshotSchedule(every_scans=1, every_seconds=60.0, max_share=1.0)
    assert schedule.due(1, 2.0, 2.0) and not schedule.due(1, 1.99, 2.0)


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5])
def test_a_share_outside_0_1_is_refused(share):
    with pytest.raises(ValueError, match="max_share"):
        SnapshotSchedule(10, 60.0, share)


@pytest.mark.parametrize("share", [0, 1.01, "half"])
def test_the_setting_names_the_field_and_value(tmp_path, share):
    with pytest.raises(SettingsError) as caught:
        load_settings(None, {"data_dir": tmp_path, "journal": {"snapshot_max_share": share}})
    assert "journal.snapshot_max_share" in str(caught.value)


def test_the_service_starts_a_snapshot_no_sooner_than_its_last_save_over_the_share(tmp_path):
    """Every scan makes a snapshot due (``snapshot_every_scans: 1``) and each save takes
    at least 0.1 s: with a share of 0.25 a save starts at least 0.4 s after the previous
    one began, however fast the scans come."""
    settings = small_settings(
        tmp_path / "data",
        journal={"snapshot_every_scans": 1, "snapshot_max_share": 0.25, "retain_seconds": None},
    )
    service = MapService(settings)
    starts: list[float] = []
    save = service.journal.save_snapshot

    def slow_save(*args, **kwargs):
        starts.append(time.monotonic())
        time.sleep(0.1)
        return save(*args, **kwargs)

    service.journal.save_snapshot = slow_save
    try:
        for k in range(1, 400):
            scan = make_scan(np.full(60, 2.0), x=3.0, y=3.0, stamp=0.01 * k, angle_min=-1.0)
            service.ingest([scan])
            time.sleep(0.005)
            if len(starts) >= 4:
                break
    finally:
        service.close()
    assert len(starts) >= 3, "the scans should have made several snapshots due"
    gaps = np.diff(starts)
    assert (gaps >= 0.4 - 0.01).all(), gaps
