"""Who triggers what, and at which priority: catanc's schedule and the hand-tuned baselines.

- :class:`CatanPolicy` does what ``catan run`` does (docs/explanation/model.md sections
  5 and 6, with :mod:`catanc.control.policy`'s decisions, the enforcer's too):
  a clock per dedicated (or clock-triggered) subchain, a periodic slot
  schedule per shared core that raises one subchain at a time, later nodes
  event-triggered, priority stealing, and, given a replanner, the periodic
  re-solve with the p95 of each node's last compute times.  Without one it
  is a static plan (Static-FullRun, Static-20s).
- :class:`TimerPolicy` is the developer's default: every node listed in
  ``baseline.rates_hz`` runs on its own timer, every other scheduled node
  when a new input arrives (from a scheduled predecessor if it has one, else
  from a sensor), on all ``K`` cores shared fairly (CFS) or by static
  SCHED_FIFO priorities (:func:`catanc.planning.baseline.static_priorities`).

Unscheduled nodes with a rate tick on their own clock under every policy.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

from catanc.control.flights import Flight, Flights, NodeQueues
from catanc.control.measure import Measurements
from catanc.control.policy import Cadence, SlotRule, boundary_ms, decide, hand_over, replanned, slot_rules
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, SubchainRun, is_late, runtime_schedule
from catanc.control.timers import Triggers, trigger_rules
from catanc.model.priorities import ENFORCER_FIFO, RUNNING_FIFO, SHARED_FIFO
from catanc.planning.replan import Replanner
from catanc.sim.cpu import Discipline, Job, Pool
from catanc.sim.dataflow import Dataflow, Origins
from catanc.sim.engine import Engine
from catanc.sim.threads import ExecutorGate
from catanc.spec.language import Spec

Sampler = Callable[[str, float], float]
"""(node, seconds into the run) -> one run's compute time in ms on one thread."""

RAISED, RESTING_SHARED, DEDICATED = RUNNING_FIFO, SHARED_FIFO, RUNNING_FIFO
"""The enforcer's SCHED_FIFO levels (docs/explanation/model.md section 6) as job priorities: the slot owner's, a shared
subchain's between its slices, a dedicated subchain's."""


@dataclass(frozen=True)
class Delays:
    """The real runtime's delays, which the simulator leaves out unless given (both 0: today's model).

    - ``wake_ms``: from a trigger (a timer, a slot switch, a node's completion relayed to the next
      node) to the triggered thread running: the worker's wake-up and its read of the trigger
      (``catanc report``'s "hop delay"; for ``catanc bench``'s driver, its timer's lateness too);
    - ``switch_late_ms``: how late the enforcer makes each slot switch (``catanc report``'s
      "switch latency"): the owner's raise and its head's trigger both come that much later.
    - ``before_run_ms`` and ``after_run_ms``: CPU a node's thread spends around each run that its
      measured compute time leaves out (``benchmarks.vr_run_cpu`` measures it from the workers'
      thread clocks), at the run's priority: *before*, from its trigger on (the wake-up, the
      receive: the run's job takes that much more, and reads its inputs when it first runs, as
      before); *after*, once its output is out (its record, its done report): its successors are
      triggered at the run's end, but the node's thread holds its core, and takes no new run,
      until that CPU is spent too.  Neither is in the compute times a re-plan measures.
    - ``charged``: each run reports the CPU around it in its compute time, so the re-plans count it
      (``before_run_ms + after_run_ms`` more than its draw: its thread's CPU since its previous
      run's report, as :mod:`catanc.ros` and ``catanc bench``'s workers report it).
    - ``switch_cpu_ms``: catanc's enforcer's CPU at each slot switch (``catanc report``'s CPU per
      wake-up), at its own level above every node, on the switch's core from the slot's boundary
      (it wakes on time; its raise and trigger come ``switch_late_ms`` after, inside that CPU).
    """

    wake_ms: float = 0.0
    switch_late_ms: float = 0.0
    before_run_ms: float = 0.0
    after_run_ms: float = 0.0
    switch_cpu_ms: float = 0.0
    charged: bool = False

    def __post_init__(self) -> None:
        if min(self.wake_ms, self.switch_late_ms, self.before_run_ms, self.after_run_ms, self.switch_cpu_ms) < 0:
            raise ValueError(f"delays are never negative: {self}")

    @property
    def none(self) -> bool:
        return self == NO_DELAYS


