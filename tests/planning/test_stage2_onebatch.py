"""Fixed runs with one batch subchain: the closed form against worked cases, a grid over ``x``, and Clarabel.

The oracles do not use the pieces the closed form works with.  With every
``n_i`` fixed and the batch fraction ``x`` given, the GP's constraints fix
the rest: ``T = (sum of slices + switches) / (1 - slack)`` per shared core,
latency ``T n_i`` (``T / x`` for the batch subchain), period
``max(latency, p_min)``; the analytic model then scores the plan.  A dense
grid over ``x`` must find nothing better than the closed form, and the conic
solver (box fixed) must agree with it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.model.metrics import Timing, bound_scale, capped_dedicated, objective
from catanc.model.problem import Problem
from catanc.planning.stage1 import allocate
from catanc.planning.stage2.base import Layout, RelaxedSolution, SharedCore
from catanc.planning.stage2.conic import ConicStage2
from catanc.planning.stage2.convex import OPEN
from catanc.planning.stage2.integer import most_runs, solve_integer
from catanc.planning.stage2.onebatch import OneBatchRuns
from catanc.spec.language import Schedule, Spec
from tests.planning.test_stage2_conic import AGREE, app_documents, batch_heads
from tests.support.strategies import spec_of

SPECS = Path(__file__).parents[2] / "specs"
GRID = np.geomspace(1e-4, 1e4, 4001)
"""Batch fractions the grid oracle tries (with the least fraction the minimum slice allows)."""


def timings_at(
    problem: Problem, layout: Layout, schedule: Schedule, *, runs: dict[str, int], batch: str, x: float
) -> tuple[dict[str, Timing], float]:
    """Every subchain's timing with these runs and batch fraction ``x``, and the sum of the ``T``."""
    by_name = {sub.name: sub for sub in problem.subchains}
    timings = {name: capped_dedicated(by_name[name], k, problem.slack).timing for name, k in layout.dedicated}
    lengths = 0.0
    for core in layout.shared:
        load = sum(by_name[n].compute_ms * x if n == batch else by_name[n].compute_ms / runs[n] for n in core.subchains)
        length = (load + len(core.subchains) * schedule.switch_ms) / (1 - schedule.slack)
        lengths += length
        for name in core.subchains:
            latency = length / x if name == batch else length * runs[name]
            timings[name] = Timing(max(latency, by_name[name].min_period_ms), latency)
    return timings, lengths


def least_fraction(problem: Problem, schedule: Schedule, batch: str) -> float:
    compute = problem.subchain(batch).compute_ms
    return min(schedule.min_slice_ms, compute) / compute if schedule.min_slice_ms > 0 else 0.0


def grid_best(
    problem: Problem, layout: Layout, schedule: Schedule, *, runs: dict[str, int], batch: str, scale: float
) -> tuple[float, float]:
    """Over the grid: the least objective where the bounds hold at ``scale`` (inf: nowhere), and the least scale."""
    least = least_fraction(problem, schedule, batch)
    best, least_scale = math.inf, math.inf
    for x in [least, *GRID[least < GRID]] if least > 0 else GRID:
        timings, lengths = timings_at(problem, layout, schedule, runs=runs, batch=batch, x=float(x))
        needed = bound_scale(problem, timings)
        least_scale = min(least_scale, needed)
        if needed <= scale * (1 + 1e-9):
            best = min(best, objective(problem, timings) if problem.weighted else lengths)
    return best, least_scale


ONE_CORE = Layout((), (SharedCore(0, ("A", "B")),))


def two_subchains(
    *,
    objective: str = "[{node: a, weight: 1}, {node: b, weight: 1}]",
    constraints: str = "[]",
    min_slice_ms: float = 0.0,
    switch_ms: float = 0.0,
    layout: Layout = ONE_CORE,
) -> tuple[Problem, ConicStage2, OneBatchRuns]:
    """``a`` (4 ms, one run per period) and batch ``b`` (8 ms), by default on one core with both periods weighted 1.

    No slack and by default no switch cost: ``T = 4 + 8x``, ``p_a = T``, ``p_b = T / x = 4 / x + 8``.
    """
    spec = parse_spec(
        "catan: 1\napp: two\nnodes: {a: {compute_ms: 4}, b: {compute_ms: 8, batch: true}}\n"
        "subchains: {A: [a], B: [b]}\n"
        f"objective: {objective}\nconstraints: {constraints}\n"
        f"schedule: {{slack: 0, switch_ms: {switch_ms}, min_slice_ms: {min_slice_ms}}}\n"
    )
    problem = build_problem(spec)
    model = ConicStage2(problem, layout, spec.schedule)
    return problem, model, OneBatchRuns(model, problem)


