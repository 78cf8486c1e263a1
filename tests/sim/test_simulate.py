"""The simulator, against cases worked by hand and against the model's analytic bound.

Oracles: processor sharing and preemptive priorities on a few jobs (finish
times by hand); chain windows (by hand); a dedicated subchain whose every
output takes exactly the model's ``R = c + p``; and, over random apps with
constant compute times, the model's worst-case response time ``R``
(docs/explanation/model.md section 2), which no simulated output may exceed.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.control.measure import percentile
from catanc.errors import CatancError, UsageError
from catanc.model.load import load_spec
from catanc.sim.comparison import comparison_payload
from catanc.sim.cpu import Job, Pool
from catanc.sim.engine import Engine
from catanc.sim.metrics import SMALL_SUM, exact_sum, percentile_of, response_arrays, sum_by_exponent
from catanc.sim.simulate import POLICIES, Setup, check_policies, simulate, simulate_policies
from catanc.spec.language import Spec
from tests.support.strategies import spec_documents, spec_of

untimed = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def finish_times(pool: Pool, jobs: list[tuple[float, float, int, int]]) -> dict[int, float]:
    """Submit (arrival ms, work ms, threads, priority) jobs; return each one's finish time by index."""
    engine = Engine([pool])
    done: dict[int, float] = {}
    for index, (arrival, work, threads, priority) in enumerate(jobs):

        def submit(index: int = index, work: float = work, threads: int = threads, priority: int = priority) -> None:
            job = Job(f"n{index}", work, threads, priority, 0, lambda _job: done.__setitem__(index, engine.now))
            engine.submit(pool, job)

        engine.at(arrival, submit)
    engine.run_until(1e6)
    return done


def test_fair_sharing_finishes_equal_jobs_together() -> None:
    # Two 10 ms jobs on one core share it: both finish at 20 ms.
    assert finish_times(Pool("p", (0,), "fair"), [(0, 10, 1, 0), (0, 10, 1, 0)]) == pytest.approx({0: 20, 1: 20})
    # Three on two cores: each runs at 2/3 speed: 15 ms.
    three = finish_times(Pool("p", (0, 1), "fair"), [(0, 10, 1, 0)] * 3)
    assert three == pytest.approx({0: 15, 1: 15, 2: 15})
    # A 4 ms job arriving at 2 ms beside a 10 ms one: from 2 ms both run at half speed; the short one
    # needs 8 ms more (done at 10), the long one has 10 - 2 - 4 = 4 ms left alone (done at 14).
    assert finish_times(Pool("p", (0,), "fair"), [(0, 10, 1, 0), (2, 4, 1, 0)]) == pytest.approx({0: 14, 1: 10})


def test_fifo_runs_the_higher_priority_first_and_first_come_first_within_one() -> None:
    # The priority-2 job arriving at 2 ms preempts: done at 7; the low one resumes: 10 + 5 = 15.
    assert finish_times(Pool("p", (0,), "fifo"), [(0, 10, 1, 1), (2, 5, 1, 2)]) == pytest.approx({0: 15, 1: 7})
    # Same priority: no preemption, the later one waits.
    assert finish_times(Pool("p", (0,), "fifo"), [(0, 10, 1, 1), (2, 5, 1, 1)]) == pytest.approx({0: 10, 1: 15})


def test_a_job_on_more_threads_than_cores_runs_at_the_share_it_gets() -> None:
    # 2 threads, 10 ms of wall time on 2 cores; alone on 1 core it takes twice as long.
    assert finish_times(Pool("p", (0,), "fifo"), [(0, 10, 2, 1)]) == pytest.approx({0: 20})
    assert finish_times(Pool("p", (0, 1), "fifo"), [(0, 10, 2, 1)]) == pytest.approx({0: 10})


jobs_and_ticks = st.tuples(
    st.lists(
        st.tuples(st.integers(0, 40), st.integers(1, 30), st.integers(1, 3), st.integers(0, 2)), min_size=1, max_size=12
    ),
    st.lists(st.integers(0, 200), max_size=20),
    st.sampled_from(["fifo", "fair"]),
    st.integers(1, 3),
)


