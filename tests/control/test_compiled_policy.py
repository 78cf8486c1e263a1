"""The compiled slot rule (catanc.control.compiled_policy) against its statement, catanc.control.policy.

Random cores (slots of random subchains, priorities, trigger cycles, stealing on or off) laid out
by catanc.control.slot_table, walked period after period with random lateness at each boundary:
the compiled decision must be the Python one, boundary by boundary, and so must the hand-over of
the core from one owner to the next.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.control import compiled_policy as cp
from catanc.control.policy import CoreCursor, boundary_ms, decide, hand_over, needs_wake, slot_rules
from catanc.control.schedule import CoreSchedule, Slot, SubchainRun
from catanc.control.slot_table import ACTIONS, HANDOVER, LOWER, NONE, RAISE, STEAL, TRIGGER, empty_rules, lay_out_rules

NAMES = ("a", "b", "c", "d", "e")
untimed = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=150)


@st.composite
def cores(draw: st.DrawFn) -> tuple[CoreSchedule, dict[str, SubchainRun]]:
    """A shared core's schedule: 1-5 slots (a subchain may have several), each subchain's priority and cycle."""
    names = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=5, unique=True))
    order = draw(st.lists(st.sampled_from(names), min_size=1, max_size=6))  # slots, in period order
    runs = {
        name: SubchainRun(
            name,
            (name,),
            (0,),
            True,
            10.0,
            5.0,
            draw(st.one_of(st.none(), st.integers(1, 4))),  # None: on its own clock, never triggered at a slot
            draw(st.integers(0, 3)),  # ties are broken by name
        )
        for name in names
    }
    switch = draw(st.sampled_from([0.0, 0.25]))
    slots, start = [], switch
    for name in order:
        length = draw(st.sampled_from([0.5, 1.0, 2.5]))
        slots.append(Slot(name, start, length))
        start += length + switch
    return CoreSchedule(0, start + 1.0, switch, tuple(slots), draw(st.booleans())), runs


@untimed
@given(cores(), st.data())
def test_the_compiled_decision_is_the_policys_boundary_by_boundary(
    core_and_runs: tuple[CoreSchedule, dict[str, SubchainRun]], data: st.DataObject
) -> None:
    core, runs = core_and_runs
    index = {name: s for s, name in enumerate(NAMES)}
    arrays = empty_rules(2, 3, len(core.slots))
    rules = slot_rules(core, runs)
    lay_out_rules(arrays, 1, 2, rules, index)  # version 1 of core 2: the others stay empty
    late_flags = np.zeros(len(NAMES), dtype=np.int64)
    raised_compiled = np.full(4, NONE, dtype=np.int64)
    raised_python: dict[int, str | None] = {}
    actions = np.full(ACTIONS, NONE, dtype=np.int64)
    cursor = CoreCursor(core, 0.0)
    for _ in range(3 * len(rules)):
        late = set(data.draw(st.sets(st.sampled_from(sorted(runs)))))
        late_flags[:] = [int(name in late) for name in NAMES]
        rule = rules[cursor.position]
        expected = decide(rule, cursor.index, late.__contains__)
        cp.decide(*arrays, 1, 2, cursor.position, cursor.index, late_flags, raised_compiled, 3, actions)

        def name(s: int) -> str | None:
            return None if s == NONE else NAMES[s]

        assert name(actions[RAISE]) == expected.owner
        assert name(actions[TRIGGER]) == expected.trigger
        assert bool(actions[STEAL]) == expected.stolen
        handover = hand_over(raised_python, 3, expected.owner)
        assert bool(actions[HANDOVER]) == handover.changed
        assert name(actions[LOWER]) == handover.lowered
        assert name(raised_compiled[3]) == raised_python[3]
        assert cp.triggers(arrays[1], 1, 2, cursor.position, cursor.index) == needs_wake(
            rule, cursor.index, active=False
        )
        assert cp.thieves(arrays[2], 1, 2, cursor.position) == len(rule.thieves)
        cursor.advance(None, cursor.due_ms())


@untimed
@given(cores(), st.floats(0.0, 1e6, allow_nan=False), st.integers(0, 6))
def test_the_compiled_boundaries_are_the_policys(
    core_and_runs: tuple[CoreSchedule, dict[str, SubchainRun]], start: float, position: int
) -> None:
    core, _ = core_and_runs
    position = min(position, len(core.slots))
    starts, lengths = np.zeros((1, 2, len(core.slots))), np.zeros((1, 2, len(core.slots)))
    for j, slot in enumerate(core.slots):
        starts[0, 1, j], lengths[0, 1, j] = slot.start_ms, slot.length_ms
    switch = np.array([[0.0, core.switch_ms]])
    nslots = np.array([[0, len(core.slots)]], dtype=np.int64)
    compiled = cp.boundary_ms(starts, lengths, switch, nslots, 0, 1, start, position)
    assert compiled == boundary_ms(core, start, position)  # the same operations: the same bits


def test_a_core_handed_to_its_owner_again_changes_nothing() -> None:
    raised = np.array([NONE, 2], dtype=np.int64)
    actions = np.full(ACTIONS, 7, dtype=np.int64)
    cp.hand_over(raised, 1, 2, actions)
    assert (actions[RAISE], actions[HANDOVER], actions[LOWER], raised[1]) == (2, 0, NONE, 2)
    cp.hand_over(raised, 1, NONE, actions)  # the end of the last slice: the owner is lowered
    assert (actions[RAISE], actions[HANDOVER], actions[LOWER], raised[1]) == (NONE, 1, 2, NONE)
    cp.hand_over(raised, 0, 4, actions)  # a core nothing was raised on
    assert (actions[RAISE], actions[HANDOVER], actions[LOWER], raised[0]) == (4, 1, NONE, 4)
