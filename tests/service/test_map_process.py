"""The map in a process of its own (``server.map_process``): the HTTP front answers as a
server whose map lives in it, refusals and acks keep their meaning, the child closes
when the front goes, and a lost child fails calls instead of leaving them waiting."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from server_helpers import JSON, TEST_SERVER, scan_body, small_settings

from mapserver.api.app import create_app
from mapserver.core.scan import Scan
from mapserver.service.map_process import MapProcess, MapProcessError, open_map_service
from mapserver.service.map_service import DataDirError, MapService
from mapserver.service.scan_gate import IngestError
from mapserver.store.journal import Journal, journal_path

ROOT = Path(__file__).resolve().parents[2]
MAP_PROCESS = {**TEST_SERVER, "map_process": True}


def scans(n: int) -> list[dict]:
    """``n`` scans of three units walking along the grid's middle row."""
    return [scan_body(stamp=1.0 + k, unit=f"u{k % 3}", x=2.0 + 0.1 * k, y=5.0) for k in range(n)]


def test_ingest_errors_pickle_whole() -> None:
    for error in (IngestError(409, "stamp: went back"), MapProcessError("gone")):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error)
        assert (again.status, again.detail) == (error.status, error.detail)


def test_open_map_service_follows_the_setting(tmp_path: Path) -> None:
    local = open_map_service(small_settings(tmp_path / "a"))
    assert isinstance(local, MapService)
    local.close()
    remote = open_map_service(small_settings(tmp_path / "b", server=MAP_PROCESS))
    try:
        assert isinstance(remote, MapProcess) and remote.pid != os.getpid()
    finally:
        remote.close()
    assert not remote._process.is_alive()


def test_the_front_answers_as_an_in_process_server_does(tmp_path: Path) -> None:
    """The same scans through both servers: the same acks, the same refusal, the same
    costmap and occupancy bytes, the same clock and metrics."""
    bodies = scans(30)
    answers = {}
    for name, server in (("local", TEST_SERVER), ("process", MAP_PROCESS)):
        settings = small_settings(tmp_path / name, server=server)
        with TestClient(create_app(settings)) as client:
            acks = [client.post("/v1/scans", json=b, headers=JSON).json() for b in bodies]
            stale = client.post("/v1/scans", json=scan_body(stamp=0.5, unit="u0"), headers=JSON)
            costmap = client.get("/v1/costmap").content
            clock = client.put("/v1/clock", json={"now": 1e12}, headers=JSON)
            declared = client.put("/v1/clock", json={"now": 40.0}, headers=JSON).json()
            metrics = client.get("/metrics").text
            answers[name] = (acks, stale.status_code, stale.json(), costmap, clock.status_code)
            assert declared["declared"]["now"] == 40.0
            assert 'fleetmap_ingest_stage_seconds_count{stage="journal"} 30.0' in metrics
            assert "fleetmap_map_version 30.0" in metrics
            assert client.get("/healthz").json()["version"] == 30
    assert answers["local"] == answers["process"]
    assert answers["process"][1] == 409 and answers["process"][4] == 422


