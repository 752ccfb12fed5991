"""Dropout benchmark: how many wall and rack cells each map policy forgets.

Run: ``python tests/benchmarks/dropout_walls.py [SCENARIO.yaml] [--policies P,...]
[--seed N] [--duration S] [--set KEY=VALUE ...] [--json]``

Runs the scenario (default ``scenarios/dropouts.yaml``: a static warehouse, LiDARs with
2 cm range noise and 5 % dropouts) once per policy (default decay, binary, sticky) with
``scenarios.run.runner.run``, and at the end compares the server's final costmap with the
ground-truth costmap the freeze classifier uses (``Episode.truth``):

- ``lethal``: cells lethal (254) in the truth;
- ``seen``: of those, cells the server's costmap does not show unknown (255);
- ``forgotten``: of those, cells the server shows free or graded (cost < 253): a wall or
  rack the map has cleared; ``free``: the part of them at cost 0; ``face``: the part of
  them on an obstacle's face (a 4-neighbour not lethal in the truth), the cells a LiDAR
  can hit; the rest lie inside walls and racks, where only beams that returned nothing
  (or passed a face cell by a corner) reach.

``--set map_server.sensor_model.p_miss_no_return=0.4`` (dotted scenario keys, values
read as YAML) runs other sensor settings, e.g. ``...p_miss_no_return=0.4`` with
``...no_return_range=null`` for no-return beams as strong as returns, out to range_max.
Measures only; tests assert behaviour.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's directory comes first on sys.path and this file would
# shadow the ``fleet`` package: drop the directory before importing the project.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import json  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL  # noqa: E402
from scenarios.run.runner import run  # noqa: E402
from scenarios.spec.scenario import load_scenario  # noqa: E402

ROOT = HERE.parents[1]
UNKNOWN = 255


class ForgottenWalls:
    """At the end of a run: truth-lethal cells the server's costmap shows below 253."""

    every_s = 1e9  # looks only at the end

    def observe(self, episode: Any) -> None:
        """Nothing during the run."""

    def finish(self, episode: Any) -> None:
        served = episode.synced().costmap().data
        lethal = episode.truth.costmap() == LETHAL
        inner = np.pad(lethal, 1, constant_values=True)
        inner = inner[:-2, 1:-1] & inner[2:, 1:-1] & inner[1:-1, :-2] & inner[1:-1, 2:]
        forgotten = lethal & (served < INSCRIBED)
        self.counts = {
            "lethal": int(lethal.sum()),
            "seen": int((lethal & (served != UNKNOWN)).sum()),
            "forgotten": int(forgotten.sum()),
            "free": int((forgotten & (served == FREE)).sum()),
            "face": int((forgotten & ~inner).sum()),
        }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", type=Path, default=ROOT / "scenarios/dropouts.yaml")
    parser.add_argument("--policies", default="decay,binary,sticky")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--duration", type=float, default=None, help="[s] sim time")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    overrides: dict[str, Any] = {}
    for item in args.set:
        key, _, value = item.partition("=")
        overrides[key] = yaml.safe_load(value)
    if args.duration is not None:
        overrides["duration"] = args.duration
    rows = []
    for policy in args.policies.split(","):
        scenario = load_scenario(args.scenario, {**overrides, "map_server.policy": policy})
        if args.seed is not None:
            scenario = scenario.with_seed(args.seed)
        counter = ForgottenWalls()
        record = run(scenario, observers=[counter])
        rows.append({"policy": policy, **counter.counts, "scans": record.metrics["scans_fused"]})
    names = ("lethal", "seen", "forgotten", "free", "face", "scans")
    print(f"{'policy':8}" + "".join(f" {n:>9}" for n in names))
    for r in rows:
        print(f"{r['policy']:8}" + "".join(f" {r[n]:9d}" for n in names))
    if args.json:
        for r in rows:
            print(json.dumps({"scenario": str(args.scenario), "overrides": overrides, **r}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
