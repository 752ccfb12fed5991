"""Fair ingest against a real server on loopback (default settings): a greedy client
posting 16,384-beam scans flat out on several connections, ignoring Retry-After, gets
429s while 5 units at 10 Hz x 1,080 beams keep their rate and a 20 Hz x 2,000-beam unit
is never throttled; /metrics counts every 429. Counts are asserted, never times."""

import http.client
import math
import threading
import time
from collections import Counter

import httpx
import orjson
from server_helpers import ServerProcess

SECONDS = 8.0  # [s] the measured window
GREEDY_CONNECTIONS = 4
JSON = {"Content-Type": "application/json"}


def template(unit: str, beams: int, y: float) -> tuple[bytes, bytes]:
    """A valid full-turn scan body of ``unit`` split around its stamp's value."""
    body = orjson.dumps(
        {
            "unit_id": unit,
            "stamp": 0.0,
            "pose": {"x": 10.0, "y": y, "yaw": 0.0},
            "angle_min": -math.pi,
            "angle_increment": 2 * math.pi / beams,
            "range_min": 0.05,
            "range_max": 20.0,
            "ranges": [2.0 + (i % 7) * 0.1 for i in range(beams)],
        }
    )
    before, _, after = body.partition(b'"stamp":0.0')
    return before + b'"stamp":', after


def post(conn: http.client.HTTPConnection, body: bytes) -> tuple[int, str | None, bytes]:
    conn.request("POST", "/v1/scans", body=body, headers=JSON)
    reply = conn.getresponse()
    return reply.status, reply.getheader("Retry-After"), reply.read()


def test_a_greedy_client_is_throttled_while_normal_units_and_a_20_hz_lidar_keep_their_rate(
    tmp_path,
):
    with ServerProcess(tmp_path / "data") as server:
        port = server.port
        start = time.monotonic() + 1.0  # the greedy client starts a second before the units
        stop = threading.Event()
        lock = threading.Lock()
        last_stamp = [0.0]
        greedy: Counter = Counter()
        refusals: list[tuple[str | None, bytes]] = []

        def greedy_loop() -> None:
            before, after = template("greedy", 16384, 15.0)
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            while not stop.is_set():
                with lock:  # unique stamps on the units' clock
                    last_stamp[0] = max(last_stamp[0] + 1e-4, time.monotonic() - start + 1.0)
                    stamp = last_stamp[0]
                status, retry_after, text = post(conn, before + repr(stamp).encode() + after)
                with lock:
                    greedy[status] += 1
                    if status == 429 and len(refusals) < 3:
                        refusals.append((retry_after, text))
            conn.close()

        def unit_loop(unit: str, hz: float, beams: int, y: float, tally: Counter) -> None:
            before, after = template(unit, beams, y)
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            for k in range(int(SECONDS * hz)):
                time.sleep(max(0.0, start + k / hz - time.monotonic()))
                stamp = round(1.0 + k / hz, 4)
                status, _, _ = post(conn, before + repr(stamp).encode() + after)
                tally[status] += 1
            conn.close()

        normal = [Counter() for _ in range(5)]
        lidar: Counter = Counter()
        threads = [threading.Thread(target=greedy_loop) for _ in range(GREEDY_CONNECTIONS)]
        threads += [
            threading.Thread(target=unit_loop, args=(f"u{k}", 10.0, 1080, 2.0 + 2 * k, normal[k]))
            for k in range(5)
        ]
        threads.append(threading.Thread(target=unit_loop, args=("lidar", 20.0, 2000, 12.0, lidar)))
        for thread in threads[GREEDY_CONNECTIONS:]:
            thread.start()
        for thread in threads[:GREEDY_CONNECTIONS]:
            thread.start()
        for thread in threads[GREEDY_CONNECTIONS:]:
            thread.join(timeout=60)
        stop.set()
        for thread in threads[:GREEDY_CONNECTIONS]:
            thread.join(timeout=60)
        metrics = httpx.get(server.url + "/metrics").text

    slots = int(SECONDS * 10)
    for tally in normal:  # each unit kept >= 95 % of its scans, none throttled
        assert tally[200] >= 0.95 * slots, (tally, greedy)
        assert tally[429] == 0
    assert lidar == Counter({200: int(SECONDS * 20)}), lidar  # never throttled
    assert greedy[429] > 0 and greedy[200] > 0, greedy  # throttled, not shut out
    retry_after, text = refusals[0]
    assert retry_after is not None and int(retry_after) >= 1
    detail = orjson.loads(text)["detail"]
    assert "unit 'greedy'" in detail and "ingest.unit_beams_per_s" in detail, detail
    line = 'fleetmap_scans_throttled_total{limit="beams",scope="unit"}'
    (counted,) = [float(row.split()[-1]) for row in metrics.splitlines() if row.startswith(line)]
    assert counted == greedy[429]
