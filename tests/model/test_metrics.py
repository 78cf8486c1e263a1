"""The analytic model against examples worked by hand (docs/explanation/model.md sections 2 and 4).

Every expected number below is derived in the comment above it, not taken
from the code under test.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.model.metrics import (
    QUICK_MARGIN,
    Timing,
    WeightedSums,
    chain_metrics,
    chain_metrics_of,
    dedicated_timing,
    evaluate_chain,
    objective,
)
from catanc.model.problem import Problem, Subchain
from catanc.spec.language import Node
from tests.support.strategies import problems

ROOT = Path(__file__).parents[2]


def node(ms: float, threads: int = 1, speedup: list[float] | None = None) -> Node:
    return Node.model_validate({"compute_ms": ms, "threads": {"max": threads, "speedup": speedup}})


def compute_by_threads(nodes: list[Node], cores: int) -> list[list[float]]:
    """The ``c^q_j`` table of a subchain made of ``nodes``."""
    subchain = Subchain(
        name="s",
        nodes=tuple(f"n{i}" for i in range(len(nodes))),
        node_compute_ms=tuple(n.mean_compute_ms for n in nodes),
        node_speedups=tuple(n.threads.speedups for n in nodes),
        batch=False,
    )
    return subchain.compute_by_threads(cores)


# Face tracking (paper 7.1): c = 25 + 58 + 1 = 84 ms, one subchain, one thread per node.
#  1 core: q = 1, p = max(58, 84 / 1) = 84, R = L + P = 84 + 84 = 168.
#  2 cores: q = 1, p = max(58, 84 / 2) = 58, R = 84 + 58 = 142;
#           q = 2 gives floor(2/2) = 1 run in flight, p = 84, R = 168: q = 1 wins.
@pytest.mark.parametrize(("cores", "period", "response"), [(1, 84.0, 168.0), (2, 58.0, 142.0)])
def test_face_tracking_worked_example(cores: int, period: float, response: float) -> None:
    spec = load_spec(ROOT / "specs" / "face_tracking.yaml")
    problem = build_problem(spec)
    tracking = problem.subchain("tracking")
    assert tracking.node_compute_ms == (25, 58, 1)  # the worked example's inputs
    timing = dedicated_timing(tracking.compute_by_threads(cores), cores)
    assert timing.threads == 1
    assert timing.period_ms == pytest.approx(period)
    assert timing.latency_ms == pytest.approx(84.0)
    metrics = evaluate_chain(problem, problem.chains[0], {"tracking": Timing(timing.period_ms, timing.latency_ms)})
    assert metrics.period_ms == pytest.approx(period)
    assert metrics.response_ms == pytest.approx(response)


# A = 100 ms with speedup [1, 1.8], B = 20 ms single-threaded, on 2 cores:
#  q = 1: c = (100, 20), p = max(100, 120 / 2) = 100, response 120 + 100 = 220
#  q = 2: c = (55.56, 20), one run in flight, p = 75.56, response 2 * 75.56 = 151.11  <- best
def test_eq1_uses_thread_speedups() -> None:
    nodes = [node(100, 2, [1.0, 1.8]), node(20)]
    timing = dedicated_timing(compute_by_threads(nodes, 2), 2)
    assert timing.threads == 2
    assert timing.period_ms == pytest.approx(100 / 1.8 + 20)
    assert timing.response_ms == pytest.approx(2 * (100 / 1.8 + 20))


# Same nodes on 4 cores:
#  q = 1: p = max(100, 120 / 4) = 100, response 220
#  q = 2: c = (55.56, 20), two runs in flight, p = max(55.56, 75.56 / 2) = 55.56, response 131.11  <- best
#  q = 3, 4: A still uses 2 threads, one run in flight: p = 75.56, response 151.11
def test_eq1_runs_in_flight() -> None:
    nodes = [node(100, 2, [1.0, 1.8]), node(20)]
    timing = dedicated_timing(compute_by_threads(nodes, 4), 4)
    assert timing.threads == 2
    assert timing.period_ms == pytest.approx(100 / 1.8)
    assert timing.latency_ms == pytest.approx(100 / 1.8 + 20)


# One 10 ms node on 2 cores: q = 1 gives p = max(10, 5) = 10, q = 2 gives p = 10; tie -> smaller q.
def test_eq1_ties_take_fewer_threads() -> None:
    timing = dedicated_timing(compute_by_threads([node(10, 2, [1.0, 1.0])], 2), 2)
    assert timing.threads == 1
    assert timing.period_ms == 10


# Speedups need not grow: with [1, 2, 1.5] "at most 3 threads" is as good as 2 threads.
def test_speedup_is_best_of_at_most_q_threads() -> None:
    assert node(30, 3, [1.0, 2.0, 1.5]).compute_ms_with(3) == pytest.approx(15.0)
    # Omitted speedup: perfect scaling, capped at threads.max.
    assert node(30, 2).compute_ms_with(4) == pytest.approx(15.0)


# Table 1: three stages on one core, unthrottled (l = p): L = p1 + 2 p2 + 2 p3.
# p = 10, 20, 30: L = 10 + 40 + 60 = 110, P = 30, R = 140.
def test_chain_metrics_table1() -> None:
    metrics = chain_metrics([Timing(10, 10), Timing(20, 20), Timing(30, 30)])
    assert (metrics.latency_ms, metrics.period_ms, metrics.response_ms) == (110, 30, 140)


# A rate cap stretches the period but not the processing latency:
# stage 2 has p = 20, l = 5: L = 10 + (20 + 5) + (30 + 30) = 95, R = 95 + 30 = 125.
def test_chain_metrics_with_rate_cap() -> None:
    metrics = chain_metrics([Timing(10, 10), Timing(20, 5), Timing(30, 30)])
    assert metrics.latency_ms == 95
    assert metrics.response_ms == 125


NAV = """
catan: 1
app: nav
nodes:
  scan: {compute_ms: 1}
  odom: {scheduled: false, rate_hz: 50}
  LM: {compute_ms: 2}
  LP: {compute_ms: 3}
  GL: {compute_ms: 4, batch: {output_rate_hz: 1.5}}
  NC: {compute_ms: 2}
  base: {scheduled: false}
