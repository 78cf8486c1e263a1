"""What the enforcer enforces, as plain data: a plan turned into triggers, slots and priorities.

Pure: :func:`runtime_schedule` reads a :class:`~catanc.planning.planner.Plan` and
the problem it was planned for (for ``c(S)``), and the loop decisions the
enforcer's threads make each period are small functions here, so the
tests can simulate them without threads or a kernel (docs/explanation/model.md
sections 5 and 6):

- a dedicated subchain's head is triggered every ``period_ms`` on its own
  clock, and so is a batch subchain (its period is an average);
- every other shared subchain is triggered at the start of its slot every
  ``k`` periods (the plan's ``every``: ``k = n = 1/f`` unless a rate cap or a
  fixed rate makes it longer, like VR's timewarp at vsync), so its run falls
  into its slices and no trigger waits for a slot (docs/explanation/model.md section 4);
- in each period a shared core raises each subchain's threads for its slice
  ``f * c(S)``, in order, after a switch; the rest of ``T`` is slack;
- priority stealing: a slot goes to the highest-priority subchain on the
  core whose output is late (triggered, not done, past its planned
  latency), when that one outranks the slot's owner (unless the spec turns
  stealing off: ``schedule.stealing: false``, the paper's ablation);
- a run is *counted* late only past the latency the plan gives it (:attr:`SubchainRun.late_after_ms`): its
  subchain's latency, plus, where a node of it shares an executor's thread with another subchain's
  node on its core group, the longest wait behind that node's run which the executor model
  predicts (:attr:`~catanc.model.executor_thread.MemberRate.longest_wait_ms`: the slot model's
  latencies leave it out, and PLAN.md says so).  It steals from its planned latency on, as the
  executor model has it steal (its hold ``S_ij`` counts on that).
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

from catanc.explain.executors import plan_turns
from catanc.model.priorities import resting_fifo
from catanc.model.problem import Problem
from catanc.planning.order import slot_starts
from catanc.spec.language import Schedule
from catanc.spec.speedup import threads_and_speedup

if TYPE_CHECKING:
    from catanc.planning.types import Plan


@dataclass(frozen=True)
class SubchainRun:
    """How one subchain is triggered and prioritised."""

    name: str
    nodes: tuple[str, ...]
    cores: tuple[int, ...]
    shared: bool
    period_ms: float
    latency_ms: float  # planned: a run is late once it takes longer
    runs: int | None  # k: triggered at its slot every k periods; None: on its own clock
    priority: int  # stealing priority: higher steals from lower
    node_threads: tuple[tuple[int, float], ...] = ()  # per node, its threads (Eq. 1's q) and their speedup
    wait_ms: float = 0.0  # a run's planned wait for an executor's thread behind another subchain's node

    @property
    def late_after_ms(self) -> float:
        """A run that takes longer is counted late: its latency and its planned wait for an executor's thread."""
        return self.latency_ms + self.wait_ms

    def threads_of(self, index: int) -> tuple[int, float]:
        """Node ``index``'s threads and the speedup they give (a measured run times it is one thread's time)."""
        return self.node_threads[index] if self.node_threads else (1, 1.0)

    @property
    def on_clock(self) -> bool:
        return self.runs is None


@dataclass(frozen=True)
class Slot:
    """One subchain's slice in a shared core's period."""

    subchain: str
    start_ms: float  # offset from the period's start, after the switch to it
    length_ms: float  # f * c(S)


@dataclass(frozen=True)
class CoreSchedule:
    core: int
    period_ms: float  # T
    switch_ms: float
    slots: tuple[Slot, ...]
    stealing: bool = True  # a late subchain may take the slot of one of lower priority (spec: schedule.stealing)

    @property
    def busy_ms(self) -> float:
        """Switches and slices: at most ``(1 - slack) * T``."""
        return sum(self.switch_ms + slot.length_ms for slot in self.slots)


