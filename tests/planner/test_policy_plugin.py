"""A new lane coordination policy is one file and one registration: this module adds
``in_order`` (a trivial policy: units at nodes go in natural id order, each granted its
next edge when it is free), and the coordinator drives it, hook by hook in set order, and
a scenario file selects it."""

from pathlib import Path

import pytest
from lane_helpers import Drive, grid_graph

from planner.coordination_state import CoordinationState, CoordinatorSettings, Tick, Unit
from planner.coordinator import LaneCoordinator
from planner.decisions import Action, Cause
from planner.policy import CoordinationPolicy, make_policies, policy_names, register_policy
from scenarios.spec.scenario import ScenarioError, load_scenario

TINY = Path("scenarios/tiny.yaml")
HEARD: list[tuple[str, str]] = []  # (policy, hook), as the driver calls them


class InOrder(CoordinationPolicy):
    """Units at nodes, in natural id order: granted their next edge when it is free, else
    they wait (recorded when whom they wait for changes). Leaves stranded units on."""

    name = "in_order"

    def decide(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> list[Unit]:
        HEARD.append((self.name, "decide"))
        for u in ready:
            if u.turn_back:
                continue
            blockers = state.step_blockers(u.uid, u.route)
            if not blockers:
                state.grant(tick, u, u.route[1], Action.GRANT, Cause.ROUTE, "in order")
            elif blockers != u.waiting:
                u.waiting = blockers
                state.say(tick, u, Action.WAIT, Cause.NODE_HELD, "in order", u.edge, blockers)
        return [u for u in ready if u.turn_back]

    def settle(self, state: CoordinationState, tick: Tick) -> None:
        HEARD.append((self.name, "settle"))


class Listener(CoordinationPolicy):
    """Hears every hook (after ``InOrder`` in the set) and what is left to decide."""

    name = "listener"

    def approaching(self, state: CoordinationState, tick: Tick, unit: Unit, to_head: float):
        HEARD.append((self.name, f"approaching {unit.uid}"))

    def decide(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> list[Unit]:
        HEARD.append((self.name, f"decide {len(ready)}"))
        return ready

    def settle(self, state: CoordinationState, tick: Tick) -> None:
        HEARD.append((self.name, "settle"))


register_policy("in_order", lambda settings: (InOrder(), Listener()))


def test_the_driver_runs_a_registered_policy_hook_by_hook_in_set_order():
    assert "in_order" in policy_names()
    coord = LaneCoordinator(grid_graph(3, 1), policy="in_order")
    assert [p.name for p in coord.policies] == ["in_order", "listener"]
    drive = Drive(coord)
    drive.add("u2", "n1_0", "n2_0")
    drive.add("u1", "n0_0", "n1_0")  # behind u2: waits until u2 has left n1_0
    HEARD.clear()
    drive.step()  # both at nodes: u1 waits for u2, u2 is granted
    assert HEARD == [
        ("in_order", "decide"),
        ("listener", "decide 0"),
        ("in_order", "settle"),
        ("listener", "settle"),
    ]
    first = [(d.unit, d.action, d.cause) for d in coord.log if d.time == drive.now]
    assert first == [("u1", Action.WAIT, Cause.NODE_HELD), ("u2", Action.GRANT, Cause.ROUTE)]
    HEARD.clear()
    drive.step()  # u2 drives its lane: the driver tells every policy how near it is
    assert HEARD[0] == ("listener", "approaching u2")
    assert drive.run(40) is not None  # the policy alone gets both units home
    assert coord.status("u1").node == "n1_0" and coord.status("u2").node == "n2_0"


@pytest.mark.sim  # the episode module imports the simulator
def test_a_scenario_file_selects_the_registered_policy():
    from scenarios.run.episode import _coordinator

    scenario = load_scenario(TINY, {"coordination.policy": "in_order"})
    assert scenario.coordination.policy == "in_order"
    units = scenario.unit_specs()
    coord = _coordinator(scenario.build_lane_graph(), None, units, scenario.coordination)
    assert coord.policy == "in_order"
    assert [type(p) for p in coord.policies] == [InOrder, Listener]


def test_names_are_registered_once_and_unknown_ones_are_refused():
    with pytest.raises(ValueError, match="policy 'in_order' is registered already"):
        register_policy("in_order", lambda settings: ())
    with pytest.raises(ValueError, match="a policy name must be an identifier, got 'in order'"):
        register_policy("in order", lambda settings: ())
    with pytest.raises(ValueError, match=r"policy must be one of reserve_ahead, pibt, .*got 'x'"):
        make_policies("x", CoordinatorSettings())
    with pytest.raises(ScenarioError, match=r"coordination\.policy.*in_order, got 'x'"):
        load_scenario(TINY, {"coordination.policy": "x"})
