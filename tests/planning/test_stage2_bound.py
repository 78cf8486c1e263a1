"""The planner's solver-free lower bound on an allocation (``stage2.solve.lower_bound``) against exact plans.

The planner skips an allocation whose bound cannot beat the best plan so far,
so a bound above some plan of its allocation would lose the best plan
silently.  The oracles: the exact integer optimum of every allocation of
random apps (``solve_layout`` with no node limit), and a closed form worked
by hand for one shared core.
"""

from __future__ import annotations

import itertools
import math

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.errors import InfeasibleError
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.model.metrics import Timing
from catanc.model.problem import Problem
from catanc.planning.planner import conic_model, ordered_layout
from catanc.planning.stage1.exhaustive import every_allocation
from catanc.planning.stage2.base import Layout, SharedCore, Stage2Model
from catanc.planning.stage2.integer import IntegerSolution, most_runs, solve_integer
from catanc.planning.stage2.solve import SCALE_PRECISION, load_bound, lower_bound, solve_layout
from catanc.spec.language import Schedule
from tests.support.strategies import spec_documents, spec_of


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=60)
@given(document=spec_documents(max_subchains=4), cores=st.integers(1, 3))
def test_no_plan_of_an_allocation_beats_its_lower_bound(document: dict[str, object], cores: int) -> None:
    spec = spec_of(document)
    problem = build_problem(spec)
    importance = problem.importance()
    models: dict[Layout, Stage2Model] = {}
    for allocation in itertools.islice(every_allocation(problem, cores), 12):
        layout = ordered_layout(Layout.from_allocation(allocation), spec.schedule, importance, problem)
        scale, value = lower_bound(problem, layout, spec.schedule)
        try:
            plan = solve_layout(problem, layout, spec.schedule, conic_model(models, problem, layout, spec.schedule))
        except InfeasibleError:
            continue
        assert plan is not None
        assert scale <= plan.scale * (1 + SCALE_PRECISION)
        # The plan's objective is exact for its whole runs; the bound may not exceed it beyond rounding.
        assert value <= plan.objective * (1 + 1e-9) + 1e-9, (allocation, value, plan.objective)


def same_search(first: IntegerSolution | None, second: IntegerSolution | None) -> bool:
    if first is None or second is None:
        return first is second
    return (first.runs, first.objective, first.gap) == (second.runs, second.objective, second.gap)


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=60)
@given(
    document=spec_documents(max_subchains=4),
    cores=st.integers(1, 3),
    drift=st.floats(0.8, 1.25),
    gap=st.sampled_from([0.0, 1e-3, 1e-2, 5e-2]),
)
def test_the_bound_stops_a_search_at_its_root_only_where_the_relaxation_would(
    document: dict[str, object], cores: int, drift: float, gap: float
) -> None:
    """A re-solve's search may stop at its start where :func:`lower_bound` proves it within the gap (no solver):
    the bound is below the root relaxation (the oracle: the conic model solved at the root box), so the
    relaxation would stop it too, and the search with the bound finds what the search without it does."""
    spec = spec_of(document)
    problem = build_problem(spec)
    if not problem.weighted:
        return
    importance = problem.importance()
    models: dict[Layout, Stage2Model] = {}
    node = problem.subchains[0].nodes[0]
    drifted = problem.with_compute({node: problem.subchains[0].node_compute_ms[0] * drift})
    for allocation in itertools.islice(every_allocation(problem, cores), 8):
        layout = ordered_layout(Layout.from_allocation(allocation), spec.schedule, importance, problem)
        model = conic_model(models, problem, layout, spec.schedule)
        if model is None:
            continue
        try:
            planned = solve_layout(problem, layout, spec.schedule, model)
        except InfeasibleError:
            continue
        assert planned is not None
        value = lower_bound(drifted, layout, spec.schedule)[1]
        model.set_numbers(drifted)
        model.set_box(
            {name: (1, most_runs(drifted.subchain(name).compute_ms, spec.schedule)) for name in model.integral}
        )
        relaxed = model.solve(1.0)
        if relaxed is not None:
            # Within the solver's accuracy (~3e-8: catanc/planning/stage2/conic.py); the search's margin is 1e-6.
            assert value <= relaxed.objective * (1 + 1e-7), (allocation, value, relaxed.objective)
        if planned.scale > 1.0 + SCALE_PRECISION:
            continue
        found = [
            solve_integer(model, drifted, 1.0, start=planned.runs, gap=gap, floor=floor)
            for floor in (lambda value=value: value, None)
        ]
        assert same_search(*found), (allocation, found)


def one_core(compute: tuple[float, float], weights: tuple[float, float]) -> tuple[Problem, Schedule]:
    """Subchains A and B on one core, each weighted by its period: no chain, no rate cap, no minimum slice."""
    document = {
        "catan": 1,
        "app": "pair",
        "nodes": {"a": {"compute_ms": compute[0]}, "b": {"compute_ms": compute[1]}},
        "subchains": {"A": ["a"], "B": ["b"]},
        "objective": [{"node": "a", "weight": weights[0]}, {"node": "b", "weight": weights[1]}],
        "schedule": {"min_slice_ms": 0, "switch_ms": 0.12, "slack": 0.05},
    }
    spec = parse_spec(yaml.safe_dump(document, sort_keys=False), "pair.yaml")
    return build_problem(spec), spec.schedule


@pytest.mark.parametrize(("compute", "weights"), [((4.0, 9.0), (1.0, 1.0)), ((2.0, 30.0), (3.0, 0.5))])
def test_one_core_without_caps_is_the_closed_form(compute: tuple[float, float], weights: tuple[float, float]) -> None:
    """``min w_a l_a + w_b l_b`` subject to ``c_a / l_a + c_b / l_b <= U`` is ``(sum sqrt(w c))^2 / U`` at
    ``l_i = sqrt(c_i / w_i) sum sqrt(w c) / U`` (Cauchy-Schwarz), the switches (2 x 0.12 ms) added to the
    load of the member with the largest ``w / c``; each latency at least a whole run alone."""
    problem, schedule = one_core(compute, weights)
    layout = Layout((), (SharedCore(0, ("A", "B")),))
    least = {name: Timing(c, c) for name, c in zip("AB", compute, strict=True)}
    loads = list(compute)
    loads[max(range(2), key=lambda i: weights[i] / compute[i])] += 2 * 0.12
    root_sum = math.fsum(math.sqrt(w * c) for w, c in zip(weights, loads, strict=True))
    latencies = [math.sqrt(c / w) * root_sum / 0.95 for w, c in zip(weights, loads, strict=True)]
    assert all(latency > c for latency, c in zip(latencies, compute, strict=True))  # no floor binds
    assert load_bound(problem, layout, schedule, least) == pytest.approx(root_sum**2 / 0.95, rel=1e-12)
