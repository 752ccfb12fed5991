"""Load a scenario, run it, write its outputs: ``metrics.json``, ``freezes.json``,
``trips.json``, ``collisions.json``, ``report.png`` and ``replay.mcap`` in one folder."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mapserver.store.atomic import atomic_output
from scenarios.replay.mcap import REPLAY_FILENAME, write_replay
from scenarios.run.observers import Observer
from scenarios.run.runner import Progress, RunOptions, run
from scenarios.score.collisions_json import write_collisions
from scenarios.score.freezes_json import write_freezes
from scenarios.score.report import write_report
from scenarios.score.trips_json import write_trips
from scenarios.spec.scenario import ScenarioError, load_scenario

__all__ = ["ScenarioError", "execute"]

METRICS_FILENAME = "metrics.json"
FREEZES_FILENAME = "freezes.json"
TRIPS_FILENAME = "trips.json"
COLLISIONS_FILENAME = "collisions.json"
REPORT_FILENAME = "report.png"
TOKEN_ENV = "FLEETMAP_TOKEN"  # bearer token for ``--server`` when it needs one


def execute(
    scenario_path: Path,
    policy: str | None,
    seed: int | None,
    server_url: str | None,
    out_dir: Path,
    progress: Progress | None = None,
    options: RunOptions | None = None,
    announce: Callable[[str], None] | None = None,
    overrides: Mapping[str, Any] | None = None,
    observers: Sequence[Observer] = (),
) -> dict[str, object]:
    """Run the scenario at ``scenario_path`` (with ``policy`` and ``seed`` overrides) and
    write its outputs to ``out_dir``; returns the metrics. ``overrides``: dotted scenario
    keys set before validation (``{"map_server.decay.half_life_occupied": 10}``, a
    sweep's parameters; ``load_scenario``); ``observers``: more observers of the episode
    (``fleetmap run --foxglove``'s live stream)."""
    scenario = load_scenario(scenario_path, overrides)
    if policy is not None:
        scenario = scenario.with_policy(policy)
    if seed is not None:
        scenario = scenario.with_seed(seed)
    token = os.environ.get(TOKEN_ENV) if server_url else None
    record = run(
        scenario, server_url, options, progress, token=token, announce=announce,
        observers=observers,
    )  # fmt: skip
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_output(out / METRICS_FILENAME) as f:
        f.write((json.dumps(record.metrics, indent=2) + "\n").encode())
    write_freezes(record, out / FREEZES_FILENAME)
    write_trips(record, out / TRIPS_FILENAME)
    write_collisions(record, out / COLLISIONS_FILENAME)
    write_report(record, out / REPORT_FILENAME)
    write_replay(record, out / REPLAY_FILENAME)
    return record.metrics
