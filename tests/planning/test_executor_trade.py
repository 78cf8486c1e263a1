"""Stage II's executor trade (catanc/planning/stage2/turns.py): each member's ``k`` against the thread's losses.

Two judges: an enumeration of every members' ``k`` vector in a window above the least, each scored
with the executor model's objective as run (the search prunes and stops early; the enumeration
does neither), and the simulator, which serialises an executor's nodes on one thread and runs the
plans made with and without the trade.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.artifacts.runtime_table import plan_payload
from catanc.explain.executors import objective_as_run
from catanc.model.build import build_problem
from catanc.model.executor_thread import as_run_objective, periods_as_run
from catanc.model.metrics import Timing, bound_scale
from catanc.model.problem import Problem
from catanc.planning.planner import plan_problem
from catanc.planning.stage2 import turns as turns_module
from catanc.planning.stage2.base import Layout, SharedCore
from catanc.planning.stage2.turns import MOST_STEPS, LayoutTurns
from catanc.planning.types import Plan
from catanc.sim.metrics import PolicyResult
from catanc.sim.simulate import Setup, simulate
from tests.explain.test_executors import nav2d, planned
from tests.support.scenario_specs import SPECS
from tests.support.strategies import spec_of

WINDOW = {2: 60, 3: 15}
"""Each member's ``k`` is enumerated from its least to this many above it, by the number of members."""

WEIGHTLESS_APP = """\
catan: 1
app: weightless
nodes:
  s0n0: {compute_ms: 36.71, threads: {max: 3, speedup: [1.0, 1.102, 1.102]}}
  s0n1: {compute_ms: 1.9, threads: {max: 3, speedup: [1.0, 1.589, 1.827]}}
  s1n0: {compute_ms: 1.9, threads: {max: 2, speedup: [1.0, 1.0]}}
  s2n0: {compute_ms: 0.5}
  sink: {scheduled: false}
edges: [[s0n0, s0n1], [s2n0, sink]]
subchains: {s0: [s0n0, s0n1], s1: [s1n0], s2: [s2n0]}
objective:
  - {chains: {to: sink}, weight: 0.01}
  - {node: s0n0, weight: 0.0}
  - {node: s1n0, weight: 0.0}
constraints:
  - {chains: {to: sink}, max_response_ms: 5.0}
executors: {e0: [s0n0, s2n0], e1: [s0n1, s1n0]}
"""


@st.composite
def executor_apps(draw: st.DrawFn, member_counts: st.SearchStrategy[int] = st.integers(2, 3)) -> dict[str, Any]:
    """One core: an executor of 2-3 single-node subchains (one long run, short ones) and 0-2 other subchains.

    The long member comes first or last: last, it is the member the search walks over last, which loses no
    trigger itself (nav2d's GM), so a hint's downhill walk is what finds its ``k``.
    """
    members = draw(member_counts)
    others = draw(st.integers(0, 2))
    long_member = draw(st.sampled_from([0, members - 1]))
    weights = st.sampled_from([1.0, 0.5, 0.05, 0.005])
    nodes: dict[str, Any] = {"out": {"scheduled": False}}
    subchains: dict[str, list[str]] = {}
    objective = []
    constraints = []
    for index in range(members + others):
        name = f"m{index}" if index < members else f"o{index - members}"
        long = index == long_member
        compute = draw(st.floats(10.0, 80.0)) if long else draw(st.floats(0.3, 3.0))
        nodes[name] = {"compute_ms": round(compute, 2)}
        subchains[f"s_{name}"] = [name]
        objective.append({"node": name, "weight": draw(weights)})
        if not long and draw(st.booleans()):
            constraints.append({"node": name, "max_rate_hz": draw(st.sampled_from([50.0, 100.0, 200.0]))})
    document: dict[str, Any] = {
        "catan": 1,
        "app": "trade",
        "nodes": nodes,
        "edges": [[name, "out"] for name in nodes if name != "out"],
        "subchains": subchains,
        "objective": objective,
        "executors": {"worker": [f"m{index}" for index in range(members)]},
        "schedule": {"stealing": draw(st.booleans())},
    }
    if constraints:
        document["constraints"] = constraints
    return document


