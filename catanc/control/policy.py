"""The runtime policy: what ``catanc run`` does and ``catanc simulate`` models, decided in one place.

Pure (no I/O, no clock): the enforcer (:mod:`catanc.runtime.enforcer.run`) and the simulator's
Python engine (:mod:`catanc.sim.policies`) ask the same functions, with the time as an
argument, so the simulation follows the enforcer's rules by construction.  Runs in flight and
their hand-offs are :mod:`catanc.control.flights`'s; the schedule they run is
:mod:`catanc.control.schedule`'s.  Here (docs/explanation/model.md sections 5 and 6):

- **Walking a shared core's period** (:class:`CoreCursor`): its boundaries are each slot's
  switch (``switch_ms`` before the slice) and the end of the last slice; a new schedule takes
  effect at the next period's start; a core that slept through whole periods (idle, or
  suspended) counts them, so its phase and its every-``runs``-periods triggers stay in place.
- **Slot ownership and stealing** (:func:`switch_at`): at a slot's switch its subchain is
  raised, unless a subchain of higher priority on the core is late (triggered, not done, past
  its planned latency), which then takes the slot (on a core with stealing, the default);
  slot-aligned heads are triggered at their slot every ``runs`` periods; at the end of the last
  slice everything is lowered.  A change of owner lowers the previous one (:func:`hand_over`).
- **Which boundaries need the enforcer awake** (:func:`needs_wake`): one that triggers a head,
  or where a subchain of the core has a run in flight; across an idle stretch nothing can
  change (threads still raised for a run that ended sleep), the owner it would raise is raised
  when its head is next triggered, and the boundaries slept through are caught up, in order, at
  the next wake-up.
- **Clocks** (:func:`next_clock_ms`): dedicated subchains (and batch ones) every period, never
  bunching up after a delay.
- **Re-solve cadence** (:class:`Cadence`): the first re-solve after ``first_solve_after_s``,
  Stage II every ``stage2_every_s``, both stages every ``stage1_every_s`` and when the cores
  change.
- **Lost runs** (:func:`lost_after_ms`): a run not done after 20 planned latencies (and a
  second) is given up.
- **A new plan** (:func:`replanned`): a new allocation, or other subchains on their own clocks,
  restarts every core's period and every clock; other changes (slots, periods, rates) are taken
  by each core at its next period.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Set
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

from catanc.control.schedule import CoreSchedule, RuntimeSchedule, SubchainRun, is_late
from catanc.spec.language import Runtime

Stage = Literal["stage1", "stage2"]

LOST_AFTER = 20.0
"""A run not done after this many planned latencies (and at least :data:`LOST_MIN_MS`) is given up as lost."""
LOST_MIN_MS = 1000.0


# --------------------------------------------------------------------------- a shared core's period


def boundary_ms(core: CoreSchedule, start_ms: float, position: int) -> float:
    """When boundary ``position`` of a period starting at ``start_ms`` is: slot ``position``'s switch (budgeted
    before its slice), or for ``position == len(slots)`` the end of the last slice."""
    slots = core.slots
    if position < len(slots):
        return start_ms + slots[position].start_ms - core.switch_ms
    last = slots[-1]
    return start_ms + last.start_ms + last.length_ms


@dataclass
class CoreCursor:
    """Where a shared core is in its periodic schedule: the next boundary of the current period."""

    schedule: CoreSchedule  # the schedule of the current period (a new one waits for the next period)
    start_ms: float  # the current period's start
    index: int = 0  # periods since the cursor started
    position: int = 0  # the next boundary: slot `position`'s switch, or the end of the last slice
    due: float = field(init=False)  # when the next boundary is due

    def __post_init__(self) -> None:
        self.due = boundary_ms(self.schedule, self.start_ms, self.position)

    @property
    def at_end(self) -> bool:
        return self.position >= len(self.schedule.slots)

    def due_ms(self) -> float:
        """When the next boundary is due."""
        return self.due

    def advance(self, latest: CoreSchedule | None, now_ms: float) -> None:
        """Past the next boundary; after the period's end, into the next period with ``latest`` (the core's schedule
        now; None keeps this one).  Whole periods slept through (an idle core sleeps until its next head
        trigger) are counted and skipped: the period containing ``now_ms`` is the next one, on the same grid."""
        if not self.at_end:
            self.position += 1
        else:
            period = self.schedule.period_ms
            start = self.start_ms + period
            skipped = max(0, math.floor((now_ms - start) / period))
            self.start_ms = start + skipped * period
            self.index += 1 + skipped
            self.position = 0
            if latest is not None:
                self.schedule = latest
        self.due = boundary_ms(self.schedule, self.start_ms, self.position)

    def next_period_ms(self) -> float:
        """When the next period starts (its first switch)."""
        return self.start_ms + self.schedule.period_ms


class Switch(NamedTuple):
    """What happens at a boundary: whose threads are raised (None: every one lowered), whose head is triggered."""

    owner: str | None
    trigger: str | None = None
    stolen: bool = False  # the owner is a late subchain that took another's slot


@dataclass(frozen=True)
class SlotRule:
    """What one boundary of a core's period decides, worked out once from its schedule."""

    subchain: str | None  # the slot's subchain; None at the end of the last slice
    every: int | None = None  # its head is triggered here every `every` periods (None: never here)
    thieves: tuple[str, ...] = ()  # subchains that take the slot when late, best first: the first late one wins


