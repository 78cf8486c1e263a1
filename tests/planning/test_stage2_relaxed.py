"""Stage II's relaxed GP: DPP, a closed-form optimum, and the analytic model's agreement."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.model.metrics import Timing, capped_dedicated, objective
from catanc.model.problem import Problem
from catanc.planning.stage1 import allocate
from catanc.planning.stage2.relaxed import Layout, RelaxedStage2, SharedCore
from catanc.spec.language import Schedule
from tests.support.strategies import spec_documents, spec_of

# Two one-node subchains on one core, no slack, no switch cost, a negligible minimum slice,
# each subchain's period weighted 1. With T = 2 f_A + 4 f_B (tight) and r = f_B / f_A:
#   p_A = T / f_A = 2 + 4 r,  p_B = T / f_B = 2 / r + 4,  objective 6 + 4 r + 2 / r,
# minimised at r = 1 / sqrt(2): 6 + 4 sqrt(2) = 11.6569.
TWO = """
catan: 1
app: two
nodes: {a: {compute_ms: 2}, b: {compute_ms: 4}}
subchains: {A: [a], B: [b]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}]
schedule: {slack: 0, switch_ms: 0, min_slice_ms: 0.001}
"""


def relaxed(text: str) -> tuple[Problem, Schedule, RelaxedStage2]:
    spec = parse_spec(text)
    problem = build_problem(spec)
    layout = Layout(dedicated=(), shared=(SharedCore(0, tuple(s.name for s in problem.subchains)),))
    model = RelaxedStage2(problem, layout, spec.schedule)
    model.set_numbers(problem)
    return problem, spec.schedule, model


def test_problem_is_dpp() -> None:
    # A non-DPP problem recompiles on every solve with only a warning.
    _, _, model = relaxed(TWO)
    assert model.problem_gp.is_dgp(dpp=True)


def test_closed_form_two_subchains() -> None:
    _, _, model = relaxed(TWO)
    solution = model.solve()
    assert solution is not None
    assert solution.objective == pytest.approx(6 + 4 * math.sqrt(2), rel=1e-6)
    ratio = solution.fraction["B"] / solution.fraction["A"]
    assert ratio == pytest.approx(1 / math.sqrt(2), rel=1e-4)


def test_slack_and_switch_cost_stretch_the_period() -> None:
    # One subchain alone (2 ms) with 5% slack and a 0.12 ms switch: T = (2 f + 0.12) / 0.95 and
    # p = T / f is smallest at f = 1: p = 2.12 / 0.95.
    text = TWO.replace("b: {compute_ms: 4}", "").replace(", B: [b]", "").replace(", {node: b, weight: 1}", "")
    text = text.replace("schedule: {slack: 0, switch_ms: 0, min_slice_ms: 0.001}", "")
    _, _, model = relaxed(text)
    solution = model.solve()
    assert solution is not None
    assert solution.period_ms["A"] == pytest.approx(2.12 / 0.95, rel=1e-6)
    assert solution.fraction["A"] == pytest.approx(1.0, rel=1e-6)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=spec_documents(max_subchains=5), cores=st.integers(1, 3))
def test_gp_value_is_the_models_objective(document: dict[str, object], cores: int) -> None:
    spec = spec_of(document)
    problem = build_problem(spec)
    allocation = allocate(problem, cores).allocation
    layout = Layout.from_allocation(allocation)
    if not layout.shared:
        return
    model = RelaxedStage2(problem, layout, spec.schedule)
    model.set_numbers(problem)
    solution = model.solve(scale=1e6)  # bounds out of the way: this checks the objective's encoding
    assert solution is not None
    by_name = {sub.name: sub for sub in problem.subchains}
    timings = {name: capped_dedicated(by_name[name], k, problem.slack).timing for name, k in layout.dedicated}
    usable = 1 - spec.schedule.slack
    for core in layout.shared:
        T = solution.core_period_ms[core.core]
        load = sum(solution.fraction[n] * by_name[n].compute_ms for n in core.subchains)
        assert (load + len(core.subchains) * spec.schedule.switch_ms) / usable <= T * (1 + 1e-6)
        for name in core.subchains:
            f = solution.fraction[name]
            assert f * by_name[name].compute_ms >= min(spec.schedule.min_slice_ms, by_name[name].compute_ms) * (
                1 - 1e-6
            )
            assert by_name[name].batch or f <= 1 + 1e-6
            timings[name] = Timing(solution.period_ms[name], T / f)
            assert timings[name].period_ms >= timings[name].latency_ms * (1 - 1e-6)
    assert objective(problem, timings) == pytest.approx(solution.objective, rel=1e-5)