def solved(found: RelaxedSolution | object) -> RelaxedSolution:
    assert isinstance(found, RelaxedSolution)
    return found


def test_worked_cases() -> None:
    # Objective 4 + 8x + 4/x + 8: least at x = 1/sqrt(2), 12 + 8 sqrt(2).
    *_, free = two_subchains()
    plan = solved(free.solve({"A": 1}, 1.0, least_scale=False))
    assert plan.fraction["B"] == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    assert plan.objective == pytest.approx(12 + 8 * math.sqrt(2), rel=1e-12)
    assert plan.core_period_ms[0] == pytest.approx(4 + 8 / math.sqrt(2), rel=1e-12)
    # A minimum slice of 8 ms makes b's slice whole: x >= 1, so x = 1 and 12 + 12.
    *_, sliced = two_subchains(min_slice_ms=8)
    plan = solved(sliced.solve({"A": 1}, 1.0, least_scale=False))
    assert plan.fraction["B"] == pytest.approx(1.0, rel=1e-12)
    assert plan.objective == pytest.approx(24, rel=1e-12)
    # b at least 100 Hz: 4/x + 8 <= 10, so x >= 2: 20 + 10 (up to the bounds' tolerance, 1e-9).
    *_, floored = two_subchains(constraints="[{node: b, min_rate_hz: 100}]")
    plan = solved(floored.solve({"A": 1}, 1.0, least_scale=False))
    assert plan.fraction["B"] == pytest.approx(2.0, rel=1e-8)
    assert plan.objective == pytest.approx(30, rel=1e-8)
    # ... and a at least 62.5 Hz too: 4 + 8x <= 16 needs x <= 1.5, so no plan at scale 1. The least
    # scale s balances (4/x + 8)/10 = (4 + 8x)/16: 10x^2 - 11x - 8 = 0, x = 1.6, s = 16.8/16 = 1.05.
    *_, both = two_subchains(constraints="[{node: b, min_rate_hz: 100}, {node: a, min_rate_hz: 62.5}]")
    assert both.solve({"A": 1}, 1.0, least_scale=False) is None
    least = solved(both.solve({"A": 1}, 1.0, least_scale=True))
    assert least.objective == pytest.approx(1.05, rel=1e-12)
    assert least.fraction["B"] == pytest.approx(1.6, rel=1e-12)
    plan = solved(both.solve({"A": 1}, 1.05 * (1 + 1e-12), least_scale=False))
    assert plan.fraction["B"] == pytest.approx(1.6, rel=1e-6)


def test_no_weighted_term_means_the_shortest_schedule() -> None:
    # The objective is then T = 4 + 8x: least at b's least slice, 2 ms of 8 (x = 1/4), T = 6.
    *_, sliced = two_subchains(objective="[]", min_slice_ms=2)
    plan = solved(sliced.solve({"A": 1}, 1.0, least_scale=False))
    assert plan.fraction["B"] == pytest.approx(0.25, rel=1e-12)
    assert plan.objective == pytest.approx(6.0, rel=1e-12)
    # With no minimum slice T only approaches 4, at x = 0: not attained, left to the solver.
    *_, free = two_subchains(objective="[]")
    assert free.solve({"A": 1}, 1.0, least_scale=False) is OPEN


def test_no_unique_optimum_is_left_to_the_solver() -> None:
    # Only b's period is weighted: 4/x + 8 keeps falling, the optimum is at x = inf.
    problem, model, closed = two_subchains(objective="[{node: b, weight: 1}]")
    assert closed.solve({"A": 1}, 1.0, least_scale=False) is OPEN
    found = solve_integer(model, problem)  # the search falls back on the conic solver
    assert found is not None
    assert found.objective == pytest.approx(8, rel=1e-3)
    # With a and b on cores of their own nothing weighted depends on x: flat, also left open
    # (the switch cost gives b's core a T that depends on x: 0.12 + 8x).
    *_, apart = two_subchains(
        objective="[{node: a, weight: 1}]",
        switch_ms=0.12,
        layout=Layout((), (SharedCore(0, ("A",)), SharedCore(1, ("B",)))),
    )
    assert apart.solve({"A": 1}, 1.0, least_scale=False) is OPEN


