"""The executor-thread model (catanc.model.executor_thread): cases worked by hand, the expected count of lost
triggers against an enumeration of phases, and properties.  The simulator judges the model on whole plans in
tests/explain/test_executors.py."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.executor_thread import CoreGroup, Member, held_ms, member_rates, periods_as_run, thread_share
from catanc.model.metrics import Timing
from catanc.model.problem import Problem
from tests.support.strategies import spec_of

GL = Member("GL", period_ms=20.0, compute_ms=3.2, latency_ms=20.0, share=0.5)
GM = Member("GM", period_ms=724.0, compute_ms=150.0, latency_ms=724.0, share=0.5)


def test_nav2ds_pair_worked_by_hand() -> None:
    # At half a core GM's run holds the thread 300 ms: 15 of GL's triggers meet it, 2 are kept, 13 lost
    # per GM run, 1000/724 runs a second.  GL's 6.4 ms hold is far below twice GM's period: GM loses none.
    gl, gm = member_rates([GL, GM])
    assert gl.rate_hz == pytest.approx(50.0 - 13.0 * 1000.0 / 724.0)
    assert gl.longest_wait_ms == pytest.approx(300.0)
    assert gl.blocked_by == "GM"
    assert gm.rate_hz == pytest.approx(1000.0 / 724.0)
    assert gm.longest_wait_ms == pytest.approx(6.4)


def test_a_late_waiter_steals_and_shortens_the_hold() -> None:
    # GL's waiting run is late 10 + 20 ms into the hold (half its period, then its latency); until then the
    # thread has half a core (15 ms of GM's compute done), then 0.8: the other 135 ms take 168.75 ms.
    stealer = Member("GL", 20.0, 3.2, latency_ms=20.0, share=0.5, stealing_share=0.8)
    assert held_ms(GM, stealer) == pytest.approx(30.0 + 135.0 / 0.8)
    gl, _ = member_rates([stealer, GM])
    assert gl.rate_hz == pytest.approx(50.0 - (198.75 / 20.0 - 2.0) * 1000.0 / 724.0)


def test_the_thread_gets_what_the_others_leave_of_one_core() -> None:
    assert thread_share(others_utilisation=0.4, cores=1) == pytest.approx(0.6)
    assert thread_share(others_utilisation=0.4, cores=2) == 1.0  # one thread: one core at most
    # With slack, of what the app gets of each core: 0.95 - 0.4, and 0.95 of one core of two.
    assert thread_share(others_utilisation=0.4, cores=1, slack=0.05) == pytest.approx(0.55)
    assert thread_share(others_utilisation=0.4, cores=2, slack=0.05) == pytest.approx(0.95)


def lost_per_span(span: float, period: float, phases: int = 20_000) -> float:
    """Triggers every ``period`` at a uniform phase meet a busy thread for ``span``: the first waits, one more
    is held, the rest are lost.  The mean over evenly spaced phases, counted trigger by trigger."""
    total = 0
    for index in range(phases):
        first = (index + 0.5) / phases * period  # the first trigger after the span starts
        met = math.ceil((span - first) / period) if span > first else 0
        total += max(0, met - 2)
    return total / phases


@pytest.mark.parametrize("span_over_period", [0.4, 1.0, 1.7, 2.0, 2.5, 3.25, 7.9, 13.0])
def test_the_expected_loss_matches_an_enumeration_of_phases(span_over_period: float) -> None:
    period = 20.0
    other = Member("long", period_ms=1000.0, compute_ms=span_over_period * period)
    short = Member("short", period_ms=period, compute_ms=0.1)
    rate = member_rates([short, other])[0]
    lost_hz = 50.0 - rate.rate_hz
    assert lost_hz == pytest.approx(lost_per_span(span_over_period * period, period), abs=1e-3)


members = st.tuples(st.floats(1.0, 2000.0), st.floats(0.01, 500.0), st.floats(0.0, 100.0))


def named(found: list[tuple[float, float, float]], share: float, stealing: float | None) -> list[Member]:
    return [
        Member(f"n{index}", period, compute, latency, share, stealing)
        for index, (period, compute, latency) in enumerate(found)
    ]


@given(st.lists(members, min_size=2, max_size=4), st.floats(0.05, 1.0), st.floats(0.05, 1.0))
def test_a_member_loses_more_the_less_its_thread_gets(
    found: list[tuple[float, float, float]], a: float, b: float
) -> None:
    low, high = sorted([a, b])
    for stealing in (None, 1.0):
        at_low, at_high = member_rates(named(found, low, stealing)), member_rates(named(found, high, stealing))
        for slow, fast in zip(at_low, at_high, strict=True):
            assert 0.0 <= slow.rate_hz <= fast.rate_hz + 1e-9 <= fast.planned_hz + 1e-9
            assert slow.longest_wait_ms >= fast.longest_wait_ms - 1e-9


@given(st.lists(members, min_size=2, max_size=4), st.floats(0.05, 1.0))
def test_stealing_never_costs_the_waiter(found: list[tuple[float, float, float]], share: float) -> None:
    for plain, stealing in zip(
        member_rates(named(found, share, None)), member_rates(named(found, share, 1.0)), strict=True
    ):
        assert stealing.rate_hz >= plain.rate_hz - 1e-9


@given(st.lists(members, min_size=2, max_size=4), st.floats(0.05, 1.0))
def test_no_trigger_is_lost_while_every_hold_is_within_two_periods(
    found: list[tuple[float, float, float]], share: float
) -> None:
    group = named(found, share, None)
    for member, rate in zip(group, member_rates(group), strict=True):
        longest = max(held_ms(other, member) for other in group if other is not member)
        if longest <= 2.0 * member.period_ms:
            assert rate.rate_hz == pytest.approx(rate.planned_hz)
        else:
            assert rate.rate_hz < rate.planned_hz


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5])
def test_a_share_outside_a_core_is_refused(share: float) -> None:
    with pytest.raises(ValueError, match="share of a core"):
        member_rates([Member("a", 10.0, 1.0, share=share), GM])


def three_on_a_core(*, a_heads: bool) -> Problem:
    """a (1 ms) and b (30 ms) in one executor, o (2 ms) and x (0.5 ms) beside them."""
    return build_problem(
        spec_of(
            {
                "catan": 1,
                "app": "three",
                "nodes": {name: {"compute_ms": ms} for name, ms in (("x", 0.5), ("a", 1.0), ("b", 30.0), ("o", 2.0))},
                "edges": [["x", "a"]],
                "subchains": {"short": ["a"] if a_heads else ["x", "a"], "long": ["b"], "other": ["o"]}
                | ({"lead": ["x"]} if a_heads else {}),
                "objective": [{"node": "a", "weight": 1.0}],
                "executors": {"worker": ["a", "b"]},
            }
        )
    )


TIMINGS = {
    "short": Timing(5.0, 5.0),
    "long": Timing(100.0, 100.0),
    "other": Timing(10.0, 10.0),
    "lead": Timing(5.0, 5.0),
}
PRIORITIES = {"lead": 4, "short": 3, "other": 2, "long": 1}


def test_periods_as_run_worked_by_hand() -> None:
    problem = three_on_a_core(a_heads=True)
    periods = {name: timing.period_ms for name, timing in TIMINGS.items()}
    group = CoreGroup(tuple(TIMINGS), 1, PRIORITIES, stealing=False)
    # The others leave 1 - 2/10 - 0.5/5 = 0.7 of the core: b's run holds the thread 30 / 0.7 ms, which
    # meets 8.57 of a's triggers; a loses 6.57 of them per run of b, b runs every 100 ms.
    lost = (30.0 / 0.7 / 5.0 - 2.0) / 100.0
    assert periods_as_run(problem, TIMINGS, [group]) == pytest.approx(periods | {"short": 1.0 / (0.2 - lost)})
    # With stealing a's run is late 2.5 + 5 ms into the hold (5.25 ms of b's compute done at 0.7); it then
    # takes o's slots (it outranks o, not x): 0.9 of the core for the other 24.75 ms, which take 27.5 ms.
    # a loses 35 / 5 - 2 per run of b; o, triggered every 10 ms, 27.5 / 10 - 2 of its triggers.
    stealing = CoreGroup(tuple(TIMINGS), 1, PRIORITIES, stealing=True)
    expected = periods | {"short": 1.0 / (0.2 - (35.0 / 5.0 - 2.0) / 100.0), "other": 1.0 / (0.1 - 0.75 / 100.0)}
    assert periods_as_run(problem, TIMINGS, [stealing]) == pytest.approx(expected)
    # Apart, on cores of their own (not one group), the executor's nodes are not modelled here.
    apart = [CoreGroup(("short",), 1, PRIORITIES), CoreGroup(("long", "other", "lead"), 1, PRIORITIES)]
    assert periods_as_run(problem, TIMINGS, apart) == periods


def test_a_node_that_does_not_head_its_subchain_keeps_its_period() -> None:
    problem = three_on_a_core(a_heads=False)
    timings = {name: TIMINGS[name] for name in ("short", "long", "other")}
    group = CoreGroup(tuple(timings), 1, PRIORITIES, stealing=False)
    assert periods_as_run(problem, timings, [group]) == {name: timing.period_ms for name, timing in timings.items()}


def test_two_executors_taking_from_one_subchain_add_up_their_losses() -> None:
    # One core: lead (x), short (a), other (o), long (b), zed (z), ranked in that order; a and b share one
    # thread, o and z another, and no slack.  Worker's thread (a, b) gets 1 - 0.1 - 0.2 - 0.2 = 0.5 of the
    # core; a's waiting run is late 2.5 + 5 ms into b's hold (3.75 ms of b's 30 done), then has 1 - 0.1:
    # the hold is 7.5 + 26.25 / 0.9 ms, a loses hold / 5 - 2 per run of b (10 a second), and a steals o's
    # slots for 26.25 / 0.9 ms of it: o, every 10 ms, loses that / 10 - 2 per run of b.
    # Pair's thread (o, z) gets 1 - 0.1 - 0.2 - 0.3 = 0.4; o's run is late 5 + 10 ms into z's hold (6 ms of
    # z's 40 done), then has 1 - 0.1 - 0.2: the hold is 15 + 34 / 0.7 ms, o loses hold / 10 - 2 per run of z
    # (5 a second); o steals from b, every 100 ms, too briefly to cost it a trigger.
    # o loses to both threads: its losses add up.
    problem = build_problem(
        spec_of(
            {
                "catan": 1,
                "app": "two_threads",
                "nodes": {
                    name: {"compute_ms": ms}
                    for name, ms in (("x", 0.5), ("a", 1.0), ("o", 2.0), ("b", 30.0), ("z", 40.0))
                },
                "subchains": {"lead": ["x"], "short": ["a"], "other": ["o"], "long": ["b"], "zed": ["z"]},
                "objective": [{"node": "a", "weight": 1.0}],
                "executors": {"worker": ["a", "b"], "pair": ["o", "z"]},
            }
        )
    )
    timings = TIMINGS | {"zed": Timing(200.0, 200.0)}
    group = CoreGroup(tuple(timings), 1, PRIORITIES | {"zed": 0}, stealing=True)
    worker_hold = 7.5 + 26.25 / 0.9
    a_lost_hz = (worker_hold / 5.0 - 2.0) * 10.0
    o_stolen_hz = ((worker_hold - 7.5) / 10.0 - 2.0) * 10.0
    o_lost_hz = ((15.0 + 34.0 / 0.7) / 10.0 - 2.0) * 5.0
    expected = {name: timing.period_ms for name, timing in timings.items()} | {
        "short": 1000.0 / (200.0 - a_lost_hz),
        "other": 1000.0 / (100.0 - o_stolen_hz - o_lost_hz),
    }
    assert periods_as_run(problem, timings, [group]) == pytest.approx(expected)