def least_spacing(plan: Plan, problem: Problem, names: tuple[str, ...]) -> dict[str, int]:
    """Each member's least ``k``: ``max(n, ceil(p_min / T))`` (docs/explanation/model.md section 4)."""
    length = plan.shared_cores[0].period_ms
    return {
        name: max(plan.runs[name], math.ceil(problem.subchain(name).min_period_ms / length - 1e-9)) for name in names
    }


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=executor_apps(), offsets=st.lists(st.integers(-3, 80), min_size=3, max_size=3))
def test_the_trade_is_the_best_spacing_by_enumeration(document: dict[str, Any], offsets: list[int]) -> None:
    spec = spec_of(document)
    problem = build_problem(spec)
    plan = plan_problem(problem, spec.schedule, 1)
    (core,) = plan.shared_cores
    layout = Layout((), (SharedCore(core.core, core.order),))
    turns = LayoutTurns.of(problem, layout, spec.schedule)
    assert turns is not None
    names = turns.members
    length = core.period_ms
    least = least_spacing(plan, problem, names)
    timings = {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in plan.subchains.items()}
    for name in names:
        timings[name] = Timing(least[name] * length, timings[name].latency_ms)
    allowed = max(1.0, bound_scale(problem, timings)) * (1 + 1e-6)
    found = turns.best_spacing(problem, timings, dict.fromkeys(names, length), least, allowed)
    assert found is not None
    value, spacing, periods = found
    assert all(least[name] <= spacing[name] <= least[name] + MOST_STEPS for name in names)
    chosen = {**timings, **{name: Timing(spacing[name] * length, timings[name].latency_ms) for name in names}}
    assert bound_scale(problem, chosen) <= allowed
    assert value == pytest.approx(as_run_objective(problem, chosen, turns.groups), rel=1e-12)
    assert periods == periods_as_run(problem, chosen, turns.groups)  # the periods as run handed over are these
    best = math.inf
    window = WINDOW[len(names)]
    for ks in itertools.product(*(range(least[name], least[name] + window + 1) for name in names)):
        spaced = {name: Timing(k * length, timings[name].latency_ms) for name, k in zip(names, ks, strict=True)}
        trial = {**timings, **spaced}
        if bound_scale(problem, trial) <= allowed:
            best = min(best, as_run_objective(problem, trial, turns.groups))
    assert value <= best * (1 + 1e-9)
    # The plan is the one the search found: the same objective as run.
    assert plan.objective_as_run == pytest.approx(value, rel=1e-9)
    # A re-solve's hint (its last k, anywhere around the answer) changes how the search walks, not its answer.
    hint = {name: least[name] + offset for name, offset in zip(names, offsets, strict=False)}
    assert turns.best_spacing(problem, timings, dict.fromkeys(names, length), least, allowed, hint=hint) == found


def trade_inputs(
    document: dict[str, Any],
) -> tuple[Problem, LayoutTurns, float, dict[str, int], dict[str, Timing], float]:
    """The search's inputs as Stage II gives them on the app's one core: the problem, its turns, the core's
    length, each member's least ``k``, the timings at those, and the bounds' allowed scale."""
    spec = spec_of(document)
    problem = build_problem(spec)
    plan = plan_problem(problem, spec.schedule, 1)
    (core,) = plan.shared_cores
    turns = LayoutTurns.of(problem, Layout((), (SharedCore(core.core, core.order),)), spec.schedule)
    assert turns is not None
    least = least_spacing(plan, problem, turns.members)
    timings = {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in plan.subchains.items()}
    for name in turns.members:
        timings[name] = Timing(least[name] * core.period_ms, timings[name].latency_ms)
    allowed = max(1.0, bound_scale(problem, timings)) * (1 + 1e-6)
    return problem, turns, core.period_ms, least, timings, allowed


def assert_spacing_a_member_lengthens_no_other_period(
    problem: Problem,
    turns: LayoutTurns,
    timings: dict[str, Timing],
    *,
    length: float,
    least: dict[str, int],
    steps: int,
) -> None:
    """The premise of the search's floor (``LayoutTurns._floor_periods``): one member's ``k`` longer by
    ``steps``, every other subchain's period as run is as long or shorter (fewer holds, later stealing)."""
    before = periods_as_run(problem, timings, turns.groups)
    for name in turns.members:
        spaced = {**timings, name: Timing((least[name] + steps) * length, timings[name].latency_ms)}
        after = periods_as_run(problem, spaced, turns.groups)
        for other, period in before.items():
            if other != name:
                assert after[other] <= period * (1 + 1e-12), (name, other, period, after[other])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=executor_apps(), steps=st.integers(1, MOST_STEPS))
def test_spacing_a_member_out_lengthens_no_other_subchain_as_run(document: dict[str, Any], steps: int) -> None:
    problem, turns, length, least, timings, _ = trade_inputs(document)
    assert_spacing_a_member_lengthens_no_other_period(problem, turns, timings, length=length, least=least, steps=steps)


