"""Re-planning with drifting compute times: the warm path against fresh, independent solves."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from catanc.errors import UsageError
from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.model.metrics import Timing, bound_scale, objective
from catanc.model.problem import Problem
from catanc.planning.planner import plan, plan_problem
from catanc.planning.replan import RUNTIME_GAP, Replanner
from catanc.planning.stage2 import solve as solve_module
from catanc.planning.stage2.base import Layout, SharedCore
from catanc.planning.stage2.integer import solve_integer
from catanc.planning.stage2.relaxed import RelaxedStage2
from catanc.planning.stage2.solve import solve_layout
from catanc.planning.stage2.turns import LayoutTurns
from catanc.planning.types import Plan
from tests.planning.test_stage2_integer import enumerate_best

SPECS = Path(__file__).parents[2] / "specs"


def searched(result: Plan, problem: Problem) -> float:
    """The plan's objective with every shared non-batch subchain triggered every least ``k`` periods: what
    Stage II's integer search minimises (and its gap bounds) before the executor trade spaces out nav2d's
    GM (catanc/planning/stage2/turns.py)."""
    lengths = {name: core.period_ms for core in result.shared_cores for name in core.order}
    timings = {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in result.subchains.items()}
    return at_least_spacing(problem, timings, result.runs, lengths)


def at_least_spacing(
    problem: Problem, timings: dict[str, Timing], runs: dict[str, int], lengths: dict[str, float]
) -> float:
    """The objective at ``timings`` with each of ``runs``' subchains every ``max(n, ceil(p_min / T))`` periods."""
    spaced = dict(timings)
    for name, n in runs.items():
        least = max(n, math.ceil(problem.subchain(name).min_period_ms / lengths[name] - 1e-9))
        spaced[name] = Timing(least * lengths[name], timings[name].latency_ms)
    return objective(problem, spaced)


def layout_of(result: Plan) -> Layout:
    return Layout(result.allocation.dedicated, tuple(SharedCore(c.core, c.order) for c in result.shared_cores))


@pytest.fixture(scope="module")
def vr() -> Replanner:
    return Replanner(load_spec(SPECS / "vr_illixr.yaml"), 1, gap=0.0)


@pytest.fixture(scope="module")
def nav() -> Replanner:
    return Replanner(load_spec(SPECS / "nav2d.yaml"), 2, gap=0.0)  # exact, to compare with fresh solves


def test_first_plan_is_the_planners(vr: Replanner, nav: Replanner) -> None:
    for replanner in (vr, nav):
        fresh = plan(replanner.spec, replanner.cores)  # cvxpy, the model of record
        assert replanner.plan.objective == pytest.approx(fresh.objective, rel=1e-6)
        assert replanner.plan.allocation == fresh.allocation


drift = st.floats(0.5, 2.0, allow_nan=False)


def spec_times(replanner: Replanner) -> dict[str, float]:
    """Every scheduled node's compute time as the spec gives it."""
    return {
        node: c
        for sub in replanner.spec_problem.subchains
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
    }


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(factors=st.lists(drift, min_size=6, max_size=6))
def test_vr_resolve_matches_enumeration(vr: Replanner, factors: list[float]) -> None:
    # VR's shared core has no batch subchain: the oracle enumerates every integer vector of runs
    # in closed form (tests/planning/test_stage2_integer.py), with the drifted compute times.
    new = {node: round(c * factor, 3) for (node, c), factor in zip(spec_times(vr).items(), factors, strict=False)}
    result = vr.resolve(new)
    problem = vr.problem
    expected = enumerate_best(problem, layout_of(result), vr.spec.schedule, 1.0)
    if expected is None:  # the drift broke the bounds: the plan says by how much, and meets that
        assert result.constraint_scale > 1
    else:
        assert result.objective == pytest.approx(expected, rel=1e-6)
    timings = {name: Timing(s.period_ms, s.latency_ms) for name, s in result.subchains.items()}
    assert objective(problem, timings) == pytest.approx(result.objective, rel=1e-9)
    assert bound_scale(problem, timings) <= result.constraint_scale * (1 + 1e-9)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(factors=st.lists(drift, min_size=8, max_size=8))
