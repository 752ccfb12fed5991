"""Fleet throughput benchmark: whole scenario runs, edge-by-edge lanes against reserve-ahead.

Run: ``python tests/benchmarks/fleet.py [SCENARIO.yaml ...] [--all] [--floors] [--policy P]
[--seed N] [--duration S] [--coordinator NAME] [--one-way PATTERN] [--json]``

Each scenario (default: ``scenarios/static_shift.yaml``, ``scenarios/moved_pod.yaml``,
``scenarios/busy_shift.yaml``; ``--all``: every ``scenarios/*.yaml`` but ``tiny.yaml`` and
``thousand_units.yaml``;
``--floors``: also the two-way floors of ``tests/benchmarks/floors/``) is run end to end
in this process with ``scenarios.run.runner.run`` (its own embedded map server each
time, the scenario's seed), once per lane coordinator:

- ``edge-by-edge``: ``coordination: {policy: reserve_ahead, segment_m: null,
  reserve_ahead_m: 0}``, the coordinator as it was: lanes run junction to junction
  (stops included) and a unit is granted one lane at a time, when it arrives at the
  lane's tail;
- ``reserve-ahead``: ``coordination: {policy: reserve_ahead}`` with the file's lane split
  and reach (by default lanes split every 4 m so units can follow one another, and a
  unit asks for its next lanes a braking distance plus ``RESERVE_MARGIN_M`` before the
  end of what it holds: ``scenarios.spec.coordination.CoordinationSpec.settings``);
- ``pibt``: as ``reserve-ahead``, with ``coordination.policy`` set to ``pibt``
  (``planner.policy_pibt``: priority inheritance with backtracking).

The rest of the file's ``coordination`` section (dispatch, lane refresh, ...) is kept.

``--one-way aisles`` (or ``loops``, ``scenarios.spec.layout.ONE_WAY_PATTERNS``) runs each
scenario whose file sets no ``layout.one_way`` a second time with that traffic pattern,
right after it (row ``<name>+aisles``); that row's ``bound`` and ``free`` are the two-way
run's, so its ``of bnd`` and ``of free`` count its trips against what the two-way floor
allows.

Only the coordinator differs: both runs use the same drive controller (regulated pure
pursuit), the same navigator (A* on the shared costmap, line-of-sight shortcuts,
recovery), the same map server settings and the same trips. ``--policy``, ``--seed`` and
``--duration`` [s] override the scenario's map policy, run seed and length.

Printed, one row per (scenario, coordinator): ``trips`` (``tasks_completed``), ``bound``
(the congestion-free bound on trips: the trips released within the run, capped by
``units x sim_seconds / ideal_trip_s``, the trips each unit could drive back to back
alone at the run's mean ideal trip time, trips under way at the end counted as
fractions), ``of bnd`` (trips / bound), ``free`` (the trips of the scenario's
congestion-free run, ``scenarios.score.free_run``: the same trips, releases, dispatcher
and breakdowns, every trip driven in its own ideal time from where its unit stands, whole
trips only; the same for every coordinator), ``of free`` (trips / free: the share of what
the floor allows that the fleet did), ``dl/10uh`` (deadlocks broken per 10 unit-hours),
``trips/u.h`` (``trips_per_unit_hour``), ``ratio`` (``trip_time_ratio``: actual / ideal
trip time), ``eff`` (``fleet_efficiency``), ``v_mov`` (``mean_speed_moving`` [m/s]),
``moving`` (``moving_share``), ``dl`` (deadlocks broken), ``coll`` (collisions), sim
seconds, wall seconds of the run loop (``metrics["wall_seconds"]``: no server start-up),
``rtf`` (real-time factor, sim / wall), and the longest time any unit held a task without
moving (from the run record's unit samples, every 0.5 s: the longest stretch of
consecutive samples of one unit with the same task and its position within 0.05 m of
where the stretch began), with the unit and the sim time it began; ``running``: the same
with the samples of a unit broken down (the scenario's breakdown events) left out, so a
scheduled breakdown does not hide a unit stuck in traffic. See docs/throughput.md for
the metrics. ``--json`` prints every row as one JSON line after the table. Measures
only; tests assert behaviour. Wall times are of this machine: the map server shares its
cores with the simulator.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's directory comes first on sys.path and this file would
# shadow the ``fleet`` package: drop the directory before importing the project.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

from scenarios.run.record import RunRecord, UnitSample  # noqa: E402
from scenarios.run.runner import run  # noqa: E402
from scenarios.score.free_run import breakdown_spans, free_run  # noqa: E402
from scenarios.spec.layout import ONE_WAY_PATTERNS  # noqa: E402
from scenarios.spec.scenario import Scenario, load_scenario  # noqa: E402

ROOT = HERE.parents[1]
DEFAULT = ("static_shift.yaml", "moved_pod.yaml", "busy_shift.yaml")
# left out of --all: tiny is a smoke test, thousand_units the scale run of docs/scaling.md
# (a minute of it takes many minutes here); name them to run them
NOT_IN_ALL = ("tiny.yaml", "thousand_units.yaml")
FLOORS = HERE / "floors"
COORDINATORS = {  # name -> what it sets in the scenario's coordination section
    "edge-by-edge": {"policy": "reserve_ahead", "segment_m": None, "reserve_ahead_m": 0.0},
    "reserve-ahead": {"policy": "reserve_ahead"},
    "pibt": {"policy": "pibt"},
}
STILL_M = 0.05  # [m] a unit that stays this close to where it stood has not moved


@dataclass(frozen=True)
class Stall:
    """The longest time a unit held one task without moving: ``seconds`` from ``start``
    [s sim time], unit ``unit_id`` on task ``task``."""

    seconds: float
    unit_id: str
    start: float
    task: str


def longest_stall(
    samples: list[UnitSample],
    still_m: float = STILL_M,
    broken: dict[str, list[tuple[float, float]]] | None = None,
) -> Stall | None:
    """The longest stretch of consecutive samples of one unit with the same (non-None)
    task and the position within ``still_m`` [m] of the stretch's first sample; None if
    no unit ever held a task. ``broken``: unit id -> [(from, until)] [s] breakdowns; a
    sample of a unit broken down ends its stretch. Ties: the earliest, then the lowest
    unit id."""
    by_unit: dict[str, list[UnitSample]] = {}
    for s in samples:
        by_unit.setdefault(s.unit_id, []).append(s)
    best: Stall | None = None
    for uid in sorted(by_unit):
        spans = (broken or {}).get(uid, [])
        anchor: UnitSample | None = None
        for s in sorted(by_unit[uid], key=lambda s: s.stamp):
            if s.task is None or any(a <= s.stamp < b for a, b in spans):
                anchor = None
                continue
            if (
                anchor is None
                or s.task != anchor.task
                or math.hypot(s.x - anchor.x, s.y - anchor.y) > still_m
            ):
                anchor = s
            seconds = s.stamp - anchor.stamp
            if best is None or seconds > best.seconds + 1e-9:
                best = Stall(seconds, uid, anchor.stamp, anchor.task)
    return best


def stall_fields(prefix: str, stall: Stall | None) -> dict:
    return {
        f"{prefix}_s": round(stall.seconds, 3) if stall else None,
        f"{prefix}_unit": stall.unit_id if stall else None,
        f"{prefix}_start": round(stall.start, 3) if stall else None,
        f"{prefix}_task": stall.task if stall else None,
    }


def with_one_way(scenario: Scenario, pattern: str) -> Scenario:
    """``scenario`` with the ``layout.one_way`` pattern ``pattern`` over its lane grid,
    named ``<name>+<pattern>``."""
    layout = scenario.layout
    pairs = ONE_WAY_PATTERNS[pattern](len(layout.lane_x), len(layout.lane_y))
    return dataclasses.replace(scenario, name=f"{scenario.name}+{pattern}", one_way=pairs)


def row(
    scenario: Scenario,
    coordinator: str,
    record: RunRecord,
    total_wall: float,
    free_trips: int,
    two_way: dict | None = None,
) -> dict:
    """One table row (and JSON line) from a run's record; ``free_trips``: the trips of the
    scenario's congestion-free run (``scenarios.score.free_run``); ``two_way``: the row
    of the same floor run two-way, whose bounds this run's trips are counted against (a
    one-way pattern makes trips longer: its own would flatter it)."""
    m = record.metrics
    broken = breakdown_spans(scenario)
    sim_s, wall_s = float(m["sim_seconds"]), float(m["wall_seconds"])
    bound = trip_bound(scenario, m["units"], sim_s, m["ideal_trip_s"])
    free = free_trips if two_way is None else two_way["trips_free_run"]
    if two_way is not None:
        bound = two_way["trip_bound"]
    unit_hours = m["units"] * sim_s / 3600.0
    return {
        "scenario": scenario.name,
        "coordinator": coordinator,
        "policy": m["policy"],
        "seed": m["seed"],
        "units": m["units"],
        "trips": m["tasks_completed"],
        "trip_bound": round(bound, 2) if bound is not None else None,
        "trips_of_bound": round(m["tasks_completed"] / bound, 3) if bound else None,
        "trips_free_run": free,
        "trips_of_free_run": round(m["tasks_completed"] / free, 3) if free else None,
        "deadlocks_per_10_unit_hours": round(10 * m["deadlocks"] / unit_hours, 2)
        if unit_hours
        else None,
        "trips_per_unit_hour": m["trips_per_unit_hour"],
        "trip_time_ratio": m["trip_time_ratio"],
        "fleet_efficiency": m["fleet_efficiency"],
        "mean_speed_moving": m["mean_speed_moving"],
        "moving_share": m["moving_share"],
        "deadlocks": m["deadlocks"],
        "collisions": m["collisions"],
        "sim_seconds": sim_s,
        "wall_seconds": wall_s,
        "wall_seconds_total": round(total_wall, 3),
        "real_time_factor": round(sim_s / wall_s, 3) if wall_s > 0 else None,
        **stall_fields("longest_stall", longest_stall(record.units)),
        **stall_fields("longest_stall_running", longest_stall(record.units, broken=broken)),
    }


def trip_bound(
    scenario: Scenario, units: int, sim_s: float, ideal_trip_s: float | None
) -> float | None:
    """The congestion-free bound on trips (module docstring); None without a completed
    trip to take the ideal trip time from."""
    released = sum(1 for t in scenario.task_stream() if t.release < sim_s)
    if not ideal_trip_s:
        return None
    return min(float(released), units * sim_s / ideal_trip_s)


COLUMNS = (  # (title, key, format)
    ("scenario", "scenario", "<20"),
    ("coordinator", "coordinator", "<13"),
    ("trips", "trips", ">5"),
    ("bound", "trip_bound", ">6.1f"),
    ("of bnd", "trips_of_bound", ">6.2f"),
    ("free", "trips_free_run", ">5"),
    ("of free", "trips_of_free_run", ">7.2f"),
    ("trips/u.h", "trips_per_unit_hour", ">9.2f"),
    ("ratio", "trip_time_ratio", ">6.2f"),
    ("eff", "fleet_efficiency", ">6.3f"),
    ("v_mov", "mean_speed_moving", ">6.3f"),
    ("moving", "moving_share", ">6.3f"),
    ("dl", "deadlocks", ">3"),
    ("dl/10uh", "deadlocks_per_10_unit_hours", ">7.1f"),
    ("coll", "collisions", ">4"),
    ("sim s", "sim_seconds", ">6.0f"),
    ("wall s", "wall_seconds", ">7.1f"),
    ("rtf", "real_time_factor", ">5.2f"),
    ("stall s", "longest_stall_s", ">7.1f"),
    ("unit @ t", "longest_stall", "<13"),
    ("running", "longest_stall_running_s", ">7.1f"),
    ("unit @ t", "longest_stall_running", "<13"),
)


def cell(r: dict, key: str, fmt: str) -> str:
    """``r[key]`` formatted; a stall's "unit @ start"; "-" for None."""
    value = r.get(key)
    if key + "_unit" in r:
        unit, start = r[key + "_unit"], r[key + "_start"]
        value = None if unit is None else f"{unit} @ {start:.1f}"
    if value is None:
        value, fmt = "-", fmt[0] + fmt[1:].split(".")[0]
    return f"{value:{fmt}}"