def slot_rules(core: CoreSchedule, runs: Mapping[str, SubchainRun]) -> tuple[SlotRule, ...]:
    """A rule per boundary of ``core``'s period: each slot's switch, then the end of the last slice.

    A slot's thieves are the other subchains of the core that outrank its own, highest priority
    (then name) first: the late one of highest priority above the slot's owner takes the slot.
    A core without stealing (``schedule.stealing: false``) has none: each slot is its owner's.
    """
    rules = []
    for slot in core.slots:
        owner = runs[slot.subchain]
        above = [
            runs[other.subchain]
            for other in core.slots
            if core.stealing and runs[other.subchain].priority > owner.priority
        ]
        above.sort(key=lambda run: (run.priority, run.name), reverse=True)
        rules.append(SlotRule(slot.subchain, owner.runs, tuple(run.name for run in above)))
    rules.append(SlotRule(None))
    return tuple(rules)


def decide(rule: SlotRule, period_index: int, late: Callable[[str], bool]) -> Switch:
    """The decision at a boundary with ``rule`` in period ``period_index``; ``late(name)``: is it late now."""
    subchain = rule.subchain
    if subchain is None:
        return Switch(None)
    owner = subchain
    for thief in rule.thieves:  # best first (a loop, not any(): the enforcer asks this at every switch)
        if late(thief):
            owner = thief
            break
    every = rule.every
    trigger = subchain if every is not None and period_index % every == 0 else None
    return Switch(owner, trigger, owner != subchain)


def late_on(
    core: CoreSchedule, runs: Mapping[str, SubchainRun], oldest_ms: Callable[[str], float | None], now_ms: float
) -> set[str]:
    """The subchains of ``core`` whose oldest run in flight is late at ``now_ms``."""
    late = set()
    for slot in core.slots:
        if is_late(oldest_ms(slot.subchain), now_ms, runs[slot.subchain]):
            late.add(slot.subchain)
    return late


def switch_at(
    core: CoreSchedule, position: int, period_index: int, runs: Mapping[str, SubchainRun], late: Set[str]
) -> Switch:
    """The decision at boundary ``position`` of period ``period_index`` (``late``: :func:`late_on` now)."""
    return decide(slot_rules(core, runs)[position], period_index, late.__contains__)


