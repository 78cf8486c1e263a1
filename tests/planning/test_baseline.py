"""The baseline under fair sharing: closed-form cases worked by hand, and the example specs' own notes;
fifo-static's static priorities: the paper's order for VR, cases by hand, and properties over random apps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import given

from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.planning.baseline import BaselineEvaluation, BaselineGap, evaluate_baseline, static_priorities
from tests.support.strategies import spec_documents, spec_of

SPECS = Path(__file__).parents[2] / "specs"

# a (10 ms) on a 20 Hz timer feeds b (5 ms, on a's output) feeds an actuator; odom is a 50 Hz clock into b.
PAIR = """
catan: 1
app: pair
nodes:
  a: {compute_ms: 10}
  b: {compute_ms: 5}
  odom: {scheduled: false, rate_hz: 50}
  out: {scheduled: false}
edges: [[a, b], [odom, b], [b, out]]
subchains: {A: [a], B: [b]}
objective:
  - {chain: [a, b, out], weight: 2.0}
  - {chain: [odom, b, out], weight: 1.0}
  - {node: b, weight: 0.5}
baseline:
  rates_hz: {a: 20}
"""


def evaluate(text: str, cores: int) -> BaselineEvaluation:
    spec = parse_spec(text)
    result = evaluate_baseline(spec, build_problem(spec), cores)
    assert isinstance(result, BaselineEvaluation), result
    return result


def responses(result: BaselineEvaluation, text: str) -> dict[tuple[str, ...], float]:
    problem = build_problem(parse_spec(text))
    return {chain.nodes: m.response_ms for chain, m in zip(problem.chains, result.chains, strict=True)}


def test_two_nodes_on_one_core() -> None:
    result = evaluate(PAIR, 1)
    # b inherits a's 50 ms period (odom is a sensor: a pipeline input comes first).
    assert result.nodes["a"].period_ms == pytest.approx(50)
    assert result.nodes["b"].period_ms == pytest.approx(50)
    assert result.nodes["b"].trigger == "a"
    # rho = 10/50 + 5/50 = 0.3; l = c / 0.7.
    assert result.utilisation == pytest.approx(0.3)
    assert not result.overloaded
    assert result.nodes["a"].latency_ms == pytest.approx(100 / 7)
    assert result.nodes["b"].latency_ms == pytest.approx(50 / 7)
    # a -> b -> out: l_a + (p_b + l_b) + max(p_a, p_b) = 100/7 + 50 + 50/7 + 50.
    # odom -> b -> out: 20 (the clock's l = p) + (50 + 50/7) + max(20, 50).
    chains = responses(result, PAIR)
    assert chains[("a", "b", "out")] == pytest.approx(150 / 7 + 100)
    assert chains[("odom", "b", "out")] == pytest.approx(20 + 50 + 50 / 7 + 50)
    expected = 2 * (150 / 7 + 100) + 1 * (120 + 50 / 7) + 0.5 * 50
    assert result.objective == pytest.approx(expected)
    assert [t.contribution for t in result.terms] == pytest.approx([2 * (150 / 7 + 100), 120 + 50 / 7, 25])


def test_two_cores_halve_the_utilisation() -> None:
    result = evaluate(PAIR, 2)
    assert result.utilisation == pytest.approx(0.15)
    assert result.nodes["a"].latency_ms == pytest.approx(10 / 0.85)
    assert responses(result, PAIR)[("a", "b", "out")] == pytest.approx(15 / 0.85 + 100)


def test_overloaded_baseline_is_stretched() -> None:
    heavy = PAIR.replace("a: {compute_ms: 10}", "a: {compute_ms: 40}").replace(
        "b: {compute_ms: 5}", "b: {compute_ms: 20}"
    )
    result = evaluate(heavy, 1)
    # rho = 40/50 + 20/50 = 1.2 >= 0.95: periods x 1.2/0.95, latencies at rho = 0.95 (c / 0.05).
    assert result.utilisation == pytest.approx(1.2)
    assert result.overloaded
    assert result.stretch == pytest.approx(1.2 / 0.95)
    period = 50 * 1.2 / 0.95
    assert result.nodes["a"].period_ms == pytest.approx(period)
    assert result.nodes["b"].period_ms == pytest.approx(period)
    assert result.nodes["a"].latency_ms == pytest.approx(800)
    assert result.nodes["b"].latency_ms == pytest.approx(400)
    assert responses(result, heavy)[("a", "b", "out")] == pytest.approx(800 + period + 400 + period)
    # Stretched, the load is exactly the cap.
    load = sum(row.compute_ms / row.period_ms for row in result.nodes.values())
    assert load == pytest.approx(0.95)


INHERIT = """
catan: 1
app: inherit
nodes:
  s1: {compute_ms: 1}
  s2: {compute_ms: 1}
  imu: {scheduled: false, rate_hz: 200}
  relay: {scheduled: false}
  c: {compute_ms: 1}
  d: {compute_ms: 1}
  e: {compute_ms: 1}
  f: {compute_ms: 1}
  g: {compute_ms: 1}