edges: [[scan, LM], [odom, LM], [LM, LP], [scan, GL], [GL, NC], [NC, LP], [LP, base]]
subchains: {local: [scan, LM, LP], GL: [GL], NC: [NC]}
objective:
  - {chain: [odom, LM, LP, base], weight: 1.0}
  - {node: GL, weight: 0.5}
  - {chains: {from: GL}, weight: 0.25}
"""


# Timings: local p = l = 6; GL p = 20, l = 20; NC p = 50, l = 50.
# Chain odom -> LM -> LP -> base: stages odom@50Hz (p = l = 20), local; base has no rate and drops out.
#   L = 20 + (6 + 6) = 32, P = 20, R = 52.
# Chain GL -> NC -> LP -> base: stages GL (batch head: period 1000 / 1.5), NC, local.
#   L = 20 + (50 + 50) + (6 + 6) = 132, P = 666.67, R = 798.67.
# Objective = 1.0 * 52 + 0.5 * 20 + 0.25 * 798.67 = 261.67.
def test_fixed_clock_batch_head_and_objective() -> None:
    problem = build_problem(parse_spec(NAV))
    timings = {"local": Timing(6, 6), "GL": Timing(20, 20), "NC": Timing(50, 50)}
    by_nodes = {chain.nodes: chain for chain in problem.chains}
    odom_chain = by_nodes[("odom", "LM", "LP", "base")]
    assert evaluate_chain(problem, odom_chain, timings).response_ms == pytest.approx(52)
    gl_chain = by_nodes[("GL", "NC", "LP", "base")]
    metrics = evaluate_chain(problem, gl_chain, timings)
    assert metrics.latency_ms == pytest.approx(132)
    assert metrics.period_ms == pytest.approx(1000 / 1.5)
    assert objective(problem, timings) == pytest.approx(52 + 10 + 0.25 * (132 + 1000 / 1.5))


def test_empty_chain_and_no_terms() -> None:
    assert chain_metrics([]).response_ms == 0
    problem = build_problem(parse_spec(NAV.split("objective:", maxsplit=1)[0]))
    assert objective(problem, {}) == 0
    assert math.isclose(sum(s.compute_ms for s in problem.subchains), 1 + 2 + 3 + 4 + 2)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problem=problems(max_subchains=6), data=st.data())
def test_chain_forms_agree_with_the_stage_by_stage_reference(problem: Problem, data: st.DataObject) -> None:
    # The solvers and the fast evaluation read chains through their forms; evaluate_chain walks
    # the stages one by one as section 2 states it. They must agree for any timings.
    positive = st.floats(0.01, 1000, allow_nan=False)
    timings = {sub.name: Timing(data.draw(positive), data.draw(positive)) for sub in problem.subchains}
    for index, chain in enumerate(problem.chains):
        fast, reference = chain_metrics_of(problem, index, timings), evaluate_chain(problem, chain, timings)
        assert fast.latency_ms == pytest.approx(reference.latency_ms, rel=1e-12)
        assert fast.period_ms == pytest.approx(reference.period_ms, rel=1e-12)
    # A problem with new compute times keeps the same chains, and so the same forms.
    first = problem.subchains[0] if problem.subchains else None
    if first is not None:
        updated = problem.with_compute({first.nodes[0]: 7.5})
        assert updated.chain_forms == problem.chain_forms
        assert updated.subchain(first.name).node_compute_ms[0] == 7.5


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problem=problems(max_subchains=6), data=st.data())
def test_weighted_sums_agree_with_the_terms_one_by_one(problem: Problem, data: st.DataObject) -> None:
    # The search rules a choice out when the per-subchain sums put it QUICK_MARGIN above a threshold:
    # they must be within far less than that of the objective as section 2 states it, term by term.
    positive = st.floats(0.01, 1000, allow_nan=False)
    timings = {sub.name: Timing(data.draw(positive), data.draw(positive)) for sub in problem.subchains}
    terms = [
        term.weight * evaluate_chain(problem, problem.chains[term.chain], timings).response_ms
        for term in problem.response_terms
    ]
    terms += [term.weight * timings[term.subchain].period_ms for term in problem.period_terms]
    reference = math.fsum(terms)
    assert WeightedSums.of(problem).value(timings) == pytest.approx(reference, rel=QUICK_MARGIN / 1000, abs=1e-12)
