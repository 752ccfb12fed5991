"""A fleet that comes and goes keeps the map (docs/map-time.md), against a real
``fleetmap serve`` on loopback: half the fleet docks and the rest posts for a minute of
map time, a unit joins late, one lags 30 s, one-shot ids post once, and none of their
honest scans is refused, with simulated stamps (no clock declared, and a declared
clock) and with epoch stamps. A unit whose clock is ahead is refused, naming its own
offset, and the map's time does not move."""

import time

import httpx
import pytest
from server_helpers import JSON, ServerProcess, scan_body

RATE_HZ = 10.0
MINUTE_S = 60.0
BEAMS = [3.0] * 60


def body(unit, stamp, x=5.0):
    return scan_body(stamp=stamp, unit=unit, x=x, y=5.0, ranges=BEAMS, angle_increment=0.03)


class Fleet:
    """Posts each tick's scans as one batch (as the simulator does: all or none) and
    tallies every unit's statuses; with ``declare``, declares the clock every second."""

    def __init__(self, http: httpx.Client, declare: bool):
        self.http = http
        self.declare = declare
        self.declared = -1.0
        self.statuses: dict[str, dict[int, int]] = {}

    def tick(self, stamps: dict[str, float], clock: float) -> None:
        if self.declare and clock - self.declared >= 1.0:
            self.http.put("/v1/clock", json={"now": clock}).raise_for_status()
            self.declared = clock
        batch = [body(unit, stamp) for unit, stamp in stamps.items()]
        status = self.http.post("/v1/scans/batch", json={"scans": batch}).status_code
        for unit in stamps:
            tally = self.statuses.setdefault(unit, {})
            tally[status] = tally.get(status, 0) + 1

    def refused(self) -> dict[str, dict[int, int]]:
        return {u: s for u, s in self.statuses.items() if set(s) != {200}}


@pytest.fixture
def server(tmp_path):
    process = ServerProcess(tmp_path / "data", grid=(200, 100))
    yield process
    process.stop()


@pytest.mark.parametrize("mode", ["simulated", "declared", "epoch"])
def test_half_the_fleet_docks_and_the_rest_keeps_the_map_for_a_minute(server, mode):
    base = time.time() - MINUTE_S - 130.0 if mode == "epoch" else 0.0
    with httpx.Client(base_url=server.url, timeout=10, headers=JSON) as http:
        fleet = Fleet(http, declare=mode == "declared")
        units = [f"u{k}" for k in range(10)]
        dt = 1.0 / RATE_HZ
        for k in range(10):  # all ten post for a second
            t = base + k * dt
            fleet.tick({u: t for u in units}, t)
        driving = units[:5]
        if mode == "epoch":  # the docked half last posted over 2 minutes before now
            base += 120.0
        for k in range(int(MINUTE_S * RATE_HZ)):
            t = base + 1.0 + k * dt
            stamps = {u: t for u in driving}
            if k >= 300:
                stamps["late"] = t  # joins halfway
            if k >= 100:
                stamps["laggard"] = t - 30.0  # replays its buffer 30 s behind
            if k % 100 == 0:
                stamps.update({f"once{k}-{j}": t for j in range(5)})  # one-shot ids
            fleet.tick(stamps, t)
        t += dt
        fleet.tick({u: t for u in units}, t)  # the docked half comes back
        assert fleet.refused() == {}
        assert fleet.statuses["u0"] == {200: 10 + 600 + 1} and fleet.statuses["u9"] == {200: 11}
        assert fleet.statuses["late"] == {200: 300} and fleet.statuses["laggard"] == {200: 500}

        stamp = http.get("/v1/map/meta").json()["stamp"]
        assert stamp == pytest.approx(t)
        for ahead in (300.0, 1e15):  # a unit whose clock runs ahead
            reply = http.post("/v1/scans", json=body("fast", t + ahead if ahead < 1e9 else ahead))
            assert reply.status_code == 422
            detail = reply.json()["detail"]
            assert detail.startswith("stamp: ") and "this unit's clock runs" in detail
            assert http.get("/v1/map/meta").json()["stamp"] == stamp  # the map's time stays
        fleet.statuses.clear()
        fleet.tick({u: t + dt for u in units}, t + dt)  # the others are unharmed
        assert fleet.refused() == {}


def test_a_declared_clock_is_reported_and_refused_ahead_of_the_wall(server):
    with httpx.Client(base_url=server.url, timeout=10, headers=JSON) as http:
        assert http.get("/v1/clock").json()["reference"] == "wall"
        declared = http.put("/v1/clock", json={"now": 12.5}).json()
        assert declared["reference"] == "declared" and declared["now"] == 12.5
        assert declared["declared"]["now"] == 12.5 and declared["max_lead_s"] == 5.0
        ahead = http.put("/v1/clock", json={"now": time.time() + 3600})
        assert ahead.status_code == 422 and ahead.json()["detail"].startswith("now: ")
        assert http.put("/v1/clock", json={"now": "soon"}).status_code == 422
        assert http.get("/v1/clock").json()["declared"]["now"] == 12.5