@pytest.mark.parametrize("steps", [1, 7, 60, MOST_STEPS])
def test_spacing_out_one_process_thread_lengthens_nothing_in_the_other(steps: int) -> None:
    # nav2d on 1 core with its deploy section: the Mapper's and the Navigator's threads share the core, so
    # one's spacing reaches the other's members through the core's load.
    spec = nav2d(executor=True, processes=True)
    plan, problem = planned(spec, 1)
    (core,) = plan.shared_cores
    turns = LayoutTurns.of(problem, Layout((), (SharedCore(core.core, core.order),)), spec.schedule)
    assert turns is not None
    assert len(turns_module.member_blocks(problem, turns.members)) == 2
    least = least_spacing(plan, problem, turns.members)
    timings = {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in plan.subchains.items()}
    for name in turns.members:
        timings[name] = Timing(least[name] * core.period_ms, timings[name].latency_ms)
    assert_spacing_a_member_lengthens_no_other_period(
        problem, turns, timings, length=core.period_ms, least=least, steps=steps
    )


@st.composite
def apps_with_a_member_nothing_weighs(draw: st.DrawFn) -> dict[str, Any]:
    """:func:`executor_apps` of two members, one of them weighted 0 (its own rate is worth nothing)."""
    document = draw(executor_apps(member_counts=st.just(2)))
    zero = draw(st.sampled_from(["m0", "m1"]))
    document["objective"] = [
        {**term, "weight": 0.0} if term.get("node") == zero else term for term in document["objective"]
    ]
    return document


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=apps_with_a_member_nothing_weighs())
def test_a_member_nothing_weighs_gets_the_least_k_as_good_as_any_up_to_the_cap(document: dict[str, Any]) -> None:
    """Its every ``k`` up to the cap enumerated (the other member's in a window): the search's answer is as good
    as the best, and no shorter ``k`` of it is (the search bisects where the enumeration walks)."""
    problem, turns, length, least, timings, allowed = trade_inputs(document)
    names = turns.members
    (zero,) = (name for name in names if problem.importance()[name] == 0.0)
    found = turns.best_spacing(problem, timings, dict.fromkeys(names, length), least, allowed)
    assert found is not None
    value, spacing, _ = found
    best, best_shorter = math.inf, math.inf
    ranges = [range(least[n], least[n] + (MOST_STEPS if n == zero else WINDOW[3]) + 1) for n in names]
    for ks in itertools.product(*ranges):
        spaced = {name: Timing(k * length, timings[name].latency_ms) for name, k in zip(names, ks, strict=True)}
        trial = {**timings, **spaced}
        if bound_scale(problem, trial) > allowed:
            continue
        as_run = as_run_objective(problem, trial, turns.groups)
        best = min(best, as_run)
        if dict(zip(names, ks, strict=True))[zero] < spacing[zero]:
            best_shorter = min(best_shorter, as_run)
    assert value <= best * (1 + 1e-9)
    assert best_shorter > value


def test_members_nothing_weighs_are_searched_in_a_few_thousand_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    """Three members of two executors on one core, two weighted 0 and one only through a 0.01 chain (a
    hypothesis draw that took CI's simulator minutes a re-solve: two million objectives as run for one plan).
    Counted, not timed: each member nothing weighs costs ~20 searches below it, not 1000."""
    evaluated = 0

    def counted(*args: Any, **kwargs: Any) -> dict[str, float]:
        nonlocal evaluated
        evaluated += 1
        return periods_as_run(*args, **kwargs)

    monkeypatch.setattr(turns_module, "periods_as_run", counted)
    document = yaml.safe_load(WEIGHTLESS_APP)
    spec = spec_of(document)
    problem = build_problem(spec)
    plan = plan_problem(problem, spec.schedule, 1)
    assert plan.objective_as_run is not None
    assert evaluated <= 2000


def run_objective(problem: Problem, result: PolicyResult) -> float:
    """The objective of a simulated run: the weights times the mean responses and the simulated periods."""
    responses = {chain.nodes: chain.response.mean for chain in result.chains if chain.response is not None}
    total = math.fsum(
        term.weight * responses[tuple(problem.chains[term.chain].nodes)] for term in problem.response_terms
    )
    return total + math.fsum(term.weight * 1000.0 / result.nodes[term.node].rate_hz for term in problem.period_terms)


def simulated(cores: int) -> tuple[Plan, Problem, PolicyResult]:
    spec = nav2d(executor=True)  # every compute time fixed at its mean
    plan, problem = planned(spec, cores)
    return plan, problem, simulate(Setup(spec, cores, 30.0, 0), "catan")


