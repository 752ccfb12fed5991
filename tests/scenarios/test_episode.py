"""The run loop as an episode: reset(seed) / step(), observers on their own clocks,
identical step for step for one seed."""

from dataclasses import replace

import httpx
import pytest

from mapserver.client import MapClient
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.run.episode import Episode, RunOptions
from scenarios.spec.scenario import load_scenario

STEPS = 80


class Count:
    """An extra observer counting the steps it saw, every 1 s."""

    every_s = 1.0

    def __init__(self) -> None:
        self.seen: list[float] = []
        self.finished = False

    def observe(self, episode: Episode) -> None:
        self.seen.append(round(episode.now, 6))

    def finish(self, episode: Episode) -> None:
        self.finished = True


def trace(
    tmp_path, name: str, seed: int, count: Count | None = None, coordination: str | None = None
) -> list[tuple]:
    """(stamp, unit poses, paths sent, coordinator decisions so far, the scans' ranges)
    after every step; ``coordination``: the scenario's ``coordination.policy``."""
    noisy = {"units.lidar.range_noise": 0.02}  # so the seed shows in the scans
    if coordination is not None:
        noisy["coordination.policy"] = coordination
    scenario = replace(load_scenario("scenarios/tiny.yaml", noisy), duration=STEPS * 0.1)
    with EmbeddedServer(tmp_path / name, scenario.server_overrides()) as server:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            extra = [count] if count is not None else []
            with Episode(scenario, MapClient(http), RunOptions(), extra) as episode:
                episode.reset(seed=seed)
                steps = []
                while not episode.done:
                    report = episode.step()
                    poses = tuple(
                        (uid, u.drive.pose.x, u.drive.pose.y, u.drive.pose.yaw)
                        for uid, u in sorted(episode.sim.units.items())
                    )
                    ranges = tuple(s.ranges.tobytes() for s in report.sim.scans)
                    steps.append((report.now, poses, tuple(report.new_paths),
                                  len(episode.coordinator.log), ranges))  # fmt: skip
                record = episode.finish()
    assert record.metrics["sim_seconds"] == pytest.approx(STEPS * 0.1)
    return steps


def test_two_episodes_with_one_seed_are_identical_step_for_step(tmp_path):
    first = trace(tmp_path, "a", seed=3)
    second = trace(tmp_path, "b", seed=3)
    assert len(first) == STEPS
    for a, b in zip(first, second, strict=True):
        assert a == b
    other = trace(tmp_path, "c", seed=4)  # and the seed matters (LiDAR noise)
    assert [s[4] for s in other] != [s[4] for s in first]


def test_two_pibt_episodes_with_one_seed_are_identical_step_for_step(tmp_path):
    first = trace(tmp_path, "a", seed=3, coordination="pibt")
    second = trace(tmp_path, "b", seed=3, coordination="pibt")
    assert len(first) == STEPS
    for a, b in zip(first, second, strict=True):
        assert a == b
    assert first[-1][3] > 0  # the coordinator decided something


def test_observers_run_on_their_own_clock_and_finish_once(tmp_path):
    count = Count()
    trace(tmp_path, "a", seed=0, count=count)
    assert count.seen == [round(0.1 + k, 6) for k in range(8)]
    assert count.finished


def test_a_step_before_reset_is_refused(tmp_path):
    scenario = load_scenario("scenarios/tiny.yaml")
    with EmbeddedServer(tmp_path / "d", scenario.server_overrides()) as server:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            with pytest.raises(RuntimeError, match=r"reset\(\) the episode before step\(\)"):
                Episode(scenario, MapClient(http)).step()
