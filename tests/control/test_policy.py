"""The runtime policy (catanc.control.policy), worked by hand: a core's boundaries, who owns a slot,
which boundaries need the enforcer awake, and the re-solve cadence."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given
from hypothesis import strategies as st

from catanc.control.policy import (
    Cadence,
    CoreCursor,
    Switch,
    boundary_ms,
    hand_over,
    late_on,
    lost_after_ms,
    needs_wake,
    next_clock_ms,
    replanned,
    slot_rules,
    switch_at,
)
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun, slot_owner, triggers_at_slot
from catanc.spec.language import Runtime


def run(name: str, *, runs: int | None = 1, priority: int = 1, latency_ms: float = 10.0) -> SubchainRun:
    return SubchainRun(name, (name,), (0,), True, 10.0, latency_ms, runs, priority)


# T = 10 ms: a (2 ms) then b (3 ms), each after a 0.5 ms switch; slack from 6 ms on.
CORE = CoreSchedule(0, 10.0, 0.5, (Slot("a", 0.5, 2.0), Slot("b", 3.0, 3.0)))
RUNS = {"a": run("a", runs=1, priority=2), "b": run("b", runs=3, priority=1)}


def test_a_periods_boundaries_are_each_switch_then_the_end_of_the_last_slice() -> None:
    assert [boundary_ms(CORE, 100.0, position) for position in range(3)] == [100.0, 102.5, 106.0]


def test_a_cursor_walks_the_period_and_takes_a_new_schedule_at_the_next_one() -> None:
    cursor = CoreCursor(CORE, 0.0)
    seen = []
    for _ in range(2):
        seen.append((cursor.index, cursor.position, cursor.due_ms()))
        cursor.advance(None, cursor.due_ms())
    seen.append((cursor.index, cursor.position, cursor.due_ms()))
    assert seen == [(0, 0, 0.0), (0, 1, 2.5), (0, 2, 6.0)]
    assert cursor.at_end
    longer = CoreSchedule(0, 20.0, 0.5, (Slot("a", 0.5, 2.0), Slot("b", 3.0, 3.0)))
    cursor.advance(longer, 6.0)  # the end of period 0: period 1 starts at 10 ms, with the new schedule
    assert (cursor.index, cursor.position, cursor.start_ms, cursor.schedule) == (1, 0, 10.0, longer)
    assert cursor.next_period_ms() == 30.0


def test_a_cursor_periods_behind_counts_the_periods_it_slept_through() -> None:
    cursor = CoreCursor(CORE, 0.0, position=2)
    cursor.advance(None, 25.0)  # period 1 was due at 10 ms; at 25 ms period 2 (from 20 ms) is the current one
    assert (cursor.index, cursor.start_ms, cursor.due_ms()) == (2, 20.0, 20.0)
    cursor = CoreCursor(CORE, 0.0, position=2)
    cursor.advance(None, 19.0)  # 9 ms late: period 1 keeps its place
    assert (cursor.index, cursor.start_ms) == (1, 10.0)
    cursor = CoreCursor(CORE, 0.0, position=2)
    cursor.advance(None, 30.0)  # exactly at period 3's start
    assert (cursor.index, cursor.start_ms) == (3, 30.0)


def test_an_idle_core_woken_at_its_next_trigger_triggers_every_runs_periods() -> None:
    # b (runs = 3) alone on an idle core: the enforcer sleeps from each trigger to the next, 30 ms on.
    alone = CoreSchedule(0, 10.0, 0.5, (Slot("b", 0.5, 3.0),))
    rules = slot_rules(alone, RUNS)
    cursor = CoreCursor(alone, 0.0)
    fired = []
    wake = 0.0
    for _ in range(4):
        while cursor.due_ms() <= wake:  # what the enforcer does on waking: every boundary due by now
            rule = rules[cursor.position]
            if rule.subchain is not None and needs_wake(rule, cursor.index, active=False):
                fired.append(cursor.due_ms())
            cursor.advance(None, wake)
        wake += 30.0
    assert fired == [0.0, 30.0, 60.0, 90.0]


def test_a_slot_goes_to_its_subchain_and_triggers_it_every_runs_periods() -> None:
    assert switch_at(CORE, 0, 0, RUNS, set()) == Switch("a", "a")
    assert [switch_at(CORE, 1, index, RUNS, set()).trigger for index in range(6)] == ["b", None, None, "b", None, None]
    assert switch_at(CORE, 2, 0, RUNS, {"a"}) == Switch(None)  # the end lowers everything


def test_a_late_subchain_of_higher_priority_steals_the_slot_but_not_the_other_way() -> None:
    assert switch_at(CORE, 1, 1, RUNS, {"a"}) == Switch("a", None, stolen=True)
    assert switch_at(CORE, 1, 0, RUNS, {"a"}) == Switch("a", "b", stolen=True)  # b's head is still triggered
    assert switch_at(CORE, 0, 1, RUNS, {"b"}) == Switch("a", "a")  # b ranks below a


def test_without_stealing_every_slot_is_its_owners_and_heads_are_still_triggered() -> None:
    without = CoreSchedule(0, 10.0, 0.5, CORE.slots, stealing=False)
    assert [rule.thieves for rule in slot_rules(without, RUNS)] == [(), (), ()]
    assert switch_at(without, 1, 0, RUNS, {"a"}) == Switch("b", "b")  # a is late: with stealing it took b's slot
    assert switch_at(without, 1, 1, RUNS, {"a"}) == Switch("b", None)


def test_late_is_past_the_planned_latency_since_the_oldest_trigger() -> None:
    oldest = {"a": 0.0, "b": None}
    assert late_on(CORE, RUNS, oldest.get, 10.0) == set()  # exactly the latency: not yet
    assert late_on(CORE, RUNS, oldest.get, 10.5) == {"a"}


def test_an_idle_core_needs_the_enforcer_only_where_a_head_is_triggered() -> None:
    rules = slot_rules(CORE, RUNS)
    needed = [
        (index, position)
        for index in range(3)
        for position, rule in enumerate(rules)
        if needs_wake(rule, index, active=False)
    ]
    assert needed == [(0, 0), (0, 1), (1, 0), (2, 0)]
    assert all(needs_wake(rule, 1, active=True) for rule in rules)


def test_a_clock_fires_a_period_on_or_now_when_behind() -> None:
    assert next_clock_ms(10.0, 5.0, 11.0) == 15.0
    assert next_clock_ms(10.0, 5.0, 17.0) == 17.0


def test_a_run_is_lost_after_20_latencies_and_at_least_a_second() -> None:
    assert lost_after_ms(run("a", latency_ms=10.0)) == 1000.0
    assert lost_after_ms(run("a", latency_ms=100.0)) == 2000.0
    assert lost_after_ms(None) == 20000.0


def test_the_cadence_re_solves_stage2_every_5_s_and_both_every_20_s_after_2_s() -> None:
    cadence = Cadence.start(Runtime())
    times = []
    now = 0.0
    while now < 50_000.0:
        now = cadence.next_ms()
        stage = cadence.due(now)
        assert stage is not None
        cadence.solved(stage, now)
        times.append((now / 1000.0, stage))
    assert times[:7] == [
        (2.0, "stage2"),
        (7.0, "stage2"),
        (12.0, "stage2"),
        (17.0, "stage2"),
        (22.0, "stage1"),  # 2 + 20
        (27.0, "stage2"),
        (32.0, "stage2"),
    ]
    assert cadence.due(now + 1.0) is None


def test_a_core_change_restarts_the_stage1_cadence_only() -> None:
    cadence = Cadence.start(Runtime())
    cadence.cores_changed(1000.0)
    assert (cadence.next_stage1_ms, cadence.next_stage2_ms) == (21000.0, 2000.0)
    assert cadence.due(1500.0) is None
    assert cadence.due(2000.0) == "stage2"


@given(
    st.lists(st.tuples(st.integers(0, 3), st.sampled_from([None, 1, 2, 3])), min_size=1, max_size=5),
    st.sets(st.integers(0, 4)),
    st.integers(0, 12),
)
def test_slot_rules_decide_as_slot_owner_and_triggers_at_slot(
    shape: list[tuple[int, int | None]], late_indices: set[int], period_index: int
) -> None:
    """Against the schedule's own rules (slot_owner, triggers_at_slot), for any priorities, lateness and period."""
    names = [f"s{i}" for i in range(len(shape))]
    runs = {name: run(name, runs=every, priority=rank) for name, (rank, every) in zip(names, shape, strict=True)}
    core = CoreSchedule(0, 10.0, 0.1, tuple(Slot(name, 0.1 + i, 0.5) for i, name in enumerate(names)))
    late = {names[i] for i in late_indices if i < len(names)}
    for position, slot in enumerate(core.slots):
        decision = switch_at(core, position, period_index, runs, late)
        assert decision.owner == slot_owner(slot, core, runs, late)
        assert (decision.trigger is not None) == triggers_at_slot(runs[slot.subchain], period_index)
        assert decision.stolen == (decision.owner != slot.subchain)
    assert switch_at(core, len(core.slots), period_index, runs, late) == Switch(None)


