"""The shared cores' periodic schedules, walked in real time: the enforcer's hot path.

Each shared core has a :class:`~catanc.control.policy.CoreCursor` (where it is in its period)
and the :func:`~catanc.control.policy.slot_rules` of its schedule.  At each boundary that is
due, :meth:`SharedCores.run_due` reads the rings of the core's runs in flight (lateness needs
them), asks :func:`~catanc.control.policy.decide` who owns the slot, changes only the threads
that must change (the previous owner's raised threads down, the new owner's threads that may
run in its slice up) and triggers a slot-aligned head.  :attr:`SharedCores.wake_ms` says when a
core next needs the loop: its next boundary, or across an idle stretch the next head trigger
(:func:`~catanc.control.policy.needs_wake`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from catanc.control.policy import (
    CoreCursor,
    SlotRule,
    Switch,
    boundary_ms,
    decide,
    hand_over,
    needs_wake,
    slot_rules,
)
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, SubchainRun
from catanc.model.priorities import RUNNING_FIFO
from catanc.runtime.enforcer.costs import SAMPLES, Costs
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook, Seen
from catanc.runtime.linux.levels import Levels


class Trigger(Protocol):
    """Trigger a subchain's head now; its nodes run raised until ``raised_until`` (its slot's end)."""

    def __call__(self, run: SubchainRun, now: float, raised_until: float | None = None, *, at_slot: bool = ...) -> None:
        """``at_slot``: at its slot's switch (its rings were just read, its threads raised)."""


Gone = Callable[[list[int]], None]
"""Threads found gone while their level was set."""

END = Switch(None)


@dataclass
class _Core:
    cursor: CoreCursor
    names: tuple[str, ...]  # the subchains of the core's current schedule
    rules: tuple[SlotRule, ...]
    watch: tuple[tuple[str, ...], ...]  # per boundary: whose rings the decision needs (thieves, the slot's own)
    every: int = 1  # the longest trigger cycle of its slots, in periods
    wake_ms: float = 0.0