NO_DELAYS = Delays()
ENFORCER = "<enforcer>"
"""The node name of the enforcer's own CPU jobs (no node is named so: names are identifiers)."""


def _nothing(_job: Job) -> None:
    pass


def after_run(engine: Engine, pool: Pool, delays: Delays, job: Job, release: Callable[[], None]) -> None:
    """``job``'s run has produced its output: ``release`` its node's thread once ``delays.after_run_ms`` of
    CPU more is spent at its priority (at once without it).  The thread was running, so it stays at the front
    of its level."""
    if delays.after_run_ms == 0.0:
        release()
        return
    tail = Job(job.node, delays.after_run_ms, 1, job.priority, 0, lambda _job: release())
    engine.submit(pool, tail)
    tail.since = -engine.arrival()


def after_wake(engine: Engine, delays: Delays, start: Callable[[], None]) -> Callable[[], None]:
    """``start``, run ``delays.wake_ms`` later than it is called (at once without a delay)."""
    if delays.wake_ms == 0.0:
        return start
    return lambda: engine.at(engine.now + delays.wake_ms, start)


class Reading:
    """What one run of ``node`` reads: its inputs' newest outputs when it first runs.

    A real node reads when its thread wakes and runs, not when it is triggered: a run triggered
    behind a higher-priority one (fifo-static's Render behind Timewarp at vsync) reads data that
    arrived while it waited (``catanc bench``'s workers record their start when they run).
    """

    def __init__(self, engine: Engine, flow: Dataflow, node: str) -> None:
        self.engine, self.flow, self.node = engine, flow, node
        self.origins: Origins = {}

    def read(self, _job: Job) -> None:
        self.origins = self.flow.read_inputs(self.node, self.engine.now)


def start_sensors(engine: Engine, flow: Dataflow, spec: Spec, phase_ms: float = 0.0) -> None:
    """Unscheduled nodes with a rate tick every period from ``phase_ms`` (0: with the schedule's first period)."""
    for name, node in spec.nodes.items():
        if not node.scheduled and node.rate_hz is not None:
            period = 1000.0 / node.rate_hz
            _tick_every(engine, flow, name, period, phase_ms)


def _tick_every(engine: Engine, flow: Dataflow, node: str, period_ms: float, due_ms: float) -> None:
    def tick() -> None:
        flow.tick(node, engine.now)
        _tick_every(engine, flow, node, period_ms, due_ms + period_ms)

    engine.at(due_ms, tick)


@dataclass
class SubchainState(Flights[Flight]):
    steals: int = 0


@dataclass(frozen=True)
class Replan:
    at_s: float
    reason: str  # stage1 | stage2
    allocation_changed: bool
    objective: float