def test_nav2d_resolve_matches_a_fresh_cvxpy_solve(nav: Replanner, factors: list[float]) -> None:
    # GL is a batch subchain on the shared core, so the oracle is the cvxpy model, built afresh.
    new = {node: c * factor for (node, c), factor in zip(spec_times(nav).items(), factors, strict=False)}
    result = nav.resolve(new)
    layout = layout_of(result)
    fresh = solve_layout(nav.problem, layout, nav.spec.schedule, RelaxedStage2(nav.problem, layout, nav.spec.schedule))
    assert fresh is not None
    assert result.constraint_scale == pytest.approx(fresh.scale, rel=1e-6)
    assert result.objective == pytest.approx(fresh.objective, rel=1e-6)


def test_resolve_keeps_the_allocation_and_the_model(nav: Replanner) -> None:
    before = dict(nav.models)
    allocation = nav.plan.allocation
    nav.resolve({"GM": 180.0})
    nav.resolve({"GP": 90.0})
    assert nav.plan.allocation == allocation
    assert nav.models == before  # same layouts, same model objects: nothing rebuilt
    assert nav.problem.subchain("GM").node_compute_ms == (180.0,)  # earlier updates stay
    assert nav.problem.subchain("GP").node_compute_ms == (90.0,)


def test_reallocate_follows_new_cores_and_times() -> None:
    spec = load_spec(SPECS / "nav2d.yaml")
    replanner = Replanner(spec, 1)
    moved = replanner.reallocate(cores=2)
    assert moved.cores == 2
    exact = plan(spec, 2)  # with cvxpy: the re-plan may be up to the gap above it
    assert moved.allocation == exact.allocation
    best = searched(exact, replanner.problem)
    assert best * (1 - 1e-6) <= searched(moved, replanner.problem) <= best / (1 - RUNTIME_GAP) * (1 + 1e-6)
    # Much slower mapping: Stage I sees it too.
    slower = replanner.reallocate({"GM": 600.0})
    assert replanner.problem.subchain("GM").node_compute_ms == (600.0,)
    assert slower.cores == 2


@pytest.mark.parametrize(
    ("times", "fragment"),
    [
        ({"LN": 3.0}, "did you mean 'LM'"),
        ({"odom": 3.0}, "not a scheduled node"),
        ({"GM": -1.0}, "not a positive finite number"),
        ({"GM": float("nan")}, "not a positive finite number"),
        ({"GM": float("inf")}, "not a positive finite number"),
    ],
)
def test_bad_compute_times_are_usage_errors(nav: Replanner, times: dict[str, float], fragment: str) -> None:
    before = nav.plan
    with pytest.raises(UsageError, match=fragment):
        nav.resolve(times)
    assert nav.plan is before  # nothing changed


@settings(max_examples=10, deadline=None)
@given(factors=st.lists(drift, min_size=8, max_size=8))
@example(factors=[1.0, 1.5, 1.0, 1.25, 1.78125, 0.69140625, 1.125, 1.0])  # 1.007% above the optimum, 0.997% of the plan
def test_a_gap_stays_within_it_of_the_exact_plan(factors: list[float]) -> None:
    """The gap is measured against the plan, as MILP solvers do: (plan - optimum) / plan <= gap."""
    spec = load_spec(SPECS / "nav2d.yaml")
    exact, default = Replanner(spec, 2, gap=0.0), Replanner(spec, 2)
    assert default.gap == RUNTIME_GAP
    new = {node: c * factor for (node, c), factor in zip(spec_times(exact).items(), factors, strict=False)}
    best = searched(exact.resolve(new), exact.problem)
    for replanner, gap in ((default, RUNTIME_GAP), (Replanner(spec, 2, gap=1e-2), 1e-2)):
        near = searched(replanner.resolve(new), replanner.problem)
        assert best <= near * (1 + 1e-6)
        assert near * (1 - gap) <= best * (1 + 1e-6)


