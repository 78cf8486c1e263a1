"""The executor-thread model (catanc.core.executor_thread): a case worked by hand, the expected count of
lost triggers against an enumeration of phases, and properties.  The simulator judges the model
on whole plans in tests/explain/test_executors.py."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.core.build import build_problem
from catanc.core.executor_thread import CoreGroup, Member, member_rates, periods_as_run, span_ms, thread_share
from catanc.core.problem import Problem
from tests.support.strategies import spec_of

GL = Member("GL", period_ms=20.0, compute_ms=3.2)
GM = Member("GM", period_ms=724.0, compute_ms=150.0)


def test_nav2ds_pair_worked_by_hand() -> None:
    # At half a core GM's run holds the thread 300 ms: 15 of GL's triggers meet it, 2 are kept, 13 lost
    # per GM run, 1000/724 runs a second.  GL's 6.4 ms span is far below twice GM's period: GM loses none.
    gl, gm = member_rates([GL, GM], share=0.5)
    assert gl.rate_hz == pytest.approx(50.0 - 13.0 * 1000.0 / 724.0)
    assert gl.longest_wait_ms == pytest.approx(300.0)
    assert gl.blocked_by == "GM"
    assert gm.rate_hz == pytest.approx(1000.0 / 724.0)
    assert gm.longest_wait_ms == pytest.approx(6.4)
    assert gm.blocked_by == "GL"


def test_the_thread_gets_what_the_others_leave_at_least_its_slices() -> None:
    assert thread_share(own_share=0.3, others_utilisation=0.4, cores=1) == pytest.approx(0.6)
    assert thread_share(own_share=0.7, others_utilisation=0.4, cores=1) == pytest.approx(0.7)
    assert thread_share(own_share=0.3, others_utilisation=0.4, cores=2) == 1.0  # one thread: one core at most


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
    rate = member_rates([short, other], share=1.0)[0]
    lost_hz = 50.0 - rate.rate_hz
    assert lost_hz == pytest.approx(lost_per_span(span_over_period * period, period), abs=1e-3)


members = st.builds(
    Member,
    node=st.sampled_from(["a"]),
    period_ms=st.floats(1.0, 2000.0),
    compute_ms=st.floats(0.01, 500.0),
)


@given(st.lists(members, min_size=2, max_size=4), st.floats(0.05, 1.0), st.floats(0.05, 1.0))
def test_a_member_loses_more_the_less_share_its_thread_gets(
    found: list[Member], share: float, other_share: float
) -> None:
    named = [Member(f"n{index}", m.period_ms, m.compute_ms) for index, m in enumerate(found)]
    low, high = sorted([share, other_share])
    for at_low, at_high in zip(member_rates(named, low), member_rates(named, high), strict=True):
        assert 0.0 <= at_low.rate_hz <= at_high.rate_hz + 1e-9 <= at_high.planned_hz + 1e-9
        assert at_low.longest_wait_ms >= at_high.longest_wait_ms


@given(st.lists(members, min_size=2, max_size=4), st.floats(0.05, 1.0))
def test_no_trigger_is_lost_while_every_other_span_is_within_two_periods(found: list[Member], share: float) -> None:
    named = [Member(f"n{index}", m.period_ms, m.compute_ms) for index, m in enumerate(found)]
    for member, rate in zip(named, member_rates(named, share), strict=True):
        longest = max(span_ms(other, share) for other in named if other is not member)
        if longest <= 2.0 * member.period_ms:
            assert rate.rate_hz == pytest.approx(rate.planned_hz)
        else:
            assert rate.rate_hz < rate.planned_hz


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5])
def test_a_share_outside_a_core_is_refused(share: float) -> None:
    with pytest.raises(ValueError, match="share of a core"):
        member_rates([GL, GM], share)


def three_on_a_core(*, a_heads: bool) -> Problem:
    """a (1 ms) and b (30 ms) in one executor, o (2 ms) beside them; a heads its subchain or follows x."""
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


def test_periods_as_run_worked_by_hand() -> None:
    problem = three_on_a_core(a_heads=True)
    periods = {"short": 5.0, "long": 100.0, "other": 10.0, "lead": 5.0}
    group = CoreGroup(("short", "long", "other", "lead"), cores=1)
    # The others leave 1 - 2/10 - 0.5/5 = 0.7 of the core: b's run holds the thread 30 / 0.7 ms, which
    # meets 30 / 0.7 / 5 = 8.57 of a's triggers; a loses 6.57 of them per run of b, b runs every 100 ms.
    lost = (30.0 / 0.7 / 5.0 - 2.0) / 100.0
    assert periods_as_run(problem, periods, [group]) == pytest.approx(periods | {"short": 1.0 / (1.0 / 5.0 - lost)})
    # Apart, on cores of their own (not one group), the executor's nodes are not modelled here.
    apart = [CoreGroup(("short",), 1), CoreGroup(("long", "other", "lead"), 1)]
    assert periods_as_run(problem, periods, apart) == periods


def test_a_node_that_does_not_head_its_subchain_keeps_its_period() -> None:
    problem = three_on_a_core(a_heads=False)
    periods = {"short": 5.0, "long": 100.0, "other": 10.0}
    assert periods_as_run(problem, periods, [CoreGroup(("short", "long", "other"), 1)]) == periods
