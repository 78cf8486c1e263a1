"""Building the planning problem: collapsing chains, selectors, bounds, defaults."""

from __future__ import annotations

import itertools
import math

import pytest

from catanc.errors import SpecError
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.model.problem import Stage

NAV = """
catan: 1
app: nav
nodes:
  scan: {compute_ms: 0.5}
  odom: {scheduled: false, rate_hz: 50}
  LM: {compute_ms: 2}
  LP: {compute_ms: 3}
  GL: {compute_ms: {modes: [{share: 0.8, ms: 1}, {share: 0.2, ms: 30}]}, batch: {output_rate_hz: 1.5}}
  GM: {compute_ms: 150}
  GP: {compute_ms: 100, threads: {max: 2, speedup: [1.0, 1.8]}}
  NC: {compute_ms: 2}
  base: {scheduled: false}
edges: [[scan, LM], [odom, LM], [LM, LP], [scan, GL], [odom, GL], [GL, GM], [GM, GP], [GL, GP],
        [GP, NC], [GL, NC], "odom -> NC", [NC, LP], [LP, base]]
subchains: {local: [scan, LM, LP], GL: [GL], GM: [GM], GP: [GP], NC: [NC]}
objective:
  - {chain: [scan, LM, LP, base], weight: 1.0}
  - {node: GL, weight: 0.5}
  - {chains: {from: GL}, weight: 0.005}
constraints:
  - {node: GL, max_rate_hz: 50}
  - {node: GP, max_rate_hz: 1}
  - {node: LP, min_rate_hz: 20}
  - {node: LM, max_rate_hz: 200}
  - {chains: {from: GL, through: GM}, max_response_ms: 5000}
"""


def test_collapse_merges_subchains_and_keeps_fixed_clocks() -> None:
    problem = build_problem(parse_spec(NAV))
    stages = {chain.nodes: chain.stages for chain in problem.chains}
    # scan, LM, LP are one subchain; base has no rate and drops out.
    assert stages[("scan", "LM", "LP", "base")] == (Stage("local"),)
    # The three chains sourced at GL re-enter `local` at LP.
    assert stages[("GL", "GM", "GP", "NC", "LP", "base")] == tuple(
        Stage(name) for name in ("GL", "GM", "GP", "NC", "local")
    )
    assert stages[("GL", "NC", "LP", "base")] == (Stage("GL"), Stage("NC"), Stage("local"))
    assert problem.fixed_periods_ms == {"odom": 20.0}


def test_subchain_of_names_the_subchain_a_scheduled_node_runs_in() -> None:
    problem = build_problem(parse_spec(NAV))  # subchains: {local: [scan, LM, LP], GL: [GL], ...}
    assert {node: problem.subchain_of(node).name for node in ("scan", "LM", "LP", "GL", "GM", "GP", "NC")} == {
        "scan": "local",
        "LM": "local",
        "LP": "local",
        "GL": "GL",
        "GM": "GM",
        "GP": "GP",
        "NC": "NC",
    }
    with pytest.raises(KeyError):
        problem.subchain_of("odom")  # on a clock of its own: in no subchain


def test_selector_expands_to_one_term_per_path_and_dedupes_chains() -> None:
    problem = build_problem(parse_spec(NAV))
    from_gl = sorted(problem.chains[t.chain].nodes for t in problem.response_terms if t.weight == 0.005)
    assert from_gl == [
        ("GL", "GM", "GP", "NC", "LP", "base"),
        ("GL", "GP", "NC", "LP", "base"),
        ("GL", "NC", "LP", "base"),
    ]
    # The constraint's selector names a chain the objective already has: stored once.
    assert len(problem.chains) == 4
    (bound,) = problem.response_bounds
    assert problem.chains[bound.chain].nodes == ("GL", "GM", "GP", "NC", "LP", "base")
    assert bound.max_response_ms == 5000
    heads = {chain.nodes[0]: chain.head_period_ms for chain in problem.chains}
    assert heads["GL"] == pytest.approx(1000 / 1.5)
    assert heads["scan"] is None


def test_subchain_compute_bounds_and_batch() -> None:
    problem = build_problem(parse_spec(NAV))
    gl = problem.subchain("GL")
    assert gl.batch
    assert gl.compute_ms == pytest.approx(0.8 * 1 + 0.2 * 30)
    assert gl.min_period_ms == pytest.approx(20.0)
    assert gl.max_period_ms == math.inf
    local = problem.subchain("local")
    assert local.compute_ms == pytest.approx(5.5)
    # LP >= 20 Hz and LM <= 200 Hz, both in `local`: period in [5, 50] ms.
    assert local.min_period_ms == pytest.approx(5.0)
    assert local.max_period_ms == pytest.approx(50.0)
    assert not local.batch
    assert problem.subchain("GP").min_period_ms == pytest.approx(1000.0)


