"""The workload model: spec validation and ComputeSampler's draws, checked against closed forms and statistics.

Statistical checks use tolerances of 6 standard errors computed from the
distribution's own moments, so a correct sampler fails one with probability
under 1e-8 per check whatever seed hypothesis picks.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.errors import SpecError
from catanc.model.load import parse_spec
from catanc.model.workload import ComputeSampler, growth_factor
from catanc.planning.planner import plan
from catanc.spec.language import Growth, Spec, Workload

untimed = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])  # tests never time things
SIGMAS = 6.0
seeds = st.integers(-(2**63), 2**63)


def spec_with(work: dict[str, Any] | None, compute: Any = 10.0, other: dict[str, Any] | None = None) -> Spec:
    """A two-node app: ``work`` is node ``w``'s workload, ``other`` node ``o``'s whole entry."""
    node: dict[str, Any] = {"compute_ms": compute}
    if work is not None:
        node["workload"] = work
    document = {
        "catan": 1,
        "app": "workload",
        "nodes": {"w": node, "o": other or {"compute_ms": 3.0}, "sink": {"scheduled": False}},
        "edges": [["w", "o"], ["o", "sink"]],
        "subchains": {"main": ["w", "o"]},
        "objective": [{"chain": ["w", "o", "sink"], "weight": 1.0}],
    }
    return parse_spec(yaml.safe_dump(document, sort_keys=False), "workload.yaml")


FULL = {
    "growth": {"start": 0.6, "end": 2.0, "over_s": 300},
    "jitter": {"cv": 0.2},
    "spikes": {"every_s": 5, "ms": 250},
}
MODAL = {"modes": [{"share": 0.8, "ms": 1.0}, {"share": 0.2, "ms": 12.0}]}


# --------------------------------------------------------------------------- (a) determinism


calls = st.lists(st.tuples(st.sampled_from(["w", "o"]), st.floats(0, 2.0)), max_size=200)


@untimed
@given(seed=seeds, steps=calls)
def test_same_seed_same_values_and_nodes_do_not_share_streams(seed: int, steps: list[tuple[str, float]]) -> None:
    spec = spec_with(FULL, compute=MODAL, other={"compute_ms": 3.0, "workload": FULL})
    at = {"w": 0.0, "o": 0.0}
    timeline = []
    for node, gap in steps:  # non-decreasing times per node
        at[node] += gap
        timeline.append((node, at[node]))
    first, second, only_o = ComputeSampler(spec, seed), ComputeSampler(spec, seed), ComputeSampler(spec, seed)
    one = [first.compute_ms(node, t) for node, t in timeline]
    assert one == [second.compute_ms(node, t) for node, t in timeline]
    # o's values do not depend on whether, or how often, w was drawn in between.
    o_alone = [only_o.compute_ms("o", t) for node, t in timeline if node == "o"]
    assert o_alone == [value for (node, _), value in zip(timeline, one, strict=True) if node == "o"]


@untimed
@given(
    seed=seeds,
    jitter=st.sampled_from(["lognormal", "uniform", "normal"]),
    counts=st.lists(st.integers(0, 3000), max_size=8),
)
def test_draws_taken_in_any_chunks_are_the_same_values(seed: int, jitter: str, counts: list[int]) -> None:
    """``bases(n)`` (the compiled simulator's draws ahead) is n single ``base()`` draws, across blocks."""
    spec = spec_with({"jitter": {"cv": 0.3, "dist": jitter}}, compute=MODAL)
    chunked, single = ComputeSampler(spec, seed).stream("w"), ComputeSampler(spec, seed).stream("w")
    for count in counts:
        modes, factors = chunked.bases(count)
        expected = [single.base() for _ in range(count)]
        assert list(zip(modes.tolist(), factors.tolist(), strict=True)) == expected


def test_seeds_and_names_give_different_streams() -> None:
    spec = spec_with({"jitter": {"cv": 0.3}}, other={"compute_ms": 10.0, "workload": {"jitter": {"cv": 0.3}}})

    def draws(seed: int, node: str) -> tuple[float, ...]:
        sampler = ComputeSampler(spec, seed)
        return tuple(sampler.compute_ms(node, 0.0) for _ in range(20))

    # w and o have the same compute and jitter: only the seed and the name tell their streams apart.
    assert len({draws(seed, node) for seed in (0, 1) for node in ("w", "o")}) == 4


SUBPROCESS = """
import json, sys
from catanc.model.load import parse_spec
from catanc.model.workload import ComputeSampler
spec = parse_spec(sys.stdin.read(), "workload.yaml")
sampler = ComputeSampler(spec, 7)
print(json.dumps([sampler.compute_ms(node, t / 10) for t in range(50) for node in ("w", "o")]))
"""


def test_streams_do_not_depend_on_the_process_hash_seed() -> None:
    """Seeds come from a stable hash: Python's hash() of a name changes with PYTHONHASHSEED."""
    document = {
        "catan": 1,
        "app": "workload",
        "nodes": {"w": {"compute_ms": MODAL, "workload": FULL}, "o": {"compute_ms": 3.0, "workload": FULL}},
        "edges": [["w", "o"]],
        "subchains": {"main": ["w", "o"]},
    }
    text = yaml.safe_dump(document, sort_keys=False)
    outputs = []
    for hash_seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed}
        result = subprocess.run(
            [sys.executable, "-c", SUBPROCESS], input=text, capture_output=True, text=True, env=env, check=True
        )
        outputs.append(json.loads(result.stdout))
    assert outputs[0] == outputs[1]
    sampler = ComputeSampler(parse_spec(text, "workload.yaml"), 7)
    assert outputs[0] == [sampler.compute_ms(node, t / 10) for t in range(50) for node in ("w", "o")]