@pytest.fixture(scope="module", params=[1, 2, 3])
def nav2d_cores(request: pytest.FixtureRequest) -> int:
    return int(request.param)


@pytest.fixture(scope="module")
def nav2d_untraded(nav2d_cores: int) -> tuple[int, Plan, Problem, PolicyResult]:
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(LayoutTurns, "best_spacing", lambda *_args, **_kwargs: None)
        return (nav2d_cores, *simulated(nav2d_cores))


@pytest.fixture(scope="module")
def nav2d_traded(nav2d_cores: int) -> tuple[int, Plan, Problem, PolicyResult]:
    return (nav2d_cores, *simulated(nav2d_cores))


def test_nav2d_runs_better_with_the_trade_in_the_simulator(
    nav2d_untraded: tuple[int, Plan, Problem, PolicyResult],
    nav2d_traded: tuple[int, Plan, Problem, PolicyResult],
) -> None:
    # Simulated 30 s (2026-11-28, the thread's share less the slack): the run's objective 38.04 -> 37.90,
    # 32.24 -> 30.21 (-6%), 40.51 -> 29.32 (-28%) on 1, 2, 3 cores; GL 38.0 -> 38.1, 34.3 -> 40.6, 20.3 -> 40.1 Hz.
    cores, before_plan, problem, before = nav2d_untraded
    _, plan, _, after = nav2d_traded
    assert plan.objective_as_run is not None
    if cores == 1:  # GM's 150 ms run near its least k already: little to trade (97 -> 101 periods)
        assert run_objective(problem, after) <= run_objective(problem, before) * 1.01
        return
    assert plan.every["GM"] > before_plan.every.get("GM", 0) or plan.allocation != before_plan.allocation
    assert run_objective(problem, after) < run_objective(problem, before) * (0.97 if cores == 2 else 0.8)
    assert after.nodes["GL"].rate_hz > before.nodes["GL"].rate_hz * (1.1 if cores == 2 else 1.6)


def test_the_runtime_table_promises_the_rates_the_simulator_runs(
    nav2d_traded: tuple[int, Plan, Problem, PolicyResult],
) -> None:
    # runtime.json's rate_as_run_hz (what `catanc report` holds a run to) where the thread takes some of a
    # planned rate.  Simulated 30 s (2026-11-28), promised -> run: 1 core GL 38.75 -> 38.10 Hz, NC 104.71 ->
    # 103.63; 2 cores GL 40.21 -> 40.57, NC 40.98 -> 40.33; 3 cores GL 39.67 -> 40.07.  The rest within 2%.
    cores, plan, problem, result = nav2d_traded
    table = plan_payload(plan, problem)["subchains"]
    promised = {name: entry["rate_as_run_hz"] for name, entry in table.items() if "rate_as_run_hz" in entry}
    assert "GL" in promised, f"{cores} cores: GL loses triggers to GM's runs in their thread"
    for name, hz in promised.items():
        assert hz < table[name]["rate_hz"]
        head = problem.subchain(name).nodes[0]
        assert result.nodes[head].rate_hz == pytest.approx(hz, rel=0.05), name
        # What `simulate` shows beside the run: the promise of the plan in force at the end (re-solved with
        # the compute times it measured), as close.
        promised_at_end = result.nodes[head].planned_hz
        assert promised_at_end is not None
        assert result.nodes[head].rate_hz == pytest.approx(promised_at_end, rel=0.05), name
    for name, entry in table.items():  # the rest run as planned (GL's thread's other member, GM, included)
        if name not in promised and entry["rate_hz"] is not None and not problem.subchain(name).batch:
            head = problem.subchain(name).nodes[0]
            assert result.nodes[head].rate_hz == pytest.approx(entry["rate_hz"], rel=0.05), name


def test_a_thread_of_batch_members_only_is_scored_as_run() -> None:
    # nav2d with GM batch as well: no member has a k to trade, but GM's runs still hold GL's thread, so the
    # plan is ranked with the triggers lost counted (before the fix its objective as run was the planned one).
    data = yaml.safe_load((SPECS / "nav2d.yaml").read_text())
    data["nodes"]["GM"]["batch"] = {"output_rate_hz": 1.0}
    spec = spec_of(data)
    plan, problem = planned(spec, 1)
    assert plan.objective_as_run is not None
    assert plan.objective_as_run > plan.objective * 1.01
    assert plan.objective_as_run == pytest.approx(objective_as_run(plan, problem, spec.schedule))