def test_fixed_rate_constraint_sets_both_bounds() -> None:
    spec = NAV.replace("{node: LM, max_rate_hz: 200}", "{node: LM, rate_hz: 100}")
    local = build_problem(parse_spec(spec)).subchain("local")
    assert local.min_period_ms == pytest.approx(10.0)
    assert local.max_period_ms == pytest.approx(10.0)


def test_defaults_follow_the_model() -> None:
    spec = parse_spec(NAV)
    assert (spec.schedule.slack, spec.schedule.switch_ms, spec.schedule.min_slice_ms) == (0.05, 0.12, 1.0)
    assert (spec.runtime.window, spec.runtime.percentile) == (50, 95)
    assert (spec.runtime.stage1_every_s, spec.runtime.stage2_every_s) == (20, 5)
    assert spec.nodes["LM"].threads.max == 1
    assert spec.nodes["odom"].scheduled is False


def test_empty_objective_is_a_warning() -> None:
    problem = build_problem(parse_spec(NAV.split("objective:", maxsplit=1)[0]))
    assert [w.field for w in problem.warnings] == ["objective"]


def test_selector_matching_too_many_paths_is_an_error() -> None:
    # 8 layers of 4 fully connected nodes: 4**8 = 65,536 paths > the 10,000 limit.
    layers = [[f"l{i}x{j}" for j in range(4)] for i in range(8)]
    nodes = "\n".join(f"  {n}: {{compute_ms: 1}}" for layer in layers for n in layer)
    edges = ", ".join(f"[{a}, {b}]" for up, low in itertools.pairwise(layers) for a in up for b in low)
    subchains = "\n".join(f"  s_{n}: [{n}]" for layer in layers for n in layer)
    text = f"catan: 1\napp: dense\nnodes:\n{nodes}\nedges: [{edges}]\nsubchains:\n{subchains}\n"
    text += "objective:\n  - {chains: {}, weight: 1}\n"
    with pytest.raises(SpecError) as info:
        parse_spec(text)
    (diagnostic,) = info.value.diagnostics
    assert "65,536 paths" in diagnostic.message
    assert diagnostic.field == "objective[0].chains"


def test_specs_built_in_python_report_fields_without_location() -> None:
    from catanc.spec.language import Spec

    spec = Spec.model_validate({"catan": 1, "app": "x", "nodes": {"a": {"compute_ms": 1}}, "subchains": {"s": ["b"]}})
    with pytest.raises(SpecError) as info:
        build_problem(spec)
    messages = [str(d) for d in info.value.diagnostics]
    assert "subchains.s[0]: unknown node 'b'" in messages


# --------------------------------------------------------------------------- rate parameters nothing caps

DRIVEN = """\
catan: 1
app: driven
nodes: {cam: {compute_ms: 5}, det: {compute_ms: 20}, motor: {scheduled: false}}
edges: [[cam, det], [det, motor]]
subchains: {main: [cam, det]}
objective: [{chain: [cam, det, motor], weight: 1}]
deploy:
  cam: {ros_node: /cam, rate_param: framerate}
  det: {ros_node: /det, rate_param: frequency}
"""


def rate_param_warnings(constraints: str) -> list[tuple[str, str]]:
    spec = parse_spec(DRIVEN + constraints)
    return [(w.field, w.message) for w in build_problem(spec).warnings if w.field.endswith(".rate_param")]


def test_a_rate_parameter_nothing_caps_is_warned_about_once_per_subchain() -> None:
    ((field, message),) = rate_param_warnings("")
    assert field == "deploy.cam.rate_param"  # the subchain's first node with one
    assert "{node: cam, rate_hz: [15, 30]}" in message
    assert "{node: cam, max_rate_hz: ...}" in message


@pytest.mark.parametrize(
    "constraint",
    ["{node: det, max_rate_hz: 40}", "{node: cam, rate_hz: 30}", "{node: cam, rate_hz: [15, 30]}"],
)
def test_a_cap_a_fixed_rate_or_offered_rates_silence_it(constraint: str) -> None:
    assert rate_param_warnings(f"constraints: [{constraint}]\n") == []


def test_a_rate_floor_alone_does_not() -> None:
    assert len(rate_param_warnings("constraints: [{node: det, min_rate_hz: 5}]\n")) == 1
