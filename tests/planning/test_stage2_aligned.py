"""Aligned triggers
(docs/explanation/model.md section 4): ``p = k T`` on shared cores, worked by hand and against enumeration.

A shared non-batch subchain's head is triggered at its slot every ``k >= n``
periods.  With the runs fixed, the objective is a sawtooth in ``T``: the best
``T`` may sit at a breakpoint ``p_min / k`` above the shortest that fits.  The
batch case is checked against a grid over the batch fraction ``x`` where,
for each ``x``, every trigger interval vector is enumerated and ``T`` is the
least that fits and keeps every ``k_i T >= p_min_i`` (no breakpoint logic).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from catanc.control.schedule import runtime_schedule
from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.model.metrics import Timing, bound_scale, capped_dedicated, objective
from catanc.model.problem import Problem
from catanc.planning.planner import plan
from catanc.planning.stage2.base import Layout
from catanc.planning.stage2.conic import ConicStage2
from catanc.planning.stage2.convex import OPEN
from catanc.planning.stage2.integer import most_runs
from catanc.planning.stage2.onebatch import OneBatchRuns
from catanc.planning.stage2.whole import WholeRuns
from catanc.spec.language import Schedule, Spec
from tests.planning.test_stage2_conic import app_documents, batch_heads, capped
from tests.support.strategies import spec_of

# a (1 ms, at most 1000/7 Hz: p >= 7 ms) and b (2 ms) on one core, no slack or switch cost, both
# periods weighted 1, slices of at least 1 ms (n_a = 1, n_b <= 2). With n = (1, 1) the slots fit
# in T = 3: a then needs k = ceil(7 / 3) = 3, p_a = 9, objective 9 + 3 = 12. At the breakpoint
# T = 7 / 2, k = 2: 7 + 3.5 = 10.5. With n_b = 2 (T >= 2) the best is T = 7/3: 7 + 14/3 = 11.67.
# So T = 3.5, a triggered every 2 periods, b every period: 10.5 (the relaxation, k free: 7 + 3 = 10).
SAWTOOTH = """\
catan: 1
app: sawtooth
nodes: {a: {compute_ms: 1}, b: {compute_ms: 2}}
subchains: {A: [a], B: [b]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}]
constraints: [{node: a, max_rate_hz: 142.857142857142857}]
schedule: {slack: 0, switch_ms: 0, min_slice_ms: 1}
"""

# a (2 ms) at exactly 120 Hz and b (3 ms) at exactly 50 Hz on one core (slices >= 1 ms: n_a <= 2,
# n_b <= 3, so T >= 2). Both aligned: T = 8.333/k_a = 20/k_b, i.e. k_b / k_a = 12/5: T <= 1.67,
# too short. No common T: each period must lie in [p_fix, s p_fix]. The least s over T >= 2,
# with k = ceil(p_fix / T) for each: at T = 20/7 (b every 7 periods, exactly 50 Hz), a every 3:
# 60/7 = 8.571 ms, s = 8.571 / 8.333 = 1.0286 (the breakpoints of a give 1.25, 1.042, 1.111,
# 1.042; b's 1.2, 1.6, 1.2, 1.44, 1.2, 1.029, 1.2, 1.067, 1.2).
CONFLICT = """\
catan: 1
app: conflict
nodes: {a: {compute_ms: 2}, b: {compute_ms: 3}}
subchains: {A: [a], B: [b]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}]
constraints: [{node: a, rate_hz: 120}, {node: b, rate_hz: 50}]
schedule: {slack: 0, switch_ms: 0, min_slice_ms: 1}
"""


def test_the_best_length_is_a_breakpoint_above_the_fit() -> None:
    spec = parse_spec(SAWTOOTH)
    result = plan(spec, 1)
    (core,) = result.shared_cores
    assert core.period_ms == pytest.approx(3.5, rel=1e-9)
    assert result.runs == {"A": 1, "B": 1}
    assert result.every == {"A": 2, "B": 1}
    assert result.subchains["A"].period_ms == pytest.approx(7.0, rel=1e-9)
    assert result.subchains["A"].latency_ms == pytest.approx(3.5, rel=1e-9)
    assert result.objective == pytest.approx(10.5, rel=1e-9)
    # The runtime triggers A at its slot every 2 periods, B every period: none on a clock of its own.
    schedule = runtime_schedule(result, build_problem(spec), spec.schedule)
    assert schedule.subchains["A"].runs == 2
    assert schedule.subchains["B"].runs == 1
    assert schedule.clocked == ()


def test_fixed_rates_with_no_common_length_are_planned_at_the_least_scale_and_named() -> None:
    result = plan(parse_spec(CONFLICT), 1)
    assert result.constraint_scale == pytest.approx(60 / 7 / (1000 / 120), rel=1e-5)
    (core,) = result.shared_cores
    assert core.period_ms == pytest.approx(20 / 7, rel=1e-5)
    assert result.every == {"A": 3, "B": 7}
    # Never faster than the fixed rate: the cap holds, the floor is what scales.
    assert result.subchains["A"].period_ms >= 1000 / 120 * (1 - 1e-9)
    assert result.subchains["B"].period_ms == pytest.approx(20.0, rel=1e-5)
    (note,) = [w for w in result.warnings if w.startswith("fixed rates")]
    assert "cannot share one schedule period" in note
    assert "A 120 Hz" in note
    assert "B 50 Hz" in note


def test_vr_timewarp_is_locked_to_vsync() -> None:
    spec = load_spec(Path(__file__).parents[2] / "specs" / "vr_illixr.yaml")
    result = plan(spec, 1)
    (core,) = result.shared_cores
    k = result.every["timewarp"]
    assert core.period_ms == pytest.approx(1000 / 120 / k, rel=1e-9)
    assert result.subchains["timewarp"].period_ms == pytest.approx(1000 / 120, rel=1e-9)
    for name, every in result.every.items():
        assert every >= result.runs[name]
        assert result.subchains[name].period_ms == pytest.approx(every * core.period_ms, rel=1e-9)


# --------------------------------------------------------------------------- one batch subchain


def oracle_timings(
    problem: Problem,
    layout: Layout,
    schedule: Schedule,
    *,
    runs: dict[str, int],
    batch: str,
    x: float,
    every: dict[str, int],
) -> tuple[dict[str, Timing], float]:
    """Timings with these runs, batch fraction and trigger intervals; T the least that fits and keeps k T >= p_min."""
    by_name = {sub.name: sub for sub in problem.subchains}
    timings = {name: capped_dedicated(by_name[name], k, problem.slack).timing for name, k in layout.dedicated}
    total = 0.0
    for core in layout.shared:
        load = sum(by_name[n].compute_ms * x if n == batch else by_name[n].compute_ms / runs[n] for n in core.subchains)
        length = (load + len(core.subchains) * schedule.switch_ms) / (1 - schedule.slack)
        length = max([length] + [by_name[n].min_period_ms / every[n] for n in core.subchains if n != batch])
        total += length
        for name in core.subchains:
            if name == batch:
                timings[name] = Timing(max(length / x, by_name[name].min_period_ms), length / x)
            else:
                timings[name] = Timing(every[name] * length, runs[name] * length)
    return timings, total


def oracle_best(
    problem: Problem, layout: Layout, schedule: Schedule, *, runs: dict[str, int], batch: str, scale: float
) -> tuple[float, float]:
    """Over a grid of ``x`` and every ``k`` vector: the least objective meeting the bounds, and the least scale."""
    by_name = {sub.name: sub for sub in problem.subchains}
    compute = by_name[batch].compute_ms
    least = min(schedule.min_slice_ms, compute) / compute if schedule.min_slice_ms > 0 else 0.0
    grid = np.geomspace(1e-3, 1e3, 121)
    best, least_scale = math.inf, math.inf
    shared = [name for core in layout.shared for name in core.subchains if name != batch]
    for x in [least, *grid[grid > least]] if least > 0 else grid:
        fit, _ = oracle_timings(
            problem, layout, schedule, runs=runs, batch=batch, x=float(x), every=dict.fromkeys(shared, 10**12)
        )
        ranges = [  # a longer k leaves T as it is and only lengthens p
            range(runs[n], max(runs[n], math.ceil(by_name[n].min_period_ms / fit[n].latency_ms * runs[n])) + 1)
            for n in shared
        ]
        for combo in itertools.product(*ranges):
            every = dict(zip(shared, combo, strict=True))
            timings, total = oracle_timings(problem, layout, schedule, runs=runs, batch=batch, x=float(x), every=every)
            needed = bound_scale(problem, timings)
            least_scale = min(least_scale, max(1.0, needed))
            if needed <= scale * (1 + 1e-9):
                best = min(best, objective(problem, timings) if problem.weighted else total)
    return best, least_scale


@st.composite
def capped_one_batch_apps(draw: st.DrawFn) -> tuple[Spec, Layout, dict[str, int]]:
    document, layout = draw(app_documents(max_subchains=4))
    # Filtered on the document, before its parse: most apps drawn are filtered out.
    batch = [name for core in layout.shared for name in core.subchains if name in batch_heads(document)]
    assume(len(batch) == 1)
    shared = [name for core in layout.shared for name in core.subchains if name not in batch]
    # One capped subchain keeps the oracle's enumeration small (its k up to p_min / T).
    assume(len(capped(document).intersection(shared)) == 1)
    spec = spec_of(document)
    problem = build_problem(spec)
    assert [name for core in layout.shared for name in core.subchains if problem.subchain(name).batch] == batch
    assert sum(problem.subchain(name).min_period_ms > 0 for name in shared) == 1
    runs = {
        name: draw(st.integers(1, min(most_runs(problem.subchain(name).compute_ms, spec.schedule), 6)))
        for name in shared
    }
    return spec, layout, runs


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(app=capped_one_batch_apps(), scale=st.sampled_from([1.0, 2.0, 1e6]))
def test_one_batch_with_caps_against_enumeration(app: tuple[Spec, Layout, dict[str, int]], scale: float) -> None:
    spec, layout, runs = app
    problem = build_problem(spec)
    model = ConicStage2(problem, layout, spec.schedule)
    closed = OneBatchRuns(model, problem)
    assert closed.aligned_matters
    (batch,) = [name for name in model.shared_names if problem.subchain(name).batch]
    best, least_scale = oracle_best(problem, layout, spec.schedule, runs=runs, batch=batch, scale=scale)
    found = closed.fixed_runs(runs, scale, least_scale=False)
    if found is not OPEN:
        if found is None:
            assert least_scale > scale * (1 - 1e-6)
        else:
            assert found is not None
            assert not isinstance(found, type(OPEN))
            assert found.objective <= best * (1 + 1e-9), "an (x, k) of the grid beats the closed form"
    least = closed.fixed_runs(runs, scale, least_scale=True)
    if least is not OPEN and least is not None:
        assert not isinstance(least, type(OPEN))
        assert least.objective <= least_scale * (1 + 1e-9), "an (x, k) of the grid needs a smaller scale"


# --------------------------------------------------------------------------- a cutoff on fixed runs


@st.composite
def capped_whole_apps(draw: st.DrawFn) -> tuple[Spec, Layout, dict[str, int]]:
    document, layout = draw(app_documents(max_subchains=5))
    shared = [name for core in layout.shared for name in core.subchains]
    # Filtered on the document, before its parse: most apps drawn are filtered out.
    assume(not batch_heads(document).intersection(shared))
    assume(bool(capped(document).intersection(shared)))  # lengths are searched
    spec = spec_of(document)
    problem = build_problem(spec)
    assert not any(problem.subchain(name).batch for name in shared)
    assert any(problem.subchain(name).min_period_ms > 0 for name in shared)
    runs = {
        name: draw(st.integers(1, min(most_runs(problem.subchain(name).compute_ms, spec.schedule), 8)))
        for name in shared
    }
    return spec, layout, runs


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(
    app=capped_whole_apps(),
    scale=st.sampled_from([1.0, 1e6]),
    least_scale=st.booleans(),
    factor=st.sampled_from([0.5, 0.999, 1.0, 1.001, 2.0]),
)
def test_a_cutoff_keeps_exactly_the_plans_below_it(
    app: tuple[Spec, Layout, dict[str, int]], scale: float, least_scale: bool, factor: float
) -> None:
    # The search's leaves skip lengths whose bound reaches the incumbent: against the search
    # without one, a cutoff may only turn a plan that does not beat it into None.
    spec, layout, runs = app
    problem = build_problem(spec)
    closed = WholeRuns(ConicStage2(problem, layout, spec.schedule), problem)
    assert closed.aligned_matters
    full = closed.fixed_runs(runs, scale, least_scale=least_scale)
    assume(full is not None)
    assert full is not None
    cutoff = full.objective * factor
    cut = closed.fixed_runs(runs, scale, least_scale=least_scale, cutoff=cutoff)
    if full.objective < cutoff:
        assert cut == full
    else:
        assert cut is None


# --------------------------------------------------------------------------- every vector of a box at once


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(app=capped_whole_apps(), scale=st.sampled_from([1.0, 1e6]), least_scale=st.booleans())
def test_a_box_scored_at_once_is_the_best_of_its_vectors_searched_one_by_one(
    app: tuple[Spec, Layout, dict[str, int]], scale: float, least_scale: bool
) -> None:
    # WholeRuns.best scores every vector's exact value as arrays and searches only the best one by one;
    # the oracle searches each vector alone (fixed_runs: the scalar search over its candidate lengths)
    # and keeps the least, ties to the first vector in the box's order.
    spec, layout, runs = app
    problem = build_problem(spec)
    closed = WholeRuns(ConicStage2(problem, layout, spec.schedule), problem)
    box = {name: (1, min(most_runs(problem.subchain(name).compute_ms, spec.schedule), 3)) for name in runs}
    assume(closed.size(box) <= 81)
    best: tuple[float, dict[str, int]] | None = None
    for combo in itertools.product(*(range(low, high + 1) for low, high in (box[n] for n in closed.shared))):
        vector = dict(zip(closed.shared, combo, strict=True))
        found = closed.fixed_runs(vector, scale, least_scale=least_scale)
        if found is not None and (best is None or found.objective < best[0]):
            best = (found.objective, vector)
    at_once = closed.best(box, scale, least_scale=least_scale)
    if best is None:
        assert at_once is None
        return
    assert at_once is not None
    assert at_once.solution.objective == best[0]
    assert at_once.runs == best[1]