class CatanPolicy:
    """catanc's plan, enforced as ``catanc run`` enforces it; re-solved if given a :class:`Replanner`."""

    def __init__(
        self,
        engine: Engine,
        flow: Dataflow,
        *,
        spec: Spec,
        schedule: RuntimeSchedule,
        sample: Sampler,
        replanner: Replanner | None = None,
        delays: Delays = NO_DELAYS,
    ) -> None:
        self.engine, self.flow, self.spec, self.sample = engine, flow, spec, sample
        self.delays = delays
        self.schedule = schedule
        self.replanner = replanner
        self.reoptimiser = Reoptimiser(spec, replanner) if replanner is not None else None
        self.measurements = self.reoptimiser.measurements if self.reoptimiser is not None else None
        self.states = {name: SubchainState() for name in schedule.subchains}
        self.nodes = NodeQueues()
        self.gate = ExecutorGate(spec)
        self.raised: dict[int, str | None] = {}
        self.pools: dict[str, Pool] = {}  # subchain -> the pool its nodes run on
        self.core_busy_ms: dict[int, float] = {}  # from pools of earlier allocations
        self.generation = 0
        self._rule_cache: dict[tuple[int, int], tuple[CoreSchedule, dict[str, SubchainRun], tuple[SlotRule, ...]]] = {}

    # -------------------------------------------------------------- set-up

    def start(self) -> None:
        self._install(self.schedule)
        if self.reoptimiser is not None:
            self.engine.at(self.reoptimiser.first_ms, self._reoptimise)

    def _install(self, schedule: RuntimeSchedule) -> None:
        """New pools for ``schedule``'s allocation (running jobs move with their subchain), clocks restarted."""
        self.generation += 1
        self.schedule = schedule
        old_jobs = [job for pool in self.engine.pools for job in pool.jobs]
        self._fold_busy()
        pools: dict[str, Pool] = {}
        by_core: dict[int, Pool] = {}
        for name, run in sorted(schedule.subchains.items()):
            if run.shared:
                core = run.cores[0]
                by_core.setdefault(core, Pool(f"core-{core}", (core,), "fifo"))
                pools[name] = by_core[core]
            else:
                pools[name] = Pool(f"dedicated-{name}", run.cores, "fifo")
        self.pools = pools
        self.raised = {}
        unique = {id(pool): pool for pool in pools.values()}
        self.engine.pools = list(unique.values())
        for job in old_jobs:
            owner = schedule.subchain_of(job.node)
            if owner is not None:
                job.priority = RESTING_SHARED if owner.shared else DEDICATED
                self.engine.submit(pools[owner.name], job)
        for pool in self.engine.pools:
            self.engine.changed(pool)
        generation = self.generation
        now = self.engine.now
        for run in schedule.clocked:
            self._clock(run.name, generation, now)
        for shared in schedule.shared:
            self._period(shared.core, generation, now, 0)

    def _fold_busy(self) -> None:
        for pool in self.engine.pools:
            for core in pool.cores:
                self.core_busy_ms[core] = self.core_busy_ms.get(core, 0.0) + pool.busy_core_ms / len(pool.cores)
            pool.busy_core_ms = 0.0

    def busy_by_core(self) -> dict[int, float]:
        """Core -> time it ran jobs (ms), over every allocation so far."""
        self._fold_busy()
        return dict(self.core_busy_ms)

    # -------------------------------------------------------------- clocks and slots

    def _clock(self, name: str, generation: int, due_ms: float) -> None:
        def fire() -> None:
            if generation != self.generation:
                return
            run = self.schedule.subchains.get(name)
            if run is None or not run.on_clock:
                return
            self._trigger_head(run)
            self._clock(name, generation, max(due_ms + run.period_ms, self.engine.now))

        self.engine.at(due_ms, fire)

    def _period(self, core_id: int, generation: int, start_ms: float, index: int) -> None:
        def begin() -> None:
            if generation != self.generation:
                return
            core = next((c for c in self.schedule.shared if c.core == core_id), None)
            if core is None or not core.slots:
                return
            for position in range(len(core.slots) + 1):  # each slot's switch, then the end of the last slice
                boundary = boundary_ms(core, start_ms, position)
                if self.delays.switch_cpu_ms:
                    self.engine.at(boundary, self._enforcer_wakes(core.core, generation))
                when = boundary + self.delays.switch_late_ms
                self.engine.at(when, self._switcher(core, position, generation, index))
            self._period(core_id, generation, start_ms + core.period_ms, index + 1)

        self.engine.at(start_ms, begin)

    def _enforcer_wakes(self, core_id: int, generation: int) -> Callable[[], None]:
        """The enforcer's CPU for one switch on ``core_id``: a job above every node's level."""

        def wake() -> None:
            pool = next((p for p in self.engine.pools if p.cores == (core_id,)), None)
            if generation == self.generation and pool is not None:
                self.engine.submit(pool, Job(ENFORCER, self.delays.switch_cpu_ms, 1, ENFORCER_FIFO, 0, _nothing))

        return wake

    def _switcher(self, core: CoreSchedule, position: int, generation: int, index: int) -> Callable[[], None]:
        def switch() -> None:
            if generation != self.generation:
                return
            runs, now = self.schedule.subchains, self.engine.now

            def late(name: str) -> bool:
                return is_late(self.states[name].oldest_ms(), now, runs[name])

            decision = decide(self._rules(core, runs)[position], index, late)
            if decision.stolen and decision.owner is not None:
                self.states[decision.owner].steals += 1
            self._raise(core.core, decision.owner)
            if decision.trigger is not None:
                self._trigger_head(runs[decision.trigger])

        return switch

    def _rules(self, core: CoreSchedule, runs: dict[str, SubchainRun]) -> tuple[SlotRule, ...]:
        """``core``'s slot rules under ``runs``, worked out once per schedule (both are replaced, never changed)."""
        key = (id(core), id(runs))
        cached = self._rule_cache.get(key)
        if cached is None or cached[0] is not core or cached[1] is not runs:
            cached = self._rule_cache[key] = (core, runs, slot_rules(core, runs))
        return cached[2]

    def _raise(self, core_id: int, owner: str | None) -> None:
        """The previous owner's jobs on ``core_id`` back to FIFO 1 (to the front), ``owner``'s to FIFO 2 (the back)."""
        handover = hand_over(self.raised, core_id, owner)
        if not handover.changed:
            return
        for name, level in ((handover.lowered, RESTING_SHARED), (owner, RAISED)):
            if name is None or name not in self.pools:
                continue
            pool = self.pools[name]
            members = set(self.schedule.subchains[name].nodes)
            for job in pool.jobs:
                if job.node in members:
                    job.priority = level
                    # Linux: a thread raised goes to the back of its new level, one lowered to the front.
                    ticket = self.engine.arrival()
                    job.since = ticket if level == RAISED else -ticket
            self.engine.changed(pool)

    # -------------------------------------------------------------- runs

    def _trigger_head(self, run: SubchainRun) -> None:
        started = self.states[run.name].start(Flight(0, self.engine.now))
        if started is not None and not started.deferred:
            self._trigger(run.nodes[0], started.seq)

    def _trigger(self, node: str, seq: int) -> None:
        if self.nodes.queued(node, seq):
            return
        run = self.schedule.subchain_of(node)
        if run is None:  # pragma: no cover - every scheduled node is in a subchain
            return
        self.nodes.started(node, seq)
        self.gate.enter(node, after_wake(self.engine, self.delays, lambda: self._start(node, seq)))

    def _start(self, node: str, seq: int) -> None:
        """``node``'s run ``seq`` starts now (its executor, if any, is free): it draws and becomes a job; it reads its
        inputs when it first runs (:class:`Reading`)."""
        run = self.schedule.subchain_of(node)
        if run is None:  # pragma: no cover - every scheduled node is in a subchain
            return
        flight = self.states[run.name].in_flight.get(seq)
        index = flight.index if flight is not None else run.nodes.index(node)
        threads, speedup = run.threads_of(index)
        compute = self.sample(node, self.engine.now / 1000.0)
        if not run.shared:
            priority = DEDICATED
        else:
            priority = RAISED if self.raised.get(run.cores[0]) == run.name else RESTING_SHARED
        reading = Reading(self.engine, self.flow, node)

        def done(job: Job) -> None:
            self._done(job, seq, reading.origins, compute)

        work = self.delays.before_run_ms + compute / speedup
        job = Job(node, work, threads, priority, 0, done, on_start=reading.read)
        self.engine.submit(self.pools[run.name], job)

    def _done(self, job: Job, seq: int, origins: Origins, compute_ms: float) -> None:
        node = job.node
        if self.measurements is not None:
            around = self.delays.before_run_ms + self.delays.after_run_ms if self.delays.charged else 0.0
            self.measurements.record(node, compute_ms + around)
        self.flow.produce(node, origins, self.engine.now)
        run = self.schedule.subchain_of(node)

        def release() -> None:
            self.gate.leave(node)
            self._free(node)

        pool = self.pools.get(run.name) if run is not None else None
        if pool is None:  # pragma: no cover - every scheduled node is in a subchain
            release()
        else:
            after_run(self.engine, pool, self.delays, job, release)
        if run is None:  # pragma: no cover
            return
        state = self.states[run.name]
        handoff = state.node_done(seq, len(run.nodes))
        if handoff is None:
            return
        if handoff.next_index is not None:
            self._trigger(run.nodes[handoff.next_index], seq)
        else:
            state.over(handoff.flight, self.engine.now, run.late_after_ms)
        if handoff.head_done:  # a trigger that came while the head ran starts its run now
            pending = state.start_pending(Flight(0, self.engine.now))
            if pending is not None:
                self._trigger(run.nodes[0], pending)

    def _free(self, node: str) -> None:
        waiting = self.nodes.free(node)
        if waiting is not None:
            self._trigger(node, waiting)

    # -------------------------------------------------------------- re-solving

    def _reoptimise(self) -> None:
        assert self.reoptimiser is not None
        after, reinstall, next_ms = self.reoptimiser.step(self.engine.now, self.schedule)
        if reinstall:
            self._install(after)  # new cores, or a subchain now clock- instead of slot-triggered
        else:
            self.schedule = after  # slots and periods take effect from the next period or trigger
        self.engine.at(next_ms, self._reoptimise)

    @property
    def replans(self) -> list[Replan]:
        return [] if self.reoptimiser is None else self.reoptimiser.replans