@settings(max_examples=10, deadline=None)
@given(factors=st.lists(drift, min_size=8, max_size=8), cores=st.sampled_from([1, 2]))
@example(factors=[1.0, 1.25, 1.0, 1.625, 2.0, 0.875, 1.0, 1.0], cores=2)  # the allocations differ
def test_reallocate_stays_within_the_gap_of_a_fresh_exact_plan(factors: list[float], cores: int) -> None:
    """Re-allocation searches with the runtime's gap, from the current runs; a fresh exact plan bounds it."""
    spec = load_spec(SPECS / "nav2d.yaml")
    replanner = Replanner(spec, cores)
    new = {node: c * factor for (node, c), factor in zip(spec_times(replanner).items(), factors, strict=False)}
    near = replanner.reallocate(new)
    best = plan_problem(replanner.problem, spec.schedule, cores, backend="conic")  # gap 0, no start
    if best.constraint_scale > 1.0 + 1e-6 or near.constraint_scale > 1.0 + 1e-6:
        assert near.constraint_scale == pytest.approx(best.constraint_scale, rel=1e-5)
    exact, found = searched(best, replanner.problem), searched(near, replanner.problem)
    if near.allocation != best.allocation:
        # Plans are ranked as run, and the gap bounds the search's planned objective: across allocations
        # no gap is promised.  Within the allocation chosen, the exact search bounds it.
        layout = layout_of(near)
        model = RelaxedStage2(replanner.problem, layout, spec.schedule)
        here = solve_layout(replanner.problem, layout, spec.schedule, model)
        assert here is not None
        lengths = {name: here.lengths[core.core] for core in here.layout.shared for name in core.subchains}
        exact = at_least_spacing(replanner.problem, here.timings, here.runs, lengths)
    assert exact <= found * (1 + 1e-6)
    assert found * (1 - RUNTIME_GAP) <= exact * (1 + 1e-6)


@settings(max_examples=10, deadline=None)
@given(
    factors=st.lists(drift, min_size=8, max_size=8),
    cores=st.sampled_from([1, 2]),
    switch_ms=st.floats(0.12, 0.6),
    slack=st.floats(0.05, 0.25),
)
@example(factors=[1.0] * 8, cores=2, switch_ms=0.12, slack=0.0856)  # the runtime's first re-plan on nav2d
def test_reconfigure_plans_with_the_new_costs_within_the_gap_of_a_fresh_exact_plan(
    factors: list[float], cores: int, switch_ms: float, slack: float
) -> None:
    """The runtime's measured costs, re-planned on the warm replanner (its models built again): a fresh exact plan
    of the spec with those costs bounds it, as for :meth:`Replanner.reallocate`."""
    spec = load_spec(SPECS / "nav2d.yaml")
    replanner = Replanner(spec, cores)
    new = {node: c * factor for (node, c), factor in zip(spec_times(replanner).items(), factors, strict=False)}
    near = replanner.reconfigure(switch_ms, slack, new)
    raised = spec.schedule.model_copy(update={"switch_ms": switch_ms, "slack": slack})
    assert replanner.spec.schedule == raised
    problem = replanner.problem
    assert problem.slack == slack
    assert problem == build_problem(spec.model_copy(update={"schedule": raised})).with_compute(new)
    best = plan_problem(problem, raised, cores, backend="conic")  # gap 0, no start, fresh models
    if best.constraint_scale > 1.0 + 1e-6 or near.constraint_scale > 1.0 + 1e-6:
        assert near.constraint_scale == pytest.approx(best.constraint_scale, rel=1e-5)
    exact, found = searched(best, problem), searched(near, problem)
    if near.allocation != best.allocation:  # within the allocation chosen, as in the test above
        layout = layout_of(near)
        here = solve_layout(problem, layout, raised, RelaxedStage2(problem, layout, raised))
        assert here is not None
        lengths = {name: here.lengths[core.core] for core in here.layout.shared for name in core.subchains}
        exact = at_least_spacing(problem, here.timings, here.runs, lengths)
    assert exact <= found * (1 + 1e-6)
    assert found * (1 - RUNTIME_GAP) <= exact * (1 + 1e-6)


def test_a_reconfigure_that_fails_leaves_the_replanner_as_it_was(monkeypatch: pytest.MonkeyPatch) -> None:
    """The re-optimiser answers a failed re-plan with its last plan: its costs, problem and models must stay that
    plan's (a fresh Replanner was only swapped in on success)."""
    spec = load_spec(SPECS / "nav2d.yaml")
    replanner = Replanner(spec, 1)
    before = (replanner.spec, replanner.problem, dict(replanner.models), replanner.plan)
    with pytest.raises(UsageError):
        replanner.reconfigure(0.3, 0.1, {"nowhere": 1.0})  # a bad time: refused before anything changes
    assert (replanner.spec, replanner.problem, dict(replanner.models), replanner.plan) == before

    def no_plan(_cores: int) -> Plan:
        raise RuntimeError("the solver failed")

    monkeypatch.setattr(replanner, "_allocate", no_plan)
    with pytest.raises(RuntimeError):
        replanner.reconfigure(0.3, 0.1)  # the search fails after the new costs are in place
    assert (replanner.spec, replanner.problem, dict(replanner.models), replanner.plan) == before
    monkeypatch.undo()
    assert replanner.resolve({}).objective == pytest.approx(before[3].objective)