def test_concurrent_submissions_are_journaled_in_order_and_all_acked(tmp_path: Path) -> None:
    """Eight threads post 40 scans each at once: every ack's seq is distinct, the journal
    holds exactly those seqs, and each unit's seqs rise with its stamps."""
    settings = small_settings(tmp_path / "data", server=MAP_PROCESS)
    service = MapProcess(settings)
    acks: dict[str, list] = {}

    def post(unit: str) -> None:
        bodies = [scan_body(stamp=1.0 + k, unit=unit, x=3.0) for k in range(40)]
        acks[unit] = [service.ingest([Scan.from_dict(b)])[0] for b in bodies]

    threads = [threading.Thread(target=post, args=(f"u{k}",)) for k in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    service.close()
    seqs = sorted(ack.seq for unit_acks in acks.values() for ack in unit_acks)
    assert seqs == list(range(1, 321))
    for unit_acks in acks.values():
        assert [a.seq for a in unit_acks] == sorted(a.seq for a in unit_acks)
        assert all(a.map_version >= a.seq for a in unit_acks)
    with Journal(journal_path(settings.data_dir), readonly=True) as journal:
        assert journal.last_seq() == 320


def test_a_data_dir_in_use_is_refused_as_in_process(tmp_path: Path) -> None:
    settings = small_settings(tmp_path / "data", server=MAP_PROCESS)
    holder = MapService(settings)
    try:
        with pytest.raises(DataDirError, match="in use"):
            MapProcess(settings)
    finally:
        holder.close()


def test_a_lost_map_process_fails_calls_and_keeps_what_it_acked(tmp_path: Path) -> None:
    settings = small_settings(tmp_path / "data", server=MAP_PROCESS)
    lost = threading.Event()
    service = MapProcess(settings, on_lost=lost.set)
    bodies = scans(10)
    acks = [service.ingest([Scan.from_dict(b)])[0] for b in bodies]
    os.kill(service.pid, signal.SIGKILL)
    assert lost.wait(10.0)
    with pytest.raises(MapProcessError, match="ended unexpectedly") as refused:
        service.ingest([Scan.from_dict(scan_body(stamp=99.0))])
    assert refused.value.status == 503
    with pytest.raises(MapProcessError):
        service.meta()
    service.close()  # closing a lost map process returns
    again = MapService(small_settings(tmp_path / "data"))  # its lock went with it
    try:
        assert again.version == acks[-1].map_version == 10
        assert again.belief.scans_fused == 10
    finally:
        again.close()


def test_the_map_process_closes_when_its_front_is_killed(tmp_path: Path) -> None:
    """A front killed with SIGKILL: its child reads the end of the pipe, closes the map
    and exits, so the data dir can be opened again; every acked scan is in it."""
    data = tmp_path / "data"
    script = textwrap.dedent(
        f"""
        import os, sys
        sys.path.insert(0, {str(ROOT / "tests")!r})
        from server_helpers import scan_body, small_settings
        from mapserver.core.scan import Scan
        from mapserver.service.map_process import MapProcess

        def main():
            service = MapProcess(small_settings({str(data)!r}, server={MAP_PROCESS!r}))
            for k in range(5):
                service.ingest([Scan.from_dict(scan_body(stamp=1.0 + k))])
            print(service.pid, flush=True)
            os.kill(os.getpid(), 9)

        if __name__ == "__main__":
            main()
        """
    )
    path = tmp_path / "front.py"
    path.write_text(script)
    front = subprocess.run(
        [sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert front.returncode == -signal.SIGKILL, front.stderr
    child = int(front.stdout.split()[0])
    deadline = time.monotonic() + 30.0
    while Path(f"/proc/{child}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not Path(f"/proc/{child}").exists()
    again = MapService(small_settings(data))
    try:
        assert again.belief.scans_fused == 5
    finally:
        again.close()


def test_reads_return_the_child_s_arrays(tmp_path: Path) -> None:
    settings = small_settings(tmp_path / "data", server=MAP_PROCESS)
    local = MapService(small_settings(tmp_path / "local"))
    service = MapProcess(settings)
    try:
        for body in scans(12):
            service.ingest([Scan.from_dict(body)])
            local.ingest([Scan.from_dict(body)])
        for read in ("costmap_read", "occupancy_read", "age_read"):
            ours, theirs = getattr(service, read)(), getattr(local, read)()
            assert np.array_equal(ours.data, theirs.data, equal_nan=True)
            assert (ours.version, ours.stamp) == (theirs.version, theirs.stamp)
        assert service.updates_since(0)[:2] == local.updates_since(0)[:2]
        points = [[2.5, 5.0], [9.0, 9.0]]
        assert service.cell_columns(points) == local.cell_columns(points)
        assert service.segments([[1.0, 5.0, 4.0, 5.0]]) == local.segments([[1.0, 5.0, 4.0, 5.0]])
        assert service.snapshot() == local.snapshot() == 12
    finally:
        service.close()
        local.close()
