"""Make ``docs/images/viewer.png``: the live viewer on a warehouse map, for the README.

Starts ``fleetmap serve`` on a free loopback port with a temporary data dir
(``scenarios.run.embedded_server``, the default 100 m x 50 m grid), posts the
scans of eight units patrolling the sample warehouse (``fleet.boxworld``), publishes the
units in every state of the viewer's legend (moving and waiting ones with paths planned
by the server; the frozen one sent to a goal inside a rack), and screenshots the page
with headless Chromium (Debian's ``chromium``).

    .venv/bin/python docs/make_picture.py [--out docs/images/viewer.png]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import httpx

from fleet.boxworld import sample_scans, warehouse_layout
from mapserver.client import MapClient, UnitState
from scenarios.run.embedded_server import EmbeddedServer

HERE = Path(__file__).resolve().parent
SIZE = (1400, 760)  # [px] window
SETTLE_MS = 6000  # [ms] of the page's (virtual) time before the screenshot


ACTIVITY = ["moving", "waiting", "moving", "broken_down", "dwelling", "moving", "frozen", "idle"]
"""What the k-th unit (by id) is shown doing: every state of the legend at least once."""
PLANS = ("moving", "waiting")  # the states shown with a planned path


def fill(client: MapClient) -> None:
    """Scans of eight patrolling units, then their states (``ACTIVITY``), those that
    drive or wait with paths planned by the server."""
    warehouse = warehouse_layout()
    scans = sample_scans(warehouse, 2400, beams=360, seed=4, units=8)
    for i in range(0, len(scans), 256):
        client.post_scans(scans[i : i + 256])
    last = {scan.unit_id: scan for scan in scans}
    junctions = [(x, y) for x in warehouse.lane_x for y in warehouse.lane_y]
    states = []
    for k, (unit_id, scan) in enumerate(sorted(last.items())):
        start, doing = (scan.pose.x, scan.pose.y), ACTIVITY[k]
        if doing == "frozen":  # sent into a rack: no admissible path, so it freezes
            rack = warehouse.world.boxes[[kind == "rack" for kind in warehouse.kinds]][3]
            goal = ((rack[0] + rack[2]) / 2, (rack[1] + rack[3]) / 2)
            reason = f"no path to ({goal[0]:.1f}, {goal[1]:.1f}): the goal is in a rack"
            states.append(
                UnitState.of(unit_id, scan.stamp, scan.pose, reason=reason, activity=doing)
            )
            continue
        path = ()
        if doing in PLANS:
            goal = junctions[(7 * k + 5) % len(junctions)]
            path = client.plan(start, goal, allow_unknown=True, unit_id=unit_id).path
        states.append(UnitState.of(unit_id, scan.stamp, scan.pose, path, activity=doing))
    client.publish_units(states)


def screenshot(url: str, out: Path) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile}", "--hide-scrollbars",
             f"--window-size={SIZE[0]},{SIZE[1]}", f"--virtual-time-budget={SETTLE_MS}",
             f"--screenshot={out}", url],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "images" / "viewer.png")
    args = parser.parse_args()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as data, EmbeddedServer(Path(data) / "map") as server:
        with httpx.Client(base_url=server.url) as http:
            fill(MapClient(http, timeout=60.0))
        screenshot(f"{server.url}/", args.out.resolve())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