class Reoptimiser:
    """The periodic re-solve of ``catanc run``: Stage II every ``stage2_every_s``, Stage I every ``stage1_every_s``,
    from the p95s of the compute times recorded since the start."""

    def __init__(self, spec: Spec, replanner: Replanner) -> None:
        self.spec, self.replanner = spec, replanner
        self.measurements = Measurements.for_spec(spec)
        self.cadence = Cadence.start(spec.runtime)
        self.first_ms = self.cadence.next_ms()
        self.replans: list[Replan] = []

    def step(self, now: float, before: RuntimeSchedule) -> tuple[RuntimeSchedule, bool, float]:
        """Re-solve now: the new schedule, whether it must be installed afresh, and when to re-solve next."""
        stage = self.cadence.due(now) or "stage2"
        self.cadence.solved(stage, now)
        estimates = self.measurements.estimates(measured_only=True)
        plan = self.replanner.reallocate(estimates or None) if stage == "stage1" else self.replanner.resolve(estimates)
        after = runtime_schedule(plan, self.replanner.problem, self.spec.schedule)
        replan = replanned(before, after)
        self.replans.append(Replan(now / 1000.0, stage, replan.moved, plan.objective))
        return after, replan.reinstall, self.cadence.next_ms()


class TimerPolicy:
    """The hand-tuned baseline: listed nodes on their own timers, the rest on new input; CFS or static FIFO."""

    def __init__(
        self,
        engine: Engine,
        flow: Dataflow,
        *,
        spec: Spec,
        cores: int,
        sample: Sampler,
        discipline: Discipline,
        priorities: dict[str, int],
        delays: Delays = NO_DELAYS,
    ) -> None:
        self.engine, self.flow, self.spec, self.sample = engine, flow, spec, sample
        self.priorities = priorities
        self.delays = delays
        self.pool = Pool("all", tuple(range(cores)), discipline)
        engine.pools = [self.pool]
        self.rules = trigger_rules(spec, "simulate")
        self.triggers = Triggers(self.rules)
        self.gate = ExecutorGate(spec)
        flow.listeners.append(self._on_output)

    def start(self) -> None:
        for name, period_ms in sorted(self.rules.timers.items()):
            self._timer(name, period_ms, 0.0)

    def busy_by_core(self) -> dict[int, float]:
        share = self.pool.busy_core_ms / len(self.pool.cores)
        return dict.fromkeys(self.pool.cores, share)

    def _timer(self, node: str, period_ms: float, due_ms: float) -> None:
        def fire() -> None:
            self._begin(self.triggers.fire(node))
            self._timer(node, period_ms, due_ms + period_ms)

        self.engine.at(due_ms, fire)

    def _on_output(self, node: str, _now_ms: float) -> None:
        self._begin(self.triggers.output(node))

    def _begin(self, nodes: list[str]) -> None:
        for node in nodes:  # a busy node's trigger waited (a depth-1 queue), the rest start now
            self.gate.enter(node, after_wake(self.engine, self.delays, functools.partial(self._start, node)))

    def _start(self, node: str) -> None:
        compute = self.sample(node, self.engine.now / 1000.0)
        reading = Reading(self.engine, self.flow, node)

        def release() -> None:
            self.gate.leave(node)
            self._begin(self.triggers.free(node))

        def done(job: Job) -> None:
            self.flow.produce(node, reading.origins, self.engine.now)  # its output triggers its successors
            after_run(self.engine, self.pool, self.delays, job, release)

        work = self.delays.before_run_ms + compute
        job = Job(node, work, 1, self.priorities.get(node, 0), 0, done, on_start=reading.read)
        self.engine.submit(self.pool, job)