class Handover(NamedTuple):
    """A core's change of owner: the previous owner's threads go back to their resting level, the new one's up."""

    changed: bool  # False: the owner stays (nothing is lowered)
    lowered: str | None  # the previous owner when it changes (None: nothing was raised)


def hand_over(raised: dict[int, str | None], core: int, owner: str | None) -> Handover:
    """``owner`` runs raised on ``core`` from now (``raised``: each core's owner, updated; None: every one lowered)."""
    previous = raised.get(core)
    if previous == owner:
        return Handover(False, None)
    raised[core] = owner
    return Handover(True, previous)


def needs_wake(rule: SlotRule, period_index: int, *, active: bool) -> bool:
    """Whether the enforcer must be awake at a boundary with ``rule`` in period ``period_index``.

    ``active``: some subchain of the core has a run in flight.  An idle core changes nothing
    at a boundary unless a head is triggered there: every thread on it sleeps (those raised
    for a run that ended too), and they are put at their levels when a head is next triggered.
    """
    return active or (rule.every is not None and period_index % rule.every == 0)


# --------------------------------------------------------------------------- clocks and cadence


def next_clock_ms(due_ms: float, period_ms: float, now_ms: float) -> float:
    """A clock that fired (due at ``due_ms``) fires next a period later, or now if it fell behind."""
    return max(due_ms + period_ms, now_ms)


def lost_after_ms(run: SubchainRun | None) -> float:
    """How long a run may stay in flight before it is given up as lost."""
    return max(LOST_MIN_MS, LOST_AFTER * (run.latency_ms if run is not None else LOST_MIN_MS))


@dataclass
class Cadence:
    """When to re-solve (times in ms from the run's start)."""

    runtime: Runtime
    next_stage1_ms: float
    next_stage2_ms: float

    @classmethod
    def start(cls, runtime: Runtime) -> Cadence:
        first = runtime.first_solve_after_s
        return cls(runtime, (first + runtime.stage1_every_s) * 1000.0, first * 1000.0)

    def due(self, now_ms: float) -> Stage | None:
        """The stage to re-solve now, if any (both stages when Stage I is due)."""
        if now_ms >= self.next_stage1_ms:
            return "stage1"
        if now_ms >= self.next_stage2_ms:
            return "stage2"
        return None

    def solved(self, stage: Stage, now_ms: float) -> None:
        """A re-solve of ``stage`` was made at ``now_ms``: the next ones count from it."""
        if stage == "stage1":
            self.next_stage1_ms = now_ms + self.runtime.stage1_every_s * 1000.0
        self.next_stage2_ms = now_ms + self.runtime.stage2_every_s * 1000.0

    def cores_changed(self, now_ms: float) -> None:
        """Stage I ran now for new cores: the next periodic one counts from it (Stage II's does not)."""
        self.next_stage1_ms = now_ms + self.runtime.stage1_every_s * 1000.0

    def next_ms(self) -> float:
        return min(self.next_stage1_ms, self.next_stage2_ms)


# --------------------------------------------------------------------------- a new plan


class Replanned(NamedTuple):
    """What a new plan's schedule does to the one running."""

    moved: bool  # a new allocation: some subchain on other cores, or shared where it was dedicated (or back)
    reinstall: bool  # every core's period and every clock restart now; else each core takes it at its next period


def replanned(before: RuntimeSchedule, after: RuntimeSchedule) -> Replanned:
    """Whether ``after`` replaces ``before`` by a reinstall (a new allocation, or another set of subchains on their
    own clocks) or by an update (slots, periods and rates, taken by each core at its next period)."""
    moved = _placement(before) != _placement(after)
    clocked = {run.name for run in before.clocked} != {run.name for run in after.clocked}
    return Replanned(moved, moved or clocked)


def _placement(schedule: RuntimeSchedule) -> tuple[tuple[str, tuple[int, ...], bool], ...]:
    return tuple((name, run.cores, run.shared) for name, run in sorted(schedule.subchains.items()))