# --------------------------------------------------------------------------- (b) growth


@untimed
@given(
    compute=st.floats(0.1, 1000),
    start=st.floats(0.05, 10),
    end=st.floats(0.05, 10),
    over_s=st.floats(0.01, 10_000),
    seed=seeds,
)
def test_growth_is_linear_then_holds(compute: float, start: float, end: float, over_s: float, seed: int) -> None:
    spec = spec_with({"growth": {"start": start, "end": end, "over_s": over_s}}, compute=compute)
    sampler = ComputeSampler(spec, seed)
    workload = spec.nodes["w"].workload
    # By hand: start at 0, the midpoint at over_s/2, end at over_s and after.
    for at_s, factor in [(0.0, start), (over_s / 2, (start + end) / 2), (over_s, end), (2 * over_s, end)]:
        assert growth_factor(workload, at_s) == pytest.approx(factor, rel=1e-12)
        assert sampler.compute_ms("w", at_s) == pytest.approx(compute * factor, rel=1e-12)


def test_growth_factor_without_growth_and_before_the_start() -> None:
    assert growth_factor(None, 123.0) == 1.0
    assert growth_factor(Workload(), 123.0) == 1.0
    assert growth_factor(Workload(growth=Growth(end=3.0, over_s=10.0)), 5.0) == 2.0  # start defaults to 1
    assert growth_factor(Workload(growth=Growth(start=0.5, end=3.0, over_s=10.0)), -4.0) == 0.5


# --------------------------------------------------------------------------- (c) jitter


def jitter_kurtosis(dist: str, cv: float) -> float:
    """Fourth standardised moment of the multiplier (mean 1, standard deviation cv)."""
    if dist == "uniform":
        return 1.8
    if dist == "normal":
        return 3.0  # the redraw below 0 happens with probability < 5e-4 at cv <= 0.3
    s2 = math.log1p(cv * cv)  # lognormal's sigma^2
    return math.exp(4 * s2) + 2 * math.exp(3 * s2) + 3 * math.exp(2 * s2) - 3