@dataclass(frozen=True)
class RuntimeSchedule:
    cores: int
    subchains: dict[str, SubchainRun]
    shared: tuple[CoreSchedule, ...]

    def subchain_of(self, node: str) -> SubchainRun | None:
        return self._run_of_node.get(node)

    @cached_property
    def _run_of_node(self) -> dict[str, SubchainRun]:  # asked on every completion: built once per plan
        return {node: run for run in self.subchains.values() for node in run.nodes}

    @property
    def clocked(self) -> tuple[SubchainRun, ...]:
        """Subchains the clock thread triggers (dedicated ones, and shared ones on their own clock)."""
        return tuple(run for run in self.subchains.values() if run.on_clock)


def runtime_schedule(plan: Plan, problem: Problem, schedule: Schedule) -> RuntimeSchedule:
    """The schedule the enforcer runs for ``plan`` (``problem`` gives each subchain's ``c(S)``)."""
    compute = {sub.name: sub.compute_ms for sub in problem.subchains}
    speedups = {sub.name: sub.node_speedups for sub in problem.subchains}
    waits = executor_waits_ms(plan, problem, schedule)
    subchains = {}
    for name, sub in plan.subchains.items():
        runs = None  # dedicated, or batch (a continuous fraction): its own clock
        if sub.shared and name in plan.runs:
            runs = plan.every.get(name, plan.runs[name])
        subchains[name] = SubchainRun(
            name=name,
            nodes=sub.nodes,
            cores=sub.cores,
            shared=sub.shared,
            period_ms=sub.period_ms,
            latency_ms=sub.latency_ms,
            runs=runs,
            priority=sub.priority,
            node_threads=tuple(threads_and_speedup(s, sub.threads) for s in speedups[name]),
            wait_ms=waits.get(name, 0.0),
        )
    shared = []
    for core in sorted(plan.shared_cores, key=lambda c: c.core):
        slices = {name: plan.subchains[name].fraction * compute[name] for name in core.order}
        starts = slot_starts(core.order, slices, schedule.switch_ms)
        slots = tuple(Slot(name, starts[name], slices[name]) for name in core.order)
        shared.append(CoreSchedule(core.core, core.period_ms, schedule.switch_ms, slots, schedule.stealing))
    return RuntimeSchedule(plan.cores, subchains, tuple(shared))


def executor_waits_ms(plan: Plan, problem: Problem, schedule: Schedule) -> dict[str, float]:
    """Per subchain, how long a run of it may wait for an executor's thread behind another subchain's node under
    ``plan``: each of its nodes' longest wait (:func:`~catanc.explain.executors.plan_turns`), added up over its
    nodes; subchains without one are left out."""
    sub_of = {node: sub.name for sub in plan.subchains.values() for node in sub.nodes}
    waits: dict[str, float] = {}
    for executor in problem.executors:
        turns = plan_turns(executor, plan, problem, schedule)
        for rate in () if turns is None else turns.rates:
            name = sub_of[rate.node]
            waits[name] = waits.get(name, 0.0) + rate.longest_wait_ms
    return waits


# --------------------------------------------------------------------------- per-period decisions


def triggers_at_slot(run: SubchainRun, period_index: int) -> bool:
    """Whether a slice-triggered subchain's head is triggered at its slot in period ``period_index``."""
    return run.runs is not None and period_index % run.runs == 0


def is_late(triggered_ms: float | None, now_ms: float, run: SubchainRun) -> bool:
    """A run triggered at ``triggered_ms`` and not done is late once its planned latency has passed: its subchain
    steals (it is *counted* late at its end only past :attr:`SubchainRun.late_after_ms`)."""
    return triggered_ms is not None and now_ms - triggered_ms > run.latency_ms


def slot_owner(slot: Slot, core: CoreSchedule, runs: Mapping[str, SubchainRun], late: Set[str]) -> str:
    """Whose threads are raised in ``slot``: its subchain's, or the late one of highest priority above it."""
    owner = runs[slot.subchain]
    if not core.stealing:
        return owner.name
    thieves = [runs[s.subchain] for s in core.slots if s.subchain in late and s.subchain != slot.subchain]
    best = max(thieves, key=lambda run: (run.priority, run.name), default=None)
    if best is not None and best.priority > owner.priority:
        return best.name
    return owner.name


def node_priority(run: SubchainRun | None) -> int:
    """The SCHED_FIFO priority a node's threads rest at: 1 shared, 2 dedicated, 3 unscheduled."""
    return resting_fifo(None if run is None else run.shared)
