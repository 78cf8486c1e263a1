"""Rates a driver offers (``{node: camera, rate_hz: [15, 30]}``): the plan runs the subchain at one of them.

Checked by hand (face tracking's one dedicated subchain), and on small random apps against an
enumeration written here, independent of Stage II's search: every offered rate, every whole
``n`` and every trigger interval ``k >= n``, each with the least ``T`` that fits the slices and
meets the offered period ``k T >= P`` (a longer ``T`` only lengthens every latency and period).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.model.metrics import Timing, bound_scale, objective
from catanc.model.problem import Problem
from catanc.planning.planner import plan
from catanc.planning.replan import Replanner
from catanc.planning.stage2.base import Layout, SharedCore
from catanc.planning.stage2.conic import ConicStage2
from catanc.planning.stage2.integer import most_runs
from catanc.planning.stage2.solve import solve_layout
from catanc.spec.language import Schedule

ROOT = Path(__file__).resolve().parents[2]
RELATIVE = 1e-6


# --------------------------------------------------------------------------- face tracking, by hand

# c = 25 + 58 + 1 = 84 ms. On 2 dedicated cores Eq. 1 pipelines to max(58, 84 / 2) = 58 ms, with the 5%
# slack 61.053 ms: 15 Hz (66.667 ms) fits, R = 84 + 66.667 = 150.667 ms; 30 Hz (33.333 ms) does not.
# On 1 core the subchain needs 84 / 0.95 = 88.421 ms: neither fits, and 15 Hz needs the least
# scale, 88.421 / 66.667 = 1.3263 (30 Hz: 2.6526); R = 84 + 88.421 = 172.421 ms.
FACE_TWO_CORES = 84.0 + 1000.0 / 15
FACE_ONE_CORE = 84.0 + 84.0 / 0.95


def test_face_tracking_picks_15_hz_on_two_cores() -> None:
    found = plan(load_spec(ROOT / "specs" / "face_tracking.yaml"), 2)
    assert found.subchains["tracking"].period_ms == pytest.approx(1000.0 / 15, rel=1e-12)
    assert found.offered_periods_ms == {"tracking": pytest.approx(1000.0 / 15, rel=1e-12)}
    assert found.objective == pytest.approx(FACE_TWO_CORES, rel=1e-9)
    assert found.constraint_scale == 1.0
    (choice,) = found.offered
    assert (choice.node, choice.offered_hz, choice.picked_hz) == ("camera", (15.0, 30.0), 15.0)
    # A free rate: the subchain's own period, 58 / 0.95 ms.
    assert choice.free_hz == pytest.approx(0.95 * 1000.0 / 58, rel=1e-9)
    assert choice.free_objective == pytest.approx(84.0 + 58.0 / 0.95, rel=1e-9)


def test_face_tracking_on_one_core_scales_the_slowest_offered_rate_and_says_so() -> None:
    found = plan(load_spec(ROOT / "specs" / "face_tracking.yaml"), 1)
    assert found.offered_periods_ms == {"tracking": pytest.approx(1000.0 / 15, rel=1e-12)}
    assert found.constraint_scale == pytest.approx((84.0 / 0.95) / (1000.0 / 15), rel=1e-6)
    assert found.objective == pytest.approx(FACE_ONE_CORE, rel=1e-9)
    assert any("none of the rates its driver offers (15, 30 Hz)" in warning for warning in found.warnings)


# --------------------------------------------------------------------------- semantics on a shared core

# a (2 ms) offers 40 or 100 Hz, b (3 ms) is free, both on one core, no slack or switches, slices of at
# least 1 ms. Objective: a's period + b's period. With n = (1, 1), T fits at 5 ms. At 100 Hz (10 ms)
# a is triggered every k = 2 periods: 10 + 5 = 15. At 40 Hz (25 ms): k = 5, 25 + 5 = 30. So 100 Hz.
# (Free, a would run every period: 5 + 5 = 10.)
SHARED = """\
catan: 1
app: shared
nodes: {a: {compute_ms: 2}, b: {compute_ms: 3}}
subchains: {A: [a], B: [b]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}]
constraints: [{node: a, rate_hz: [40, 100]}]
schedule: {slack: 0, switch_ms: 0, min_slice_ms: 1}
"""


def test_a_shared_subchain_runs_at_an_offered_rate_on_the_slot_grid() -> None:
    found = plan(parse_spec(SHARED), 1)
    assert found.subchains["A"].period_ms == pytest.approx(10.0, rel=1e-9)
    assert found.objective == pytest.approx(15.0, rel=1e-9)
    (core,) = found.shared_cores
    assert found.subchains["A"].period_ms == pytest.approx(found.every["A"] * core.period_ms, rel=1e-9)
    (choice,) = found.offered
    assert (choice.node, choice.offered_hz, choice.picked_hz) == ("a", (40.0, 100.0), 100.0)
    assert choice.free_objective == pytest.approx(10.0, rel=1e-9)


def test_re_planning_with_new_compute_times_keeps_to_the_offered_rates() -> None:
    spec = parse_spec(SHARED)
    replanner = Replanner(spec, 1)
    layout = Layout((), (SharedCore(0, ("A", "B")),))
    for compute in ({"a": 2.0, "b": 20.0}, {"a": 9.0, "b": 30.0}, {"a": 2.0, "b": 3.0}):
        found = replanner.resolve(compute)
        problem = build_problem(spec).with_compute(compute)
        _, best, _ = oracle(problem, layout, spec.schedule)
        assert found.objective == pytest.approx(best, rel=RELATIVE)
        assert found.subchains["A"].period_ms in (10.0, 25.0)
        assert found.offered_periods_ms == {"A": found.subchains["A"].period_ms}


def test_a_one_element_list_is_a_fixed_rate() -> None:
    listed = build_problem(parse_spec(SHARED.replace("rate_hz: [40, 100]", "rate_hz: [100]")))
    fixed = build_problem(parse_spec(SHARED.replace("rate_hz: [40, 100]", "rate_hz: 100")))
    assert listed == fixed
    assert not listed.offered()


# --------------------------------------------------------------------------- against enumeration


def oracle(problem: Problem, layout: Layout, schedule: Schedule) -> tuple[float, float, float]:
    """(least scale, the best objective at it, ...) over every offered rate, ``n`` and ``k``: by brute force.

    Returns (least scale, best objective at scale 1 (inf: none), best objective at the least scale).
    One shared core of non-batch subchains; the rest dedicated.
    """
    (core,) = layout.shared
    names = list(core.subchains)
    offered = [sub for sub in problem.subchains if sub.offered_periods_ms]
    by_name = {sub.name: sub for sub in problem.subchains}
    usable = 1.0 - schedule.slack
    results: list[tuple[float, float]] = []  # (scale, objective) of every point
    for periods in itertools.product(*(sub.offered_periods_ms for sub in offered)):
        fixed = problem.choosing({sub.name: p for sub, p in zip(offered, periods, strict=True)})
        subs = {name: fixed.subchain(name) for name in names}
        dedicated = {}
        for name, cores in layout.dedicated:
            sub = fixed.subchain(name)
            # Eq. 1 with one thread per node (the strategy's nodes take one), then the slack and cap.
            period = max(*sub.node_compute_ms, sub.compute_ms / cores) / usable
            dedicated[name] = Timing(max(period, sub.min_period_ms), sub.compute_ms)
        for runs in itertools.product(*(range(1, most_runs(by_name[n].compute_ms, schedule) + 1) for n in names)):
            n = dict(zip(names, runs, strict=True))
            fit = (sum(subs[x].compute_ms / n[x] for x in names) + len(names) * schedule.switch_ms) / usable
            ranges = [
                range(n[x], max(n[x], math.ceil(subs[x].min_period_ms / fit)) + 1) if subs[x].min_period_ms else [n[x]]
                for x in names
            ]
            for every in itertools.product(*ranges):
                k = dict(zip(names, every, strict=True))
                length = max([fit] + [subs[x].min_period_ms / k[x] for x in names])
                timings = dict(dedicated)
                timings.update({x: Timing(k[x] * length, n[x] * length) for x in names})
                results.append((max(1.0, bound_scale(fixed, timings)), objective(fixed, timings)))
    least = min(scale for scale, _ in results)
    at_one = min((value for scale, value in results if scale <= 1.0 + 1e-9), default=math.inf)
    at_least = min(value for scale, value in results if scale <= least * (1 + 1e-9))
    return least, at_one, at_least


@st.composite
def offered_apps(draw: st.DrawFn) -> tuple[str, Layout]:
    """2-3 one-node subchains on one shared core in a chain, maybe one dedicated, 1-2 offering rates."""
    count = draw(st.integers(2, 3))
    names = [f"n{i}" for i in range(count)]
    compute = [draw(st.sampled_from([1.0, 2.0, 3.5, 5.0])) for _ in names]
    rates = [40.0, 60.0, 100.0, 150.0, 250.0]
    lines = []
    offering = draw(st.lists(st.sampled_from(names), min_size=1, max_size=2, unique=True))
    for name in offering:
        listed = sorted(draw(st.lists(st.sampled_from(rates), min_size=2, max_size=3, unique=True)))
        lines.append(f"  - {{node: {name}, rate_hz: [{', '.join(f'{r:g}' for r in listed)}]}}")
    others = [name for name in names if name not in offering]
    capped: bool = draw(st.booleans())
    if others and capped:
        lines.append(f"  - {{node: {others[0]}, max_rate_hz: {draw(st.sampled_from(rates)):g}}}")
    bound = draw(st.sampled_from([None, 30.0, 80.0]))
    if bound is not None:
        lines.append(f"  - {{chain: [{', '.join(names)}], max_response_ms: {bound:g}}}")
    weights = [draw(st.sampled_from([0.0, 0.5, 1.0])) for _ in names]
    slack, switch = draw(st.sampled_from([0.0, 0.05])), draw(st.sampled_from([0.0, 0.12]))
    objective_lines = [f"  - {{chain: [{', '.join(names)}], weight: 1}}"]
    objective_lines += [f"  - {{node: {n}, weight: {w:g}}}" for n, w in zip(names, weights, strict=True) if w]
    text = "\n".join(
        [
            "catan: 1",
            "app: offered",
            "nodes:",
            *(f"  {n}: {{compute_ms: {c:g}}}" for n, c in zip(names, compute, strict=True)),
            f"edges: [{', '.join(f'[{a}, {b}]' for a, b in itertools.pairwise(names))}]",
            "subchains: {" + ", ".join(f"S{n}: [{n}]" for n in names) + "}",
            "objective:",
            *objective_lines,
            "constraints:",
            *lines,
            f"schedule: {{slack: {slack:g}, switch_ms: {switch:g}, min_slice_ms: 1.2}}",
            "",
        ]
    )
    subchains = [f"S{n}" for n in names]
    dedicated: tuple[tuple[str, int], ...] = ()
    if count == 3 and draw(st.booleans()):
        dedicated = ((subchains.pop(draw(st.integers(0, 2))), 1),)
    return text, Layout(dedicated, (SharedCore(0, tuple(subchains)),))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(app=offered_apps())
def test_stage2_matches_enumeration_over_the_offered_rates(app: tuple[str, Layout]) -> None:
    text, layout = app
    spec = parse_spec(text)
    problem = build_problem(spec)
    result = solve_layout(problem, layout, spec.schedule, ConicStage2(problem, layout, spec.schedule))
    assert result is not None
    least, at_one, at_least = oracle(problem, layout, spec.schedule)
    for sub in problem.offered():  # each runs at exactly the offered period picked (scaled: up to s times it)
        picked = result.offered[sub.name]
        assert any(picked == pytest.approx(period, rel=1e-12) for period in sub.offered_periods_ms)
        period = result.timings[sub.name].period_ms
        assert picked * (1 - RELATIVE) <= period <= picked * result.scale * (1 + RELATIVE)
    if math.isfinite(at_one):
        assert result.scale == pytest.approx(1.0, rel=1e-9)
        assert result.objective == pytest.approx(at_one, rel=RELATIVE)
        for sub in problem.offered():
            assert result.timings[sub.name].period_ms == pytest.approx(result.offered[sub.name], rel=RELATIVE)
    else:
        assert result.scale == pytest.approx(least, rel=1e-5)
        assert result.objective <= at_least * (1 + 1e-5)