jitters = st.one_of(
    st.tuples(st.just("lognormal"), st.floats(0.01, 1.0)),
    st.tuples(st.just("uniform"), st.floats(0.01, 0.5)),
    st.tuples(st.just("normal"), st.floats(0.01, 0.3)),
)


@settings(untimed, max_examples=30)
@given(jitter=jitters, compute=st.floats(0.5, 500), seed=seeds)
def test_jitter_has_mean_one_and_the_given_cv(jitter: tuple[str, float], compute: float, seed: int) -> None:
    dist, cv = jitter
    sampler = ComputeSampler(spec_with({"jitter": {"cv": cv, "dist": dist}}, compute=compute), seed)
    n = 20_000
    factors = [sampler.compute_ms("w", i * 0.01) / compute for i in range(n)]
    assert min(factors) > 0
    mean = statistics.fmean(factors)
    variance = statistics.variance(factors)
    assert abs(mean - 1.0) <= SIGMAS * cv / math.sqrt(n)
    # Var(sample variance) ~ (mu4 - sigma^4) / n = sigma^4 (kurtosis - 1) / n.
    assert abs(variance / cv**2 - 1.0) <= SIGMAS * math.sqrt((jitter_kurtosis(dist, cv) - 1) / n)
    if dist == "uniform":
        width = math.sqrt(3) * cv
        assert min(factors) >= 1 - width - 1e-12
        assert max(factors) <= 1 + width + 1e-12


def test_jitter_of_zero_and_none_draw_compute_exactly() -> None:
    for work in ({"jitter": {"cv": 0}}, None, {}):
        sampler = ComputeSampler(spec_with(work, compute=7.5), 3)
        assert {sampler.compute_ms("w", i / 3) for i in range(100)} == {7.5}


@settings(untimed, max_examples=10)
@given(seed=seeds, at_s=st.floats(0, 600))
def test_jitter_multiplies_the_grown_time(seed: int, at_s: float) -> None:
    spec = spec_with({"growth": {"start": 0.6, "end": 2.0, "over_s": 300}, "jitter": {"cv": 0.2}}, compute=100)
    sampler = ComputeSampler(spec, seed)
    n = 10_000
    draws = [sampler.compute_ms("w", at_s) for _ in range(n)]
    expected = 100 * growth_factor(spec.nodes["w"].workload, at_s)
    assert abs(statistics.fmean(draws) / expected - 1) <= SIGMAS * 0.2 / math.sqrt(n)


# --------------------------------------------------------------------------- (d) modes


@st.composite
def mode_lists(draw: st.DrawFn) -> list[dict[str, float]]:
    times = draw(st.lists(st.integers(1, 500), min_size=1, max_size=5, unique=True))
    weights = draw(st.lists(st.integers(1, 20), min_size=len(times), max_size=len(times)))
    total = sum(weights)
    return [{"share": weight / total, "ms": float(ms)} for weight, ms in zip(weights, times, strict=True)]


@settings(untimed, max_examples=30)
@given(modes=mode_lists(), seed=seeds, grown=st.booleans())
def test_modes_are_drawn_by_share(modes: list[dict[str, float]], seed: int, grown: bool) -> None:
    work = {"growth": {"start": 0.5, "end": 4.0, "over_s": 100}} if grown else None
    spec = spec_with(work, compute={"modes": modes})
    sampler = ComputeSampler(spec, seed)
    n = 20_000
    times = [i * 0.01 for i in range(n)]
    # With growth, a draw divided by the growth factor at its time is a mode's ms.
    unscaled = [round(sampler.compute_ms("w", t) / growth_factor(spec.nodes["w"].workload, t), 9) for t in times]
    counts = {mode["ms"]: 0 for mode in modes}
    for value in unscaled:
        counts[value] += 1  # a KeyError here: a draw that is no mode
    for mode in modes:
        p = mode["share"]
        assert abs(counts[mode["ms"]] / n - p) <= SIGMAS * math.sqrt(p * (1 - p) / n) + 1e-12