class SharedCores:
    """Every shared core's period, raised owner and next wake-up."""

    def __init__(
        self, book: RunBook, levels: Levels, costs: Costs, *, trigger: Trigger, seen: Seen, gone: Gone
    ) -> None:
        self.book, self.levels, self.costs = book, levels, costs
        self.trigger, self.seen, self.gone = trigger, seen, gone
        self.schedule: RuntimeSchedule | None = None
        self.runs: dict[str, SubchainRun] = {}
        self.wiring: Wiring | None = None  # the node threads, as the hot path needs them (the caller keeps it fresh)
        self._latest: dict[int, CoreSchedule] = {}
        self.cores: dict[int, _Core] = {}
        self.raised: dict[int, str | None] = {}  # core -> the subchain raised there (as the simulator has it)
        self._raised_from: dict[int, int] = {}  # core -> the owner's threads are raised from this node on
        self.wake_ms = math.inf
        self._now = 0.0

    def install(self, schedule: RuntimeSchedule, now_ms: float) -> None:
        """Start ``schedule``'s periods from ``now_ms`` (a new allocation: nothing raised)."""
        self.update(schedule)
        self.raised.clear()
        self._raised_from.clear()
        self.cores = {core.core: self._core(CoreCursor(core, now_ms)) for core in schedule.shared if core.slots}
        self.rewake()

    def update(self, schedule: RuntimeSchedule) -> None:
        """A new schedule on the same allocation: each core takes it at its next period."""
        self.schedule = schedule
        self.runs = schedule.subchains
        self._latest = {core.core: core for core in schedule.shared}
        self.rewake()

    def _core(self, cursor: CoreCursor) -> _Core:
        rules = slot_rules(cursor.schedule, self.runs)
        watch = tuple(() if rule.subchain is None else (*rule.thieves, rule.subchain) for rule in rules)
        every = max((rule.every or 1 for rule in rules), default=1)
        return _Core(cursor, tuple(slot.subchain for slot in cursor.schedule.slots), rules, watch, every)

    def rewire(self, wiring: Wiring) -> None:
        """The node threads changed (one came or went): what was raised is worked out again at the next switch."""
        self.wiring = wiring
        self._raised_from.clear()

    def forget_raised(self) -> None:
        """Every thread was put back at its resting level (a re-pin): nothing is raised."""
        self.raised.clear()
        self._raised_from.clear()

    def latest(self, core: int) -> CoreSchedule | None:
        """``core``'s schedule in the plan in force (a cursor takes it at its next period)."""
        return self._latest.get(core)

    # ------------------------------------------------------------------ the hot path

    def run_due(self, now_ms: float) -> None:
        """Every boundary due by ``now_ms``, in order, on every core."""
        woke = False
        for core_id, core in self.cores.items():
            cursor = core.cursor
            if cursor.due > now_ms:
                continue
            woke = True
            planned = core.wake_ms  # earlier boundaries were slept through: caught up now, not switch latencies
            while cursor.due <= now_ms:
                self._boundary(core_id, core, now_ms, sample=cursor.due >= planned)
                schedule = cursor.schedule
                cursor.advance(self._latest.get(core_id), now_ms)
                if cursor.schedule is not schedule:
                    fresh = self._core(cursor)
                    core.names, core.rules, core.watch, core.every = fresh.names, fresh.rules, fresh.watch, fresh.every
            core.wake_ms = self._wake(core_id, core)
        if woke:
            self.wake_ms = min(core.wake_ms for core in self.cores.values())

    def _late(self, name: str) -> bool:
        return self.book.late(name, self._now, self.runs[name])

    def _boundary(self, core_id: int, core: _Core, now_ms: float, *, sample: bool) -> None:
        cursor = core.cursor
        position = cursor.position
        rule = core.rules[position]
        if rule.subchain is None:
            decision = END
        else:  # who is late, and how far the runs got: what the rings say now
            readers = self.wiring.readers if self.wiring is not None else {}
            raised = self.raised.get(core_id)
            for name in core.watch[position] if raised is None else (*core.watch[position], raised):
                ring = readers.get(name, ())
                for _, _, reader in ring:
                    if reader.words[2] != reader.last:
                        self.book.read(self.runs[name], ring, now_ms, self.seen)
                        break
            self._now = now_ms
            decision = decide(rule, cursor.index, self._late)
        owner, trigger, stolen = decision
        if stolen and owner is not None:
            self.book.state(owner).steals += 1
        levels = self.levels
        calls = levels.calls
        self.raise_owner(core_id, owner, triggered=trigger is not None and trigger == owner)
        if trigger is not None:
            slot = cursor.schedule.slots[position]
            raised_until = slot.start_ms + slot.length_ms + cursor.start_ms if owner == trigger else None
            self.trigger(self.runs[trigger], now_ms, raised_until, at_slot=True)
        if sample and (trigger is not None or levels.calls != calls):
            switches = self.costs.switches.get(core_id)
            if switches is None:
                switches = self.costs.switches[core_id] = deque(maxlen=SAMPLES)
            switches.append(time.monotonic_ns() / 1e6 - cursor.due)

    def raise_owner(self, core: int, owner: str | None, *, triggered: bool) -> None:
        """Lower what was raised on ``core`` if the owner changes; raise the owner's threads that may run now."""
        levels = self.levels
        if hand_over(self.raised, core, owner).changed:
            self._raised_from.pop(core, None)
            if levels.raised.get(core):
                gone = levels.lower_on(core)
                if gone:
                    self.gone(gone)
        if owner is None or self.wiring is None:
            return
        first = 0 if triggered else self.book.first_index(owner)
        if first is None or self._raised_from.get(core, math.inf) <= first:
            return  # idle (raised when its head is next triggered), or raised from that node on already
        tids = self.wiring.tids.get(owner, ())
        if first < len(tids):
            self._raised_from[core] = first
            gone = levels.raise_on(core, tids[first], RUNNING_FIFO)
            if gone:
                self.gone(gone)

    def raised_on(self, run: SubchainRun) -> bool:
        """Whether ``run`` (shared) is the subchain raised on its core now."""
        return self.raised.get(run.cores[0]) == run.name

    # ------------------------------------------------------------------ when to wake

    def rewake(self) -> None:
        for core_id, core in self.cores.items():
            core.wake_ms = self._wake(core_id, core)
        self.wake_ms = min((core.wake_ms for core in self.cores.values()), default=math.inf)

    def _wake(self, core_id: int, core: _Core) -> float:
        """When ``core`` next needs the loop: its next boundary, or on an idle core the next head trigger
        (:func:`~catanc.control.policy.needs_wake` with nothing active: a boundary whose rule triggers now).

        Threads raised for a run that has ended do not keep the core awake: they are put back at
        their resting level now, as the next boundary would (asleep, nothing changes for them), and
        raised again when their subchain's head is next triggered in its slot.  The boundaries slept
        through are caught up, in order, at the next wake-up.
        """
        cursor = core.cursor
        states = self.book.states
        for name in core.names:
            state = states.get(name)
            if state is not None and (state.in_flight or state.pending is not None):
                return cursor.due
        if self.levels.raised.get(core_id):  # after this wake-up's switch: it is not delayed by this
            self._raised_from.pop(core_id, None)
            gone = self.levels.lower_on(core_id)
            if gone:
                self.gone(gone)
        schedule = cursor.schedule
        rules = core.rules
        same = self._latest.get(core_id) is schedule  # else a new schedule starts next period: wake then
        position, index, start = cursor.position, cursor.index, cursor.start_ms
        end = len(rules) - 1  # the last rule is the period's end, which never triggers
        for _ in range((core.every + 1) * len(rules)):
            if needs_wake(rules[position], index, active=False):
                return boundary_ms(schedule, start, position)
            position += 1
            if position > end:
                if not same:
                    return start + schedule.period_ms
                position, index, start = 0, index + 1, start + schedule.period_ms
        return math.inf
