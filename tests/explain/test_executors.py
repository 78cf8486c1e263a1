"""An executor's thread across subchains (catanc.explain.executors): worked by hand, and its predicted
rates against the simulator.

The simulator serialises an executor's nodes on one thread (a run waits for the thread) and
holds one pending trigger per head, so it is an independent judge of the prediction: a node
whose thread is held by another's long runs runs at about the rate predicted, and one that is
never held long runs at its planned rate.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest
import yaml

from catanc.explain.analysis import explain_plan
from catanc.explain.executors import core_groups, member_warning, objective_as_run, plan_turns, rate_warnings
from catanc.model.build import build_problem
from catanc.model.executor_thread import ExecutorTurns, MemberRate
from catanc.model.problem import Problem
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


def nav2d(*, executor: bool, processes: bool = False) -> Spec:
    """nav2d with every compute time fixed at its planned mean (no growth, spikes or jitter): the
    simulator then runs what the plan assumes.  Without ``processes`` its deploy section is left out, so
    its Mapper's executor is the only one (the deploy section's Navigator runs GP and NC in one thread)."""
    data = copy.deepcopy(yaml.safe_load((SPECS / "nav2d.yaml").read_text()))
    if not executor:
        del data["executors"]
    if not processes:
        del data["deploy"]
    for node in data["nodes"].values():
        node.pop("workload", None)
    data["nodes"]["GL"]["compute_ms"] = 3.2  # its modes' mean
    return spec_of(data)


def long_and_short(long_ms: float, short_period_ms: float | None) -> Spec:
    """A 1 ms node and a long one in one executor, each heading its subchain; the short one's rate weighs most.

    With no slack: the simulator, these tests' judge, charges no runtime cost, so the thread gets every
    moment the core's other subchains leave, and the model, told the same, predicts that world.
    """
    data: dict[str, Any] = {
        "catan": 1,
        "app": "long_and_short",
        "nodes": {"a": {"compute_ms": 1.0}, "b": {"compute_ms": long_ms}, "out": {"scheduled": False}},
        "edges": [["a", "out"], ["b", "out"]],
        "subchains": {"short": ["a"], "long": ["b"]},
        "objective": [{"node": "a", "weight": 1.0}, {"node": "b", "weight": 0.05}],
        "executors": {"worker": ["a", "b"]},
        "schedule": {"slack": 0.0},
    }
    if short_period_ms is not None:
        data["constraints"] = [{"node": "a", "max_rate_hz": 1000.0 / short_period_ms}]
    return spec_of(data)


def simulated_hz(spec: Spec, cores: int, node: str) -> float:
    return simulate(Setup(spec, cores, DURATION_S, 0), "catan").nodes[node].rate_hz


def turns_of(spec: Spec, plan: Plan, problem: Problem) -> ExecutorTurns:
    turns = plan_turns(problem.executors[0], plan, problem, spec.schedule)
    assert turns is not None
    return turns


def losing(turns: ExecutorTurns) -> list[MemberRate]:
    return [rate for rate in turns.rates if rate.lost_share > 0.01]


def test_a_pair_that_fits_its_periods_is_predicted_and_runs_at_its_planned_rates() -> None:
    spec = spec_of(PAIR)
    plan, problem = planned(spec, 1)
    assert (plan.subchains["first"].fraction, plan.subchains["second"].fraction) == (1.0, 1.0)
    turns = turns_of(spec, plan, problem)
    # Nothing else on the core: the thread gets what the slack leaves, 0.95 of it.
    assert [member.share for member in turns.members] == [0.95, 0.95]
    a, b = turns.rates
    assert [a.longest_wait_ms, b.longest_wait_ms] == pytest.approx([2.0 / 0.95, 1.0 / 0.95])  # the other's compute
    assert [a.rate_hz, b.rate_hz] == pytest.approx([a.planned_hz, b.planned_hz])
    assert rate_warnings(plan, problem, spec.schedule) == []
    for name, node in (("first", "a"), ("second", "b")):
        assert simulated_hz(spec, 1, node) == pytest.approx(1000.0 / plan.subchains[name].period_ms, rel=0.05)


@pytest.mark.parametrize(("long_ms", "short_period_ms"), [(30.0, None), (60.0, None), (30.0, 5.0)])
def test_a_long_run_costs_the_short_node_the_triggers_predicted(long_ms: float, short_period_ms: float | None) -> None:
    spec = long_and_short(long_ms, short_period_ms)
    plan, problem = planned(spec, 1)
    turns = turns_of(spec, plan, problem)
    assert [(rate.node, rate.blocked_by) for rate in losing(turns)] == [("a", "b")]
    (rate,) = losing(turns)
    assert rate.rate_hz < 0.7 * rate.planned_hz  # far below the plan: the prediction is worth having
    assert simulated_hz(spec, 1, "a") == pytest.approx(rate.rate_hz, rel=0.05)
    assert simulated_hz(spec, 1, "b") == pytest.approx(1000.0 / plan.subchains["long"].period_ms, rel=0.02)


@pytest.mark.parametrize("cores", [1, 2, 3])
def test_nav2d_gl_and_the_slots_it_steals_run_at_about_their_predicted_rates(cores: int) -> None:
    spec = nav2d(executor=True)
    plan, problem = planned(spec, cores)
    turns = turns_of(spec, plan, problem)
    assert [(rate.node, rate.blocked_by) for rate in losing(turns)] == [("GL", "GM")]
    (rate,) = losing(turns)
    warnings = explain_plan(spec, problem, plan).warnings
    assert member_warning(turns, rate) in warnings
    assert rate.planned_hz == pytest.approx(1000.0 / plan.subchains["GL"].period_ms)
    result = simulate(Setup(spec, cores, DURATION_S, 0), "catan")
    # Simulated 60 s: GL 38.2, 34.3, 20.3 Hz against 39.2, 34.8, 21.1 predicted on 1, 2, 3 cores.
    assert result.nodes["GL"].rate_hz == pytest.approx(rate.rate_hz, rel=0.08)
    # NC, which GL outranks, loses its slots while GL waits late (on 1 and 2 cores it shares GL's core):
    # simulated 104.5 and 34.9 Hz against 105.9 and 37.4 predicted.
    stolen = {name: hz for name, hz in turns.stolen_hz.items() if hz > 0.0}
    assert sorted(stolen) == (["NC"] if cores < 3 else [])
    if stolen:
        predicted = 1000.0 / plan.subchains["NC"].period_ms - stolen["NC"]
        assert result.nodes["NC"].rate_hz == pytest.approx(predicted, rel=0.1)
        assert any(warning.startswith("executor mapper: subchain NC runs at about") for warning in warnings)
    # The same plan without the executor: GL keeps its rate, so the loss is the thread's.
    assert simulated_hz(nav2d(executor=False), cores, "GL") > 0.95 * rate.planned_hz


@pytest.mark.parametrize(("long_ms", "short_period_ms"), [(30.0, None), (30.0, 5.0)])
@pytest.mark.usefixtures("untraded")
def test_the_objective_as_run_counts_lost_triggers(long_ms: float, short_period_ms: float | None) -> None:
    spec = long_and_short(long_ms, short_period_ms)
    plan, problem = planned(spec, 1)
    short, long = plan.subchains["short"].period_ms, plan.subchains["long"].period_ms
    # Worked from the formula (nothing else on the core: the thread gets all of it while b runs):
    # a keeps 1/p_a - (1/p_b) (c_b / p_a - 2) runs a millisecond.
    rate_a = 1.0 / short - (1.0 / long) * (long_ms / short - 2.0)
    as_run = objective_as_run(plan, problem, spec.schedule)
    assert as_run == pytest.approx(1.0 / rate_a + 0.05 * long)
    assert as_run > 1.3 * plan.objective
    # The simulator's periods, weighted as the objective weighs them.
    result = simulate(Setup(spec, 1, DURATION_S, 0), "catan")
    simulated = 1000.0 / result.nodes["a"].rate_hz + 0.05 * 1000.0 / result.nodes["b"].rate_hz
    assert as_run == pytest.approx(simulated, rel=0.05)


def test_a_plan_whose_executor_loses_nothing_runs_as_planned() -> None:
    spec = spec_of(PAIR)
    plan, problem = planned(spec, 1)
    assert objective_as_run(plan, problem, spec.schedule) == pytest.approx(plan.objective)
    (group,) = core_groups(plan, spec.schedule)
    assert (group.subchains, group.cores) == (("first", "second"), 1)
    assert group.priorities["first"] > group.priorities["second"]  # first is planned to outrank (steal from) second
    assert plan.subchains["first"].priority > plan.subchains["second"].priority