@given(jobs_and_ticks)
def test_every_job_finishes_once_and_the_cores_do_exactly_its_work(case: Any) -> None:
    """Conservation: whatever the coincidences of arrivals, completions and other events (times in
    whole tenths of a ms, so they coincide often), each job completes exactly once, and the pool's
    busy core time is the work submitted (work x threads)."""
    jobs, ticks, discipline, cores = case
    pool = Pool("p", tuple(range(cores)), discipline)
    engine = Engine([pool])
    finished: list[int] = []
    for index, (arrival, work, threads, priority) in enumerate(jobs):

        def submit(index: int = index, work: int = work, threads: int = threads, priority: int = priority) -> None:
            job = Job(f"n{index}", work / 10, threads, priority, 0, lambda _job: finished.append(index))
            engine.submit(pool, job)

        engine.at(arrival / 10, submit)
    for tick in ticks:  # other events (slot switches, say) that change nothing
        engine.at(tick / 10, lambda: engine.changed(pool))
    engine.run_until(10_000.0)
    assert sorted(finished) == list(range(len(jobs)))
    assert pool.busy_core_ms == pytest.approx(sum(work / 10 * threads for _, work, threads, _ in jobs))
    assert not pool.jobs


def test_response_arrays_hand_worked() -> None:
    # Origins 0, 10, 10 (a repeat), 30; each new one measured from the origin before it.
    arrivals = [(0.0, 5.0), (10.0, 16.0), (10.0, 18.0), (30.0, 37.0)]
    done, response = response_arrays(arrivals)
    assert (done.tolist(), response.tolist()) == ([16.0, 37.0], [16.0, 27.0])
    assert response_arrays([])[1].tolist() == []
    assert response_arrays([(0.0, 1.0)])[1].tolist() == []


@given(
    st.lists(st.floats(0.0, 1e4, allow_nan=False) | st.sampled_from([0.0, 1.0, 2.5]), min_size=1, max_size=300),
    st.floats(0.0, 100.0) | st.sampled_from([0.0, 50.0, 95.0, 100.0]),
)
def test_percentile_of_an_array_is_the_sorting_percentile_to_the_last_bit(values: list[float], q: float) -> None:
    assert percentile_of(np.array(values), q) == percentile(values, q)


def _fsum_or_none(values: list[float]) -> float | None:
    try:
        return math.fsum(values)
    except OverflowError:  # an intermediate sum beyond the largest float: fsum gives up
        return None


@given(
    st.lists(
        st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True)
        | st.floats(-1e4, 1e4)
        | st.sampled_from([0.0, -0.0, 5e-324, 1.0, 0.1, 1e16, -1e16, 2.0**-1074 * 3]),
        max_size=200,
    ),
    st.integers(0, 3),
)
@settings(max_examples=400)
def test_the_sum_by_exponent_is_fsum_to_the_last_bit(values: list[float], repeats: int) -> None:
    """Against Python's correctly rounded sum, on any finite values, with cancellations and repeats."""
    values = values * (1 + repeats)
    expected = _fsum_or_none(values)
    if expected is not None:
        assert sum_by_exponent(np.array(values, np.float64)) == expected


def test_the_sum_by_exponent_hand_worked_cases() -> None:
    assert sum_by_exponent(np.array([0.1] * 10)) == 1.0  # plain addition: 0.9999999999999999
    assert sum_by_exponent(np.array([1e100, 1.0, -1e100])) == 1.0
    assert sum_by_exponent(np.array([2.0**53, 1.0, 1.0])) == 2.0**53 + 2  # a tie at the first 1.0, exact at the end
    assert sum_by_exponent(np.array([5e-324] * 3)) == 1.5e-323  # subnormal
    assert sum_by_exponent(np.array([])) == 0.0
    with pytest.raises(ValueError, match="inf"):  # as math.fsum
        sum_by_exponent(np.array([1.0, math.inf, -math.inf]))
    assert sum_by_exponent(np.array([1.0, math.inf])) == math.inf


@given(st.integers(0, 2**32), st.floats(1e-3, 1e3), st.integers(0, 3 * SMALL_SUM))
@settings(max_examples=40)
def test_exact_sum_of_response_times_is_fsum(seed: int, scale: float, extra: int) -> None:
    """Both ways :func:`exact_sum` goes (fsum itself below :data:`SMALL_SUM` values), on response-time-like values."""
    values = np.random.default_rng(seed).exponential(scale, SMALL_SUM - 2 + extra)
    assert exact_sum(values) == math.fsum(values.tolist())


ONE_SUBCHAIN = {
    "catan": 1,
    "app": "one",
    "nodes": {"cam": {"compute_ms": 4}, "det": {"compute_ms": 6}, "out": {"scheduled": False}},
    "edges": [["cam", "det"], ["det", "out"]],
    "subchains": {"main": ["cam", "det"]},
    "objective": [{"chain": ["cam", "det", "out"], "weight": 1.0}],
    "constraints": [{"node": "cam", "max_rate_hz": 50}],
}


def constant(spec: Spec, _seed: int) -> Any:
    return lambda node, _at_s: spec.nodes[node].mean_compute_ms