edges: [[s1, c], [s2, c], [c, d], [imu, e], [s1, f], [imu, f], [s2, relay], [relay, g]]
subchains: {S1: [s1], S2: [s2], C: [c, d], E: [e], F: [f], G: [g]}
objective: [{chain: [s1, c, d], weight: 1}]
baseline:
  rates_hz: {s1: 10, s2: 40}
"""


def test_unlisted_nodes_inherit_periods() -> None:
    result = evaluate(INHERIT, 1)
    periods = {name: row.period_ms for name, row in result.nodes.items()}
    assert periods["s1"] == pytest.approx(100)
    assert periods["s2"] == pytest.approx(25)
    assert periods["c"] == pytest.approx(25)  # the faster of s1 (100 ms) and s2 (25 ms)
    assert result.nodes["c"].trigger == "s2"
    assert periods["d"] == pytest.approx(25)  # through c, in topological order
    assert periods["e"] == pytest.approx(5)  # only a sensor feeds it: the sensor's 200 Hz
    assert periods["f"] == pytest.approx(100)  # s1 and the sensor: the pipeline input wins
    assert periods["g"] == pytest.approx(25)  # through a rate-less unscheduled relay
    assert result.nodes["s1"].trigger is None
    assert result.nodes["s1"].rate_hz == 10


def test_a_node_without_any_rate_makes_the_baseline_incomplete() -> None:
    text = INHERIT.replace("rates_hz: {s1: 10, s2: 40}", "rates_hz: {s1: 10}")
    spec = parse_spec(text)
    result = evaluate_baseline(spec, build_problem(spec), 1)
    assert isinstance(result, BaselineGap)
    assert result.nodes == ("s2", "g")  # s2 has no input at all; g only gets s2's output through the relay
    assert "incomplete" in result.reason
    assert "s2, g have no rate" in result.reason


def test_no_baseline() -> None:
    text = PAIR.replace("baseline:\n  rates_hz: {a: 20}\n", "")
    spec = parse_spec(text)
    result = evaluate_baseline(spec, build_problem(spec), 1)
    assert isinstance(result, BaselineGap)
    assert "no baseline" in result.reason


def test_a_batch_head_uses_its_observed_period() -> None:
    text = """
catan: 1
app: batch
nodes:
  g: {compute_ms: 4, batch: {output_rate_hz: 2}}
  h: {compute_ms: 6}
