"""Readers never starve writers: with 50 clients asking for plans and one looping over
100,000-point cell queries, a unit posting at 10 Hz has every scan accepted, waits less
for each than a planner waits for its plan, and /healthz answers (a real server on
loopback; clients honour Retry-After as a fleet's client does). The writer's rate is
printed, not asserted: on a shared machine a time is the machine's (the fleet load
benchmark, tests/benchmarks/fleet_load.py, measures rates beside a peer)."""

import json
import statistics
import threading
import time

import httpx
from server_helpers import ServerProcess, scan_body

WRITER_HZ = 10.0
JSON = {"Content-Type": "application/json"}
SECONDS = 6.0


def test_a_10_hz_writer_keeps_its_rate_beside_50_planners_and_a_heavy_reader(tmp_path):
    with ServerProcess(tmp_path / "data", grid=(800, 800)) as server:  # 80 m x 80 m
        stop = threading.Event()
        shed = {"plans": 0, "queries": 0}
        served = {"plans": 0, "queries": 0}
        plan_waits: list[float] = []  # [s] request to reply, of the plans served

        def loop(kind, path, body):
            with httpx.Client(base_url=server.url, timeout=60.0) as client:
                while not stop.is_set():
                    t0 = time.perf_counter()
                    reply = client.post(path, content=body, headers=JSON)
                    if reply.status_code == 429:
                        shed[kind] += 1
                        stop.wait(float(reply.headers["Retry-After"]))
                    else:
                        assert reply.status_code == 200, reply.text
                        served[kind] += 1
                        if kind == "plans":
                            plan_waits.append(time.perf_counter() - t0)

        plan = json.dumps({"start": [0.5, 0.5], "goal": [79.5, 79.5], "algorithm": "dijkstra"})
        points = json.dumps(  # 1.5 MB of JSON, under the 2 MiB body limit
            {
                "points": [
                    [round(0.05 + (i % 800) * 0.1, 2), round(0.05 + (i // 800) * 0.1, 2)]
                    for i in range(100_000)
                ]
            }
        )  # encoded once: the test's own threads must not take the writer's time
        readers = [
            threading.Thread(target=loop, args=("plans", "/v1/plan", plan)) for _ in range(50)
        ]
        readers.append(threading.Thread(target=loop, args=("queries", "/v1/query/cells", points)))
        for thread in readers:
            thread.start()
        time.sleep(1.0)  # let the readers pile up first

        health: list[float] = []
        write_waits: list[float] = []  # [s] request to acknowledgement, of each scan
        posted = 0
        with httpx.Client(base_url=server.url, timeout=10.0) as writer:
            start = time.monotonic()
            slots = int(SECONDS * WRITER_HZ)
            for k in range(slots):
                t0 = time.perf_counter()
                reply = writer.post(
                    "/v1/scans", json=scan_body(stamp=k / WRITER_HZ, x=40.0, y=40.0)
                )
                write_waits.append(time.perf_counter() - t0)
                assert reply.status_code == 200, reply.text
                posted += 1
                if k % 5 == 0:
                    t0 = time.perf_counter()
                    assert writer.get("/healthz").status_code == 200
                    health.append(time.perf_counter() - t0)
                time.sleep(max(0.0, start + (k + 1) / WRITER_HZ - time.monotonic()))
            elapsed = time.monotonic() - start
        stop.set()
        for thread in readers:
            thread.join(timeout=120)

    rate = posted / elapsed
    print(f"writer {rate:.2f} Hz; healthz max {max(health) * 1e3:.0f} ms; "
          f"served {served}; shed {shed}")  # fmt: skip
    assert posted == int(SECONDS * WRITER_HZ)  # every scan acknowledged, none shed
    # Scans are not queued behind plans: a scan's median wait is below a plan's.
    assert statistics.median(write_waits) < statistics.median(plan_waits)
    assert served["plans"] > 0 and served["queries"] > 0  # the readers were served too
    assert shed["plans"] > 0  # 50 planners are more than one planner and its queue