def schedule_of(*runs: SubchainRun) -> RuntimeSchedule:
    return RuntimeSchedule(2, {run.name: run for run in runs}, (CORE,))


def test_a_new_allocation_or_other_clocks_reinstall_and_anything_else_updates() -> None:
    before = schedule_of(run("a"), run("b", runs=3))
    assert replanned(before, before) == (False, False)
    faster = schedule_of(run("a", priority=5, latency_ms=3.0), run("b", runs=1))  # slots and rates: an update
    assert replanned(before, faster) == (False, False)
    moved = schedule_of(run("a"), replace(run("b", runs=3), cores=(1,)))
    assert replanned(before, moved) == (True, True)
    dedicated = schedule_of(run("a"), replace(run("b", runs=None), shared=False))
    assert replanned(before, dedicated) == (True, True)
    on_its_clock = schedule_of(run("a"), run("b", runs=None))  # same cores, now on its own clock
    assert replanned(before, on_its_clock) == (False, True)


def test_a_new_owner_lowers_the_previous_one_and_the_same_owner_changes_nothing() -> None:
    raised: dict[int, str | None] = {}
    assert hand_over(raised, 0, "a") == (True, None)  # nothing was raised on core 0
    assert hand_over(raised, 0, "a") == (False, None)
    assert hand_over(raised, 1, "b") == (True, None)  # cores are apart
    assert hand_over(raised, 0, "b") == (True, "a")
    assert hand_over(raised, 0, None) == (True, "b")  # the end of the last slice
    assert hand_over(raised, 0, None) == (False, None)
    assert raised == {0: None, 1: "b"}