edges: [[g, h]]
subchains: {G: [g], H: [h]}
objective: [{chain: [g, h], weight: 1}, {node: g, weight: 1}]
baseline: {rates_hz: {g: 50, h: 10}}
"""
    result = evaluate(text, 1)
    # rho = 4/20 + 6/100 = 0.26; chain: l_g + (p_h + l_h) + max(500, 100), g's period 500 ms as the head.
    assert result.utilisation == pytest.approx(0.26)
    expected = 4 / 0.74 + 100 + 6 / 0.74 + 500
    assert responses(result, text)[("g", "h")] == pytest.approx(expected)
    assert result.terms[1].value_ms == pytest.approx(20)  # the period term: g's timer, not the observed rate


@pytest.mark.parametrize(
    ("name", "utilisation"),
    [
        # The load each spec's header works out by hand for one core.
        ("nav2d", 0.2 * 50 + 0.8 * 5 + 0.5 * 10 + 3.2 * 50 + 150 * 0.2 + 100 * 1 + 1.0 * 10),
        ("vr_illixr", 1.5 * 120 + 3 * 120 + 1.5 * 20 + 10 * 20),
        ("face_tracking", 84 * 30),
    ],
)
def test_example_loads_match_the_specs_notes(name: str, utilisation: float) -> None:
    spec = load_spec(SPECS / f"{name}.yaml")
    result = evaluate_baseline(spec, build_problem(spec), 1)
    assert isinstance(result, BaselineEvaluation)
    assert result.utilisation == pytest.approx(utilisation / 1000)
    assert result.overloaded == (name == "face_tracking")  # 2.5 cores of work at 30 Hz, as the spec says


def test_cores_must_be_positive() -> None:
    spec = parse_spec(PAIR)
    with pytest.raises(ValueError, match="at least one core"):
        evaluate_baseline(spec, build_problem(spec), 0)


# -- fifo-static's static priorities ------------------------------------------------------------


def test_vr_fifo_static_runs_the_papers_order_not_the_stealing_priorities() -> None:
    """docs/explanation/model.md section 7: Timewarp, then Render, then Camera -> VIO (IMU and Int are unscheduled
    clocks, above every thread); every subchain its own level.  The spec's schedule.priorities
    (timewarp 1, vio 0, render 0) rank stealing and put Render and VIO on one level."""
    spec = load_spec(SPECS / "vr_illixr.yaml")
    assert spec.schedule.priorities == {"timewarp": 1, "vio": 0, "render": 0}
    assert static_priorities(spec, build_problem(spec)) == {"timewarp": 3, "render": 2, "vio": 1}


def test_a_tie_in_weight_goes_to_the_subchain_nearer_the_chains_end() -> None:
    # One chain a -> b -> out through both: equal weight; b finishes what a started, so b first.
    text = PAIR.replace("  - {chain: [odom, b, out], weight: 1.0}\n  - {node: b, weight: 0.5}\n", "")
    spec = parse_spec(text)
    assert static_priorities(spec, build_problem(spec)) == {"A": 1, "B": 2}
    # PAIR: a -> b (2.0) and odom -> b (1.0) and b's period (0.5): B weighs 3.5, A 2.0.
    spec = parse_spec(PAIR)
    assert static_priorities(spec, build_problem(spec)) == {"A": 1, "B": 2}


def test_the_specs_baseline_priorities_win_and_unlisted_subchains_are_lowest() -> None:
    spec = parse_spec(PAIR + "  priorities: {A: 7}\n")
    assert static_priorities(spec, build_problem(spec)) == {"A": 7, "B": 0}
    # Written into runtime tables only when given: those of specs without it stay as they were.
    assert spec.model_dump()["baseline"]["priorities"] == {"A": 7}
    assert "priorities" not in parse_spec(PAIR).model_dump()["baseline"]


@given(spec_documents())
def test_every_subchain_its_own_level_the_heavier_higher(document: dict[str, Any]) -> None:
    spec = spec_of(document)
    problem = build_problem(spec)
    levels = static_priorities(spec, problem)
    assert sorted(levels.values()) == list(range(1, len(problem.subchains) + 1))
    # The weight through each subchain, summed here from the terms themselves.
    weight = {sub.name: 0.0 for sub in problem.subchains}
    for term in problem.response_terms:
        for name in {stage.name for stage in problem.chains[term.chain].stages if not stage.fixed}:
            weight[name] += term.weight
    for period_term in problem.period_terms:
        weight[period_term.subchain] += period_term.weight
    for a, heavier in weight.items():
        for b, lighter in weight.items():
            if heavier > lighter + 1e-12:
                assert levels[a] > levels[b], (a, b, weight)