# --------------------------------------------------------------------------- (e) spikes

SPIKE_MS = 250.0
WITH_SPIKES = {"growth": {"start": 0.6, "end": 2.0, "over_s": 300}, "jitter": {"cv": 0.1}}


def spike_spec(every_s: float) -> Spec:
    # Growth and jitter make every normal draw differ from SPIKE_MS: a draw equal to it is a spike.
    return spec_with({**WITH_SPIKES, "spikes": {"every_s": every_s, "ms": SPIKE_MS}}, compute=100)


@settings(untimed, max_examples=25)
@given(every_s=st.floats(0.5, 60), calls_per_mean=st.integers(1, 40), seed=seeds)
def test_spike_count_matches_poisson_arrivals(every_s: float, calls_per_mean: int, seed: int) -> None:
    """Calls every dt: a call is a spike iff an arrival fell in the dt before it, p = 1 - exp(-dt / every_s)."""
    sampler = ComputeSampler(spike_spec(every_s), seed)
    dt = every_s / calls_per_mean
    intervals = 300 * calls_per_mean  # ~300 arrivals
    draws = [sampler.compute_ms("w", k * dt) for k in range(intervals + 1)]
    assert draws[0] != SPIKE_MS  # an arrival at exactly 0 has probability 0
    spikes = sum(draw == SPIKE_MS for draw in draws)
    p = -math.expm1(-dt / every_s)
    assert abs(spikes - intervals * p) <= SIGMAS * math.sqrt(intervals * p * (1 - p))


@pytest.mark.parametrize(("every_s", "dt"), [(30.0, 6.0), (2.0, 0.1), (10.0, 25.0)])
def test_first_spike_comes_after_the_first_arrival(every_s: float, dt: float) -> None:
    """The first spike is at the first call at or after an Exp(every_s) arrival: a geometric number of calls."""
    spec = spike_spec(every_s)
    samples = 2000
    firsts = []
    for seed in range(samples):
        sampler = ComputeSampler(spec, seed)
        k = 0
        while sampler.compute_ms("w", k * dt) != SPIKE_MS:
            k += 1
        firsts.append(k)
    assert min(firsts) >= 1
    p = -math.expm1(-dt / every_s)  # P(an arrival in one interval); K ~ Geometric(p) on 1, 2, ...
    assert abs(statistics.fmean(firsts) - 1 / p) <= SIGMAS * math.sqrt((1 - p) / p**2 / samples)
    # Spikes are never early: P(K = 1) is p, not more.
    assert abs(firsts.count(1) / samples - p) <= SIGMAS * math.sqrt(p * (1 - p) / samples)


@untimed
@given(gaps=st.lists(st.floats(0, 20), min_size=1, max_size=100), seed=seeds)
def test_a_spike_is_consumed_by_one_run(gaps: list[float], seed: int) -> None:
    """Every arrival up to a run's start goes to that run: a second run at the same time is normal."""
    sampler = ComputeSampler(spike_spec(3.0), seed)
    at = 0.0
    for gap in gaps:
        at += gap
        if sampler.compute_ms("w", at) == SPIKE_MS:
            assert sampler.compute_ms("w", at) != SPIKE_MS


@untimed
@given(seed=seeds, every_s=st.floats(0.5, 20), dt=st.floats(0.05, 2), step=st.integers(2, 10))
def test_spike_arrivals_follow_time_not_calls(seed: int, every_s: float, dt: float, step: int) -> None:
    """A node called less often sees the same arrivals: a coarse call is a spike iff a fine call since the last was."""
    fine, coarse = ComputeSampler(spike_spec(every_s), seed), ComputeSampler(spike_spec(every_s), seed)
    fine_spikes = [fine.compute_ms("w", k * dt) == SPIKE_MS for k in range(100 * step + 1)]
    for j in range(1, 101):
        since_last = fine_spikes[(j - 1) * step + 1 : j * step + 1]
        assert (coarse.compute_ms("w", j * step * dt) == SPIKE_MS) == any(since_last)