@st.composite
def one_batch_apps(draw: st.DrawFn) -> tuple[Spec, Layout, dict[str, int]]:
    """A random app whose layout shares exactly one batch subchain, and fixed runs within the slices."""
    document, layout = draw(app_documents(max_subchains=5))
    # Filtered on the document, before its parse: most apps drawn are filtered out.
    batch = [name for core in layout.shared for name in core.subchains if name in batch_heads(document)]
    assume(len(batch) == 1)
    spec = spec_of(document)
    problem = build_problem(spec)
    assert [name for core in layout.shared for name in core.subchains if problem.subchain(name).batch] == batch
    runs = {
        name: draw(st.integers(1, min(most_runs(problem.subchain(name).compute_ms, spec.schedule), 50)))
        for core in layout.shared
        for name in core.subchains
        if not problem.subchain(name).batch
    }
    return spec, layout, runs


@pytest.mark.slow
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(app=one_batch_apps(), scale=st.sampled_from([0.7, 1.0, 2.0, 1e6]))
def test_closed_form_against_grid_and_solver(app: tuple[Spec, Layout, dict[str, int]], scale: float) -> None:
    spec, layout, runs = app
    problem = build_problem(spec)
    model = ConicStage2(problem, layout, spec.schedule)
    assert OneBatchRuns.applies(model, problem)
    closed = OneBatchRuns(model, problem)
    (batch,) = [name for name in model.shared_names if problem.subchain(name).batch]
    best, least_scale = grid_best(problem, layout, spec.schedule, runs=runs, batch=batch, scale=scale)
    model.set_box({name: (n, n) for name, n in runs.items()})

    found = closed.solve(runs, scale, least_scale=False)
    if found is not OPEN:
        if found is None:  # no grid point may clearly meet the bounds
            assert least_scale > scale * (1 - 1e-6)
        else:
            plan = solved(found)
            x = plan.fraction[batch]
            assert x >= least_fraction(problem, spec.schedule, batch) * (1 - 1e-12)
            timings, lengths = timings_at(problem, layout, spec.schedule, runs=runs, batch=batch, x=x)
            assert bound_scale(problem, timings) <= scale * (1 + 1e-9)
            value = objective(problem, timings) if problem.weighted else lengths
            assert plan.objective == pytest.approx(value, rel=1e-12)
            assert plan.objective <= best * (1 + 1e-9), "a grid point beats the closed form"
            reference = model.solve(scale)
            if reference is not None and max(reference.fraction.values()) < 1e3:
                assert plan.objective == pytest.approx(reference.objective, rel=AGREE)

    least = closed.solve(runs, scale, least_scale=True)
    if least is not OPEN:
        plan = solved(least)
        timings, _ = timings_at(problem, layout, spec.schedule, runs=runs, batch=batch, x=plan.fraction[batch])
        assert plan.objective == pytest.approx(max(1.0, bound_scale(problem, timings)), rel=1e-12)
        assert plan.objective <= max(1.0, least_scale) * (1 + 1e-9), "a grid point needs a smaller scale"
        reference = model.solve_least_scale()
        if reference is not None and max(reference.fraction.values()) < 1e3:
            assert plan.objective == pytest.approx(reference.objective, rel=AGREE)


@pytest.mark.parametrize(("name", "cores"), [("nav2d", 1), ("nav2d", 2), ("nav2d_yolo", 1), ("nav2d_yolo", 2)])
def test_example_specs_evaluate_fixed_runs_without_the_solver(name: str, cores: int) -> None:
    # GL is batch and shares a core: the integer search's plan, and its neighbours, in closed form.
    spec = load_spec(SPECS / f"{name}.yaml")
    problem = build_problem(spec)
    model = ConicStage2(problem, Layout.from_allocation(allocate(problem, cores).allocation), spec.schedule)
    closed = OneBatchRuns(model, problem)
    found = solve_integer(model, problem)
    assert found is not None
    most = {name: most_runs(problem.subchain(name).compute_ms, spec.schedule) for name in found.runs}
    for step in (0, 1, -1):
        runs = {name: min(max(n + step, 1), most[name]) for name, n in found.runs.items()}
        plan = solved(closed.solve(runs, 1.0, least_scale=False))
        model.set_box({name: (n, n) for name, n in runs.items()})
        reference = model.solve(1.0)
        assert reference is not None
        assert plan.objective == pytest.approx(reference.objective, rel=AGREE)
        assert plan.objective <= reference.objective * (1 + 1e-9)  # exact: no worse than the solver's
