"""An executor's wait for its thread (catanc.explain.executors): worked by hand, and its warning against the simulator.

The simulator serialises an executor's nodes on one thread (a run waits for the thread) and
triggers a head only when its last run is done, so it is an independent judge of the warning's
claim: a node that may wait longer than its period runs below its planned rate, and one that
does not runs at it.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest
import yaml

from catanc.core.build import build_problem
from catanc.core.problem import Problem
from catanc.explain.analysis import explain_plan
from catanc.explain.executors import executor_waits, lost_triggers
from catanc.planning.planner import plan_problem
from catanc.planning.types import Plan
from catanc.sim.simulate import Setup, simulate
from catanc.spec.language import Spec
from tests.support.scenario_specs import SPECS
from tests.support.strategies import spec_of

# Two single-node subchains on one core, in one executor: each runs whole in its slot every period.
PAIR: dict[str, Any] = {
    "catan": 1,
    "app": "pair",
    "nodes": {"a": {"compute_ms": 1.0}, "b": {"compute_ms": 2.0}, "out": {"scheduled": False}},
    "edges": [["a", "b"], ["b", "out"]],
    "subchains": {"first": ["a"], "second": ["b"]},
    "objective": [{"chain": ["a", "b", "out"], "weight": 1.0}],
    "executors": {"worker": ["a", "b"]},
}
DURATION_S = 20.0


def planned(spec: Spec, cores: int) -> tuple[Plan, Problem]:
    problem = build_problem(spec)
    return plan_problem(problem, spec.schedule, cores), problem


def nav2d(*, executor: bool) -> Spec:
    data = yaml.safe_load((SPECS / "nav2d.yaml").read_text())
    if not executor:
        data = copy.deepcopy(data)
        del data["executors"]
    return spec_of(data)


def simulated_hz(spec: Spec, cores: int, node: str) -> float:
    return simulate(Setup(spec, cores, DURATION_S, 0), "catan").nodes[node].rate_hz


def test_the_waits_of_a_pair_worked_by_hand() -> None:
    plan, problem = planned(spec_of(PAIR), 1)
    (core,) = plan.shared_cores
    first, second = plan.subchains["first"], plan.subchains["second"]
    assert (first.fraction, second.fraction) == (1.0, 1.0)  # whole runs each period: slices 1 and 2 ms
    share = 3.0 / core.period_ms  # the executor's slices over T
    waits = {wait.node: wait for wait in executor_waits(problem.executors[0], plan, problem)}
    assert waits["a"].wait_ms == pytest.approx(2.0 / share)  # a waits for b's 2 ms at the executor's share
    assert waits["b"].wait_ms == pytest.approx(1.0 / share)
    assert waits["a"].wait_ms < first.period_ms  # both fit in a period: T covers the two slices and more
    assert lost_triggers(plan, problem) == []


def test_a_pair_that_fits_its_periods_runs_at_its_planned_rates() -> None:
    spec = spec_of(PAIR)
    plan, _problem = planned(spec, 1)
    for name, node in (("first", "a"), ("second", "b")):
        assert simulated_hz(spec, 1, node) == pytest.approx(1000.0 / plan.subchains[name].period_ms, rel=0.05)


@pytest.mark.parametrize("cores", [1, 3])
def test_nav2d_gl_waits_longer_than_its_period_and_runs_below_its_planned_rate(cores: int) -> None:
    spec = nav2d(executor=True)
    plan, problem = planned(spec, cores)
    lost = lost_triggers(plan, problem)
    assert [(wait.node, wait.behind) for wait in lost] == [("GL", "GM")]
    assert lost[0].warning in explain_plan(spec, problem, plan).warnings
    planned_hz = 1000.0 / plan.subchains["GL"].period_ms
    assert simulated_hz(spec, cores, "GL") < 0.9 * planned_hz
    # The same plan without the executor: GL keeps its rate, so the loss is the wait's.
    assert simulated_hz(nav2d(executor=False), cores, "GL") > 0.95 * planned_hz
