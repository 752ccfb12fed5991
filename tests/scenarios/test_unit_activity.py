"""What each unit does (``scenarios.run.agents.activity``), as the run publishes it to the
map server's live viewer (``UnitPublisher``, ``POST /v1/units``)."""

import math
from types import SimpleNamespace

import httpx
import pytest
from scenario_helpers import TINY

from mapserver.client import ACTIVITIES, MapClient
from planner.navigator import Command
from scenarios.run.agents import AgentState, activity
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.run.episode import Episode, RunOptions
from scenarios.spec.scenario import load_scenario

READY = SimpleNamespace(broken_until=-math.inf, dwell_until=None)


def state(kind: str, has_task: bool = True, blocked: str | None = None) -> AgentState:
    return AgentState(Command(kind), has_task, blocked, (), None)


@pytest.mark.parametrize(
    "agent, tick, expected",
    [
        (READY, state("follow"), "moving"),
        (READY, state("rotate"), "moving"),  # turning in place
        (READY, state("stop"), "waiting"),  # a task, no lane granted yet: traffic
        (READY, state("idle", has_task=False), "idle"),
        (READY, state("stop", blocked="no path to (1.00, 2.00)"), "frozen"),
        (READY, state("rotate", blocked="no path to (1.00, 2.00)"), "frozen"),  # looks again
        (SimpleNamespace(broken_until=-math.inf, dwell_until=9.0), state("stop"), "dwelling"),
        (SimpleNamespace(broken_until=-math.inf, dwell_until=5.0), state("stop"), "waiting"),
        (SimpleNamespace(broken_until=9.0, dwell_until=9.0), state("stop"), "broken_down"),
        (
            SimpleNamespace(broken_until=9.0, dwell_until=None),
            state("stop", blocked="x"),
            "broken_down",
        ),
    ],
)
def test_activity_at_five_seconds(agent, tick, expected):
    assert activity(5.0, agent, tick) == expected
    assert expected in ACTIVITIES


class BoardReader:
    """Beside the publisher (same clock, run after it): the board against each agent."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.seen: list[tuple[float, str, str | None, bool, str]] = []

    def observe(self, episode: Episode) -> None:
        now = episode.report.now
        for unit in episode.client.units():
            agent = episode.agents[unit.unit_id]
            expected = activity(now, agent, episode.report.states[unit.unit_id])
            self.seen.append((now, unit.unit_id, unit.activity, unit.frozen, expected))

    def finish(self, episode: Episode) -> None:
        return None


def test_a_run_publishes_each_units_activity_and_a_breakdown_shows(tmp_path):
    text = TINY.read_text().replace(
        "events:\n", "events:\n  - {at: 2.0, breakdown: u2, duration: 4.0}\n"
    )
    path = tmp_path / "tiny_breakdown.yaml"
    path.write_text(text.replace("duration: 20.0", "duration: 10.0").replace("at: 12.0", "at: 8.0"))
    scenario = load_scenario(path)
    options = RunOptions()
    reader = BoardReader(options.record_units_s)
    with EmbeddedServer(tmp_path / "map", scenario.server_overrides()) as server:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            with Episode(scenario, MapClient(http), options, [reader]) as episode:
                episode.reset(seed=0)
                while not episode.done:
                    episode.step()
    assert len(reader.seen) == 2 * 20  # two units, every 0.5 s for 10 s
    for now, uid, posted, frozen, expected in reader.seen:
        assert posted == expected, (now, uid)
        assert frozen == (posted == "frozen")
    u2 = {now: posted for now, uid, posted, _, _ in reader.seen if uid == "u2"}
    assert {u2[t] for t in u2 if 2.05 < t < 5.95} == {"broken_down"}
    assert u2[min(u2)] != "broken_down" and u2[max(u2)] != "broken_down"
    assert {"moving", "broken_down"} <= {posted for _, _, posted, _, _ in reader.seen}