def test_a_dedicated_subchain_meets_the_model_exactly() -> None:
    """One core, c = 10 ms, capped at 50 Hz: triggered every 20 ms, each output 10 ms later: R = 10 + 20."""
    spec = spec_of(ONE_SUBCHAIN)
    result = simulate(Setup(spec, 1, 2.0, 0), "catan", constant)
    chain = result.chains[0]
    assert chain.nodes == ("cam", "det", "out")
    assert chain.model_ms == pytest.approx(30.0)
    assert chain.response is not None
    assert chain.response.max == pytest.approx(30.0)
    assert chain.response.mean == pytest.approx(30.0)
    assert result.nodes["cam"].rate_hz == pytest.approx(50.0, abs=0.5)
    assert result.utilisation[0] == pytest.approx(0.5, abs=0.01)


def test_the_baseline_shares_the_core_and_runs_at_the_hand_tuned_rates() -> None:
    """cam on a 25 Hz timer, det on cam's output: 10 ms per 40 ms; det's output 10 ms after cam started."""
    document = {**ONE_SUBCHAIN, "baseline": {"rates_hz": {"cam": 25}}}
    result = simulate(Setup(spec_of(document), 1, 2.0, 0), "baseline", constant)
    assert result.nodes["cam"].rate_hz == pytest.approx(25.0, abs=0.5)
    assert result.nodes["det"].rate_hz == pytest.approx(25.0, abs=0.5)
    response = result.chains[0].response
    assert response is not None
    assert response.max == pytest.approx(40.0 + 10.0)  # the window is the timer's period, then the run
    assert result.utilisation[0] == pytest.approx(0.25, abs=0.01)


def test_a_baseline_without_rates_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match=r"baseline\.rates_hz"):
        simulate(Setup(spec_of(ONE_SUBCHAIN), 1, 1.0, 0), "baseline", constant)


def test_unknown_policies_are_named() -> None:
    with pytest.raises(UsageError, match="'fastest'"):
        check_policies(["catan", "fastest"])
    assert check_policies(["catan", "catan", "baseline"]) == ("catan", "baseline")


@pytest.mark.slow
@untimed
@given(spec_documents(max_subchains=5), st.integers(1, 3))
def test_no_simulated_output_is_later_than_the_models_bound(document: dict[str, Any], cores: int) -> None:
    """With constant compute times, every named chain's worst simulated response is at most the model's R.

    The model's R (section 2) is a worst case: each later stage may wait a whole period for its
    input. The simulator enforces the plan (slots, slack, switches, stealing), so an output later
    than R would mean the enforcement or the model is wrong.
    """
    spec = spec_of(document)
    try:
        first = simulate(Setup(spec, cores, 0.5, 0), "static-fullrun", constant)
    except CatancError:  # an infeasible random app: the planner's own tests cover those
        return
    longest = max((chain.model_ms or 0.0) for chain in first.chains)
    duration_s = min(max(20 * longest / 1000.0, 1.0), 20.0)
    result = simulate(Setup(spec, cores, duration_s, 0), "static-fullrun", constant)
    for chain in result.chains:
        if chain.named and chain.model_ms is not None and chain.response is not None:
            assert chain.response.max <= chain.model_ms * (1 + 1e-9) + 1e-6, chain


@pytest.fixture(scope="module")
def nav2d() -> Spec:
    return load_spec("specs/nav2d.yaml")


def test_the_same_seed_gives_the_same_bytes_and_another_seed_other_draws(nav2d: Spec) -> None:
    setup = Setup(nav2d, 1, 6.0, 7)
    one = json.dumps(comparison_payload(simulate_policies(setup, POLICIES)), sort_keys=True)
    two = json.dumps(comparison_payload(simulate_policies(setup, POLICIES)), sort_keys=True)
    assert one == two
    other = json.dumps(comparison_payload(simulate_policies(Setup(nav2d, 1, 6.0, 8), POLICIES)), sort_keys=True)
    assert other != one  # the workload's draws differ (GL's modes at least)


def test_catan_beats_the_hand_tuned_default_on_the_local_chain(nav2d: Spec) -> None:
    """The paper's section 7.2 claim, on 1 core: the local chain reacts far faster under catanc's plan."""
    results = {r.policy: r for r in simulate_policies(Setup(nav2d, 1, 10.0, 0), ["catan", "baseline"])}
    local = ("scan", "LM", "LP", "base")
    catan = next(c for c in results["catan"].chains if c.nodes == local).response
    baseline = next(c for c in results["baseline"].chains if c.nodes == local).response
    assert catan is not None
    assert baseline is not None
    assert catan.p95 * 5 < baseline.p95
    assert results["catan"].replans >= 1