def test_the_first_plan_is_exact_whatever_the_gap() -> None:
    spec = load_spec(SPECS / "nav2d.yaml")
    coarse = Replanner(spec, 2, gap=0.5)
    assert coarse.plan.objective == pytest.approx(plan(spec, 2).objective, rel=1e-6)


def test_gap_out_of_range_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="gap must be in"):
        Replanner(load_spec(SPECS / "face_tracking.yaml"), 1, gap=1.5)


@pytest.mark.parametrize("cores", [1, 2, 3])
def test_a_replans_periods_as_run_are_its_timings_scored_afresh(cores: int) -> None:
    # Stage II's executor trade hands the plan the periods as run it scored; here they are scored again from the
    # plan's own numbers (its timings, its layout's executor threads), for the first plan and each re-solve.
    spec = load_spec(SPECS / "nav2d.yaml")
    replanner = Replanner(spec, cores)
    spec_times = {
        node: c
        for sub in replanner.spec_problem.subchains
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
    }
    longer = 0
    for step in range(5):
        if step:
            replanner.resolve({node: c * (1 + 0.02 * (step - 2.5)) for node, c in spec_times.items()})
        result = replanner.plan
        turns = LayoutTurns.of(replanner.problem, layout_of(result), spec.schedule)
        assert turns is not None
        periods = turns.periods(
            replanner.problem, {n: Timing(s.period_ms, s.latency_ms) for n, s in result.subchains.items()}
        )
        for name, sub in result.subchains.items():
            slower = periods[name] > sub.period_ms * (1 + 1e-9)
            assert sub.period_as_run_ms == (periods[name] if slower else None), name
            longer += slower
    assert longer  # the Mapper's thread makes some period longer as run


@pytest.mark.parametrize(("cores", "gap"), [(1, 0.0), (1, RUNTIME_GAP), (2, 0.0), (2, RUNTIME_GAP)])
def test_a_resolve_the_bound_settles_is_the_one_the_relaxation_settles(
    monkeypatch: pytest.MonkeyPatch, cores: int, gap: float
) -> None:
    # nav2d on 2 cores: the solver-free bound is the root relaxation's value, so a re-solve's search stops at its
    # start without a conic solve; the oracle is the same re-solves with the relaxation alone.
    spec = load_spec(SPECS / "nav2d.yaml")
    replanners = [Replanner(spec, cores, gap=gap), Replanner(spec, cores, gap=gap)]
    solves = [0, 0]
    searched = solve_integer

    def counted(which: int) -> Any:
        def search(model: Any, *args: Any, **kwargs: Any) -> Any:
            original = model.solve

            def solve(scale: float = 1.0) -> Any:
                solves[which] += 1
                return original(scale)

            model.solve = solve
            try:
                return searched(model, *args, **({**kwargs, "floor": None} if which else kwargs))
            finally:
                del model.solve

        return search

    times = {
        node: c
        for sub in replanners[0].spec_problem.subchains
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
    }
    for step in range(8):
        drifted = {node: c * (1 + 0.01 * ((step * 7 + index) % 5 - 2)) for index, (node, c) in enumerate(times.items())}
        found = []
        for which, replanner in enumerate(replanners):
            monkeypatch.setattr(solve_module, "solve_integer", counted(which))
            found.append(replanner.resolve(drifted))
        with_bound, relaxed = found
        assert (with_bound.objective, with_bound.runs, with_bound.every) == (
            relaxed.objective,
            relaxed.runs,
            relaxed.every,
        )
        assert with_bound.subchains == relaxed.subchains
    if (cores, gap) == (2, RUNTIME_GAP):
        assert solves[0] < solves[1]  # the bound settled some re-solves