def header() -> str:
    return "  ".join(
        f"{title:{fmt[0]}{fmt[1:].split('.')[0]}}" for title, _, fmt in COLUMNS
    ).rstrip()


def line(r: dict) -> str:
    return "  ".join(cell(r, key, fmt) for _, key, fmt in COLUMNS).rstrip()


def scenario_paths(given: list[str], everything: bool, floors: bool = False) -> list[Path]:
    """The scenario files to run, in order, without repeats."""
    paths = [Path(p) for p in given]
    if everything:
        paths += [
            p for p in sorted((ROOT / "scenarios").glob("*.yaml")) if p.name not in NOT_IN_ALL
        ]
    if floors:
        paths += sorted(FLOORS.glob("*.yaml"))
    if not paths and not floors:
        paths = [ROOT / "scenarios" / name for name in DEFAULT]
    seen: set[Path] = set()
    out = []
    for p in paths:
        if p.resolve() not in seen:
            seen.add(p.resolve())
            out.append(p)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", help="scenario YAML files (default: three)")
    parser.add_argument(
        "--all", action="store_true", help="every scenarios/*.yaml except tiny.yaml"
    )
    parser.add_argument(
        "--floors", action="store_true", help="also the two-way floors of tests/benchmarks/floors"
    )
    parser.add_argument(
        "--policy",
        help="map policy for every run (dual, decay, binary, sticky; default: each file's)",
    )
    parser.add_argument("--seed", type=int, help="run seed for every run")
    parser.add_argument("--duration", type=float, help="cut every run to this many sim [s]")
    parser.add_argument(
        "--coordinator",
        choices=sorted(COORDINATORS),
        action="append",
        help="run only this coordinator (repeatable; default: all)",
    )
    parser.add_argument(
        "--one-way",
        choices=sorted(ONE_WAY_PATTERNS),
        help="also run each two-way scenario with this layout.one_way pattern, its trips "
        "against the two-way run's bound (default: only as each file says)",
    )
    parser.add_argument("--json", action="store_true", help="print every row as a JSON line")
    args = parser.parse_args()

    coordinators = [c for c in COORDINATORS if c in (args.coordinator or COORDINATORS)]
    print(header(), flush=True)
    rows = []
    for path in scenario_paths(args.scenarios, args.all, args.floors):
        scenario = load_scenario(path)
        if args.policy is not None:
            scenario = scenario.with_policy(args.policy)
        if args.seed is not None:
            scenario = scenario.with_seed(args.seed)
        if args.duration is not None:
            scenario = dataclasses.replace(scenario, duration=args.duration)
        free_trips = free_run(scenario).trips  # the same for every coordinator
        for name in coordinators:
            t0 = time.perf_counter()
            coordination = dataclasses.replace(scenario.coordination, **COORDINATORS[name])
            record = run(dataclasses.replace(scenario, coordination=coordination))
            rows.append(row(scenario, name, record, time.perf_counter() - t0, free_trips))
            print(line(rows[-1]), flush=True)
            if args.one_way is None or scenario.one_way:
                continue
            two_way = rows[-1]
            patterned = with_one_way(scenario, args.one_way)
            t0 = time.perf_counter()
            record = run(dataclasses.replace(patterned, coordination=coordination))
            rows.append(row(patterned, name, record, time.perf_counter() - t0, free_trips, two_way))
            print(line(rows[-1]), flush=True)
    if args.json:
        for r in rows:
            print(json.dumps(r))


if __name__ == "__main__":
    main()