# --------------------------------------------------------------------------- (f) the spec


@pytest.mark.parametrize(
    ("work", "field", "fragment"),
    [
        ({"jitter": {"cv": -0.1}}, "workload.jitter.cv", "must be >= 0"),
        ({"jitter": {"cv": 2.5}}, "workload.jitter.cv", "must be <= 2"),
        ({"jitter": {"cv": 0.6, "dist": "uniform"}}, "workload.jitter.cv", "uniform jitter takes cv <= 0.5"),
        ({"jitter": {"cv": 0.31, "dist": "normal"}}, "workload.jitter.cv", "normal jitter takes cv <= 0.3"),
        ({"jitter": {"cv": 0.1, "dist": "cauchy"}}, "workload.jitter.dist", "'cauchy'"),
        ({"jitter": {"dist": "uniform"}}, "workload.jitter", "missing required field 'cv'"),
        ({"growth": {"end": 0, "over_s": 10}}, "workload.growth.end", "must be > 0"),
        ({"growth": {"start": -1, "end": 2, "over_s": 10}}, "workload.growth.start", "must be > 0"),
        ({"growth": {"end": 2, "over_s": 0}}, "workload.growth.over_s", "must be > 0"),
        ({"growth": {"end": 2}}, "workload.growth", "missing required field 'over_s'"),
        ({"spikes": {"every_s": 0, "ms": 5}}, "workload.spikes.every_s", "must be > 0"),
        ({"spikes": {"every_s": 10, "ms": -5}}, "workload.spikes.ms", "must be > 0"),
        ({"jitters": {"cv": 0.1}}, "workload.jitters", "unknown field 'jitters'"),
        ({"growth": {"end": 2, "over_s": 10, "shape": "exp"}}, "workload.growth.shape", "unknown field 'shape'"),
        (0.1, "workload", "expected a mapping"),
    ],
)
def test_a_bad_workload_is_one_line_naming_its_field(work: Any, field: str, fragment: str) -> None:
    with pytest.raises(SpecError) as caught:
        spec_with(work)
    [diagnostic] = caught.value.diagnostics
    assert diagnostic.field == f"nodes.w.{field}"
    assert fragment in diagnostic.message
    assert "\n" not in str(diagnostic)


def test_a_workload_on_an_unscheduled_node_is_an_error() -> None:
    with pytest.raises(SpecError) as caught:
        spec_with(None, other={"scheduled": False, "workload": {"jitter": {"cv": 0.1}}})
    [diagnostic] = caught.value.diagnostics
    assert diagnostic.field == "nodes.o.workload"
    assert "unscheduled" in diagnostic.message


def test_unscheduled_and_unknown_nodes_cannot_be_sampled() -> None:
    sampler = ComputeSampler(spec_with(FULL), 0)
    with pytest.raises(ValueError, match="'sink' is unscheduled"):
        sampler.compute_ms("sink", 0.0)
    with pytest.raises(KeyError, match="no node 'nope'"):
        sampler.compute_ms("nope", 0.0)


def test_the_normalised_spec_keeps_the_workload() -> None:
    """runtime.json carries model_dump(mode="json"); the enforcer reads it back with model_validate."""
    spec = spec_with(FULL, compute=MODAL)
    again = Spec.model_validate(json.loads(json.dumps(spec.model_dump(mode="json", by_alias=True))))
    assert again.nodes["w"].workload == spec.nodes["w"].workload
    assert again.nodes["w"].workload is not None
    assert again.nodes["w"].workload.jitter is not None
    assert again.nodes["w"].workload.jitter.dist == "lognormal"  # the default, written out


def test_planning_ignores_the_workload() -> None:
    without, with_workload = spec_with(None, compute=MODAL), spec_with(FULL, compute=MODAL)
    for cores in (1, 2):
        assert plan(with_workload, cores).objective == plan(without, cores).objective
