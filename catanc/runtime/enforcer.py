"""``catanc run``: apply a plan on a live Linux system and keep it right as compute times drift.

The enforcer (catan-model.md sections 5 and 6) is a handful of threads
around one mutable state, each with one job:

- the *receiver* (SCHED_FIFO 4) takes registrations and completions from
  the nodes (:mod:`catanc.runtime.protocol`), pins a node's threads as the
  plan says, records compute times and triggers the next node of a
  subchain when the previous one is done;
- the *clock* (FIFO 4) triggers dedicated subchains, and shared ones that
  run on their own clock, every planned period;
- one *core scheduler* per shared core (FIFO 4, pinned there) runs the
  periodic schedule: in order, it raises the owner of each slot (the slot's
  subchain, or a late one of higher priority) to FIFO 2 for its slice and
  puts it back to FIFO 1, triggering slot-aligned subchains every ``n``
  periods; the rest of the period is slack;
- the *re-optimiser* (SCHED_OTHER) re-solves Stage II every
  ``stage2_every_s`` and both stages every ``stage1_every_s`` or when the
  process's CPU set changes, with the measured p95 compute times, and
  swaps the new schedule in; the core schedulers restart when the
  allocation changes.

Every thread the enforcer changes is remembered first; they all get their
policy, priority and affinity back on exit (and from the watchdog process
if the enforcer is killed).
"""

from __future__ import annotations

import gc
import heapq
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from catanc.artifacts.runtime_table import RuntimeTable
from catanc.control import flights
from catanc.control.schedule import (
    CoreSchedule,
    RuntimeSchedule,
    SubchainRun,
    is_late,
    node_priority,
    slot_owner,
    triggers_at_slot,
)
from catanc.core.priorities import APP_FIFO_LEVELS, ENFORCER_FIFO, RUNNING_FIFO
from catanc.runtime import protocol
from catanc.runtime.log import RunLog
from catanc.runtime.measure import Measurements, OpenCpuClocks, cpu_ms, percentile, reconcile
from catanc.runtime.planning import Answer, PlannerProcess, Request
from catanc.runtime.sched import (
    SCHED_RESET_ON_FORK,
    Restorer,
    ThreadGone,
    allowed_cpus,
    name_thread,
    read_policy,
    set_affinity,
    set_fifo,
    threads_of,
)

Start = Literal["bootstrap", "spec"]

RECEIVE_TIMEOUT_S = 0.05
CPU_WATCH_S = 1.0
SWITCH_INTERVAL_S = 0.0002
"""The interpreter lock passes to a waking FIFO-4 thread within this (Python's default: 5 ms)."""
STATUS_EVERY_S = 1.0
RATE_WINDOW = 20
"""A subchain's measured rate is over its last 20 trigger-to-trigger periods."""
KERNEL_CHECK_EVERY = 8
"""Every 8th run, a node's reported compute time is checked against the kernel's (two /proc reads)."""
SWITCH_SAMPLES = 2000
"""Switch latencies kept per shared core: scheduled switch time to the slot owner raised (and triggered)."""
STOP_CHECK_MS = 50.0
"""A core scheduler's longest sleep before it looks whether the run is stopping."""
LOST_AFTER = 20.0
"""A run not done after this many planned latencies (and at least a second) is given up as lost."""
LOST_CHECK_MS = 100.0
"""How often runs in flight are looked at for lost ones."""


def now_ms() -> float:
    return time.monotonic_ns() / 1e6


@dataclass
class Endpoint:
    """One registered node thread."""

    node: str
    pid: int
    tid: int
    address: Any


@dataclass
class Flight(flights.Flight):
    """One run of a subchain in flight, with what measures its running node."""

    cpu_ns: int | None  # the running node thread's CPU time when it was triggered (schedstat)
    speedup: float = 1.0  # the running node's speedup with the threads its trigger gave it


@dataclass
class SubchainState(flights.Flights[Flight]):
    """Runs of one subchain in flight, and what was seen of them (``skipped`` also counts the triggers not
    sent because a node of the subchain is not registered yet)."""

    last_trigger_ms: float | None = None
    periods_ms: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))  # trigger to trigger
    lost: int = 0
    steals: int = 0


class Enforcer:
    """One app's enforcer; :meth:`run` blocks until ``stop()`` or the duration ends."""

    def __init__(
        self,
        table: RuntimeTable,
        *,
        socket_path: str,
        rt: bool = True,
        start: Start = "bootstrap",
        log_path: str | Path | None = None,
        cores: int | None = None,
        restorer: Restorer | None = None,
        clock: Callable[[], float] = now_ms,
    ) -> None:
        self.table = table
        self.spec = table.spec
        self.rt = rt
        self.log_path = log_path
        self.log: RunLog | None = None  # opened once the socket is ours: never truncate another run's log
        self.clock = clock
        self.socket_path = socket_path
        self.restorer = restorer if restorer is not None else Restorer()
        self.measurements = Measurements.for_spec(self.spec)
        self.cpu_clocks = OpenCpuClocks()  # node threads' kernel CPU counts (read under self.lock)
        bootstrap = self.spec.runtime.bootstrap_ms if start == "bootstrap" else None
        self.cpu_ids = sorted(allowed_cpus())  # plan core i runs on the i-th CPU this process may use
        self.events: list[str] = []  # short notes for the live status (node crashed, ...)
        planned_cores = self._fit_cores(cores or table.cores)
        self.planner = PlannerProcess(
            table.spec.model_dump(mode="json", by_alias=True), planned_cores, bootstrap_ms=bootstrap
        )
        self.answer: Answer = self.planner.initial
        self.lock = threading.RLock()  # guards the schedule, endpoints and subchain states
        self.schedule: RuntimeSchedule = self.answer.schedule
        self.generation = 0  # bumped when the allocation changes: core schedulers restart
        self.endpoints: dict[str, list[Endpoint]] = {}
        self.states = {name: SubchainState() for name in self.schedule.subchains}
        self.raised: dict[int, str | None] = {}  # core -> subchain raised to FIFO 2 now
        self.core_threads: list[threading.Thread] = []
        self.switches: dict[int, deque[float]] = {}  # core -> recent switch latencies (ms)
        self.nodes = flights.NodeQueues()  # the run each node was triggered for and has not finished
        self.stopping = threading.Event()
        self.requested_cores: int | None = None
        self.last_resolve_s: float | None = None
        self.started_ms = clock()
        self.preexisting: dict[int, set[int]] = {}  # pid -> its threads when a node of it registered

    # ------------------------------------------------------------------ lifecycle

    def run(
        self,
        duration_s: float | None = None,
        *,
        on_start: Callable[[Enforcer], None] | None = None,
        on_tick: Callable[[Enforcer], None] | None = None,
    ) -> None:
        """Enforce until :meth:`stop`, SIGINT/SIGTERM or ``duration_s``.

        ``on_start`` runs once the socket is bound (start the app's processes there); ``on_tick``
        about every 0.2 s (a live status).  Call from the main thread: it installs the restorer's
        signal handlers and runs at FIFO 4 itself, so a restore on SIGINT is never starved.
        """
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        # SIGTERM (systemd, docker) ends the run as SIGINT does: nodes stopped, log closed, summary.
        # The restorer, installed next, puts the threads back first and then calls this.
        previous_term = signal.signal(signal.SIGTERM, self._on_sigterm)
        try:
            self._run(duration_s, on_start=on_start, on_tick=on_tick)
        finally:
            signal.signal(signal.SIGTERM, previous_term)

    def _run(
        self,
        duration_s: float | None,
        *,
        on_start: Callable[[Enforcer], None] | None,
        on_tick: Callable[[Enforcer], None] | None,
    ) -> None:
        with protocol.EnforcerSocket(self.socket_path) as sock, self.restorer:
            self.sock = sock
            if self.log_path is not None:
                self.log = RunLog(self.log_path)
            self._raise_self(cpus=None)
            self._log("start", cores=self.schedule.cores, plan=self.answer.summary)
            threads = [
                threading.Thread(target=self._receiver, name="catanc-receiver", daemon=True),
                threading.Thread(target=self._clock_loop, name="catanc-clock", daemon=True),
                threading.Thread(target=self._reoptimiser, name="catanc-reoptimiser", daemon=True),
            ]
            try:  # whatever fails from here on (a --launch command, say), every thread is stopped first
                for thread in threads:
                    thread.start()
                self._start_core_schedulers()
                if on_start is not None:
                    on_start(self)
                gc.freeze()  # start-up's objects never need collecting: later collections stay short
                deadline = None if duration_s is None else time.monotonic() + duration_s
                next_status = time.monotonic() + STATUS_EVERY_S
                while not self.stopping.is_set():
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        break
                    self.stopping.wait(0.2 if remaining is None else min(0.2, remaining))
                    if on_tick is not None:
                        on_tick(self)
                    if time.monotonic() >= next_status:
                        next_status += STATUS_EVERY_S
                        self._adopt_spawned()
                        self._log("status", **self.status())
                        if self.log is not None:
                            self.log.flush()
            finally:
                self.stopping.set()
                for thread in [*threads, *self.core_threads]:  # no slot may raise a thread after this
                    if thread.ident is not None:
                        thread.join(timeout=2.0)
                self._stop_nodes()
                self._await_last_runs(protocol.STOP_GRACE_S)
                with self.lock:
                    self.cpu_clocks.close()
                self.planner.close()
                if self.log is not None:
                    self.log.flush()  # the last second's samples before the stop line
                self._log("stop", summary=self.status())
                if self.log is not None:
                    log, self.log = self.log, None
                    log.close()

    def stop(self) -> None:
        self.stopping.set()

    def _on_sigterm(self, signum: int, frame: object) -> None:  # noqa: ARG002 - a signal handler's signature
        self.stop()

    def _stop_nodes(self) -> None:
        """Tell every registered node the run is over (their loops end; they are not killed)."""
        with self.lock:
            endpoints = [e for es in self.endpoints.values() for e in es if e.address is not None]
        for endpoint in endpoints:
            self.sock.send(protocol.Stop(), endpoint.address)

    def _await_last_runs(self, grace_s: float) -> None:
        """Keep the socket open, at most ``grace_s``, until every node busy with a run has reported it.

        A node in the middle of a run when the run ends still sends its done message (then
        sees the Stop); with the socket gone it would fail there ("lost the catanc enforcer")
        instead of ending cleanly.  Nothing new is triggered: the run is over.
        """
        deadline = time.monotonic() + grace_s
        while (remaining := deadline - time.monotonic()) > 0:
            with self.lock:
                if not self.nodes.any_busy():
                    return
            got = self.sock.receive(min(remaining, RECEIVE_TIMEOUT_S))
            if got is not None and isinstance(got[0], protocol.Done | protocol.Bye):
                with self.lock:
                    self.nodes.free(got[0].node)  # what waited for it is not triggered: the run is over

    # ------------------------------------------------------------------ registration and completion

    def _receiver(self) -> None:
        self._raise_self(cpus=None)
        checked_ms = self.clock()
        while not self.stopping.is_set():
            got = self.sock.receive(RECEIVE_TIMEOUT_S)  # skips and counts garbage datagrams
            if self.clock() - checked_ms >= LOST_CHECK_MS:  # also under steady traffic, which never times out
                checked_ms = self.clock()
                self._check_lost()
            if got is None:
                continue
            message, address = got
            if isinstance(message, protocol.Hello):
                self._register(message, address)
            elif isinstance(message, protocol.Done):
                self._done(message)
            elif isinstance(message, protocol.Bye):
                self._unregister(message.node, message.tid)
            elif isinstance(message, protocol.SetCores):
                self.requested_cores = message.cores

    def _register(self, hello: protocol.Hello, address: Any) -> None:
        if hello.node not in self.spec.nodes:
            self.sock.send(protocol.Reject(hello.node, f"no node {hello.node!r} in app {self.spec.app}"), address)
            return
        endpoint = Endpoint(hello.node, hello.pid, hello.tid, address)
        before = threads_of(hello.pid)  # read before the thread is raised: what it starts later inherits
        with self.lock:
            self.preexisting.setdefault(hello.pid, set()).update(before)
            self.endpoints.setdefault(hello.node, []).append(endpoint)
            self._place(endpoint)
        self.sock.send(protocol.Welcome(hello.node), address)
        self._log("register", node=hello.node, pid=hello.pid, tid=hello.tid)

    def _unregister(self, node: str, tid: int) -> None:
        with self.lock:
            self.endpoints[node] = [e for e in self.endpoints.get(node, []) if e.tid != tid]
            self.cpu_clocks.forget(tid)

    def _place(self, endpoint: Endpoint) -> None:
        """Pin a node thread to its subchain's cores at its resting priority (rates only without RT)."""
        run = self.schedule.subchain_of(endpoint.node)
        cores = run.cores if run is not None else range(self.schedule.cores)
        cpus = self.cpus_of(cores)
        try:
            self.restorer.remember(endpoint.tid)
            set_affinity(endpoint.tid, cpus)
            if self.rt:
                set_fifo(endpoint.tid, node_priority(run))
        except ThreadGone:
            self._gone(endpoint)

    def _adopt_spawned(self) -> None:
        """Remember threads that node threads started after being raised, so they are put back too.

        A new thread inherits its creator's SCHED_FIFO priority and CPUs (a multi-threaded node's
        helpers, say).  Their own original is unknowable; they get their creator's.  Threads that
        the app raised itself are left alone (see below).  Looked for
        once a second: one started less than a second before the enforcer is SIGKILLed stays as
        it is.  Threads the process had when its node registered are its own business.
        """
        known = self.restorer.remembered
        with self.lock:
            creators = {e.pid: e.tid for endpoints in self.endpoints.values() for e in endpoints if e.tid in known}
            preexisting = {pid: set(tids) for pid, tids in self.preexisting.items()}
        for pid, creator in creators.items():
            for tid in threads_of(pid):
                if tid in known or tid in preexisting.get(pid, ()):
                    continue
                try:
                    now = read_policy(tid)
                    if now.policy & ~SCHED_RESET_ON_FORK == os.SCHED_FIFO and now.priority in APP_FIFO_LEVELS:
                        self.restorer.remember(tid, original=known[creator])
                except ThreadGone:
                    continue

    def cpus_of(self, cores: Iterable[int]) -> frozenset[int]:
        """The CPUs of plan cores: core ``i`` is the ``i``-th allowed CPU (a cpuset {2, 3} runs cores 0, 1 there)."""
        ids = self.cpu_ids
        return frozenset(ids[core % len(ids)] for core in cores)

    def _gone(self, endpoint: Endpoint) -> None:
        self._unregister(endpoint.node, endpoint.tid)
        self._note(f"{endpoint.node}: thread {endpoint.tid} exited")
        self._log("gone", node=endpoint.node, tid=endpoint.tid)

    def _done(self, done: protocol.Done) -> None:
        run = self.schedule.subchain_of(done.node)
        with self.lock:
            state = self.states.get(run.name) if run is not None else None
            flight = state.in_flight.get(done.seq) if state is not None else None
            kernel_ms = self._cpu_ms_since(done.node, done.tid, flight)
        compute = kernel_ms if done.compute_ms is None else reconcile(done.compute_ms, kernel_ms)
        if compute is not None and flight is not None:
            compute *= flight.speedup  # a run on q threads: back to the one-thread time the planner budgets
        if compute is not None and done.node in self.measurements.nodes:
            self.measurements.record(done.node, compute)
        self._sample("compute", done.node, (compute, done.compute_ms, kernel_ms))
        if run is None or state is None or flight is None:
            with self.lock:
                self._free(done.node)
            return  # an unscheduled node, a run given up as lost, or one from before a re-plan
        with self.lock:
            self._free(done.node)
            handoff = state.node_done(done.seq, len(run.nodes))
            if handoff is None:
                return  # given up as lost while the lock was free
            if handoff.next_index is not None:
                self._trigger(run.nodes[handoff.next_index], done.seq)
            if handoff.head_done:  # a trigger that came while it ran: the next run starts now
                pending = state.start_pending(Flight(0, self.clock(), None))
                if pending is not None:
                    self._trigger(run.nodes[0], pending)
            if handoff.next_index is not None:
                return
            latency = state.over(handoff.flight, self.clock(), run.latency_ms)
        self._sample("run", run.name, (done.seq, latency))

    def _cpu_ns(self, node: str) -> int | None:
        """The CPU time (ns) of ``node``'s thread so far, from the kernel; None if unreadable."""
        endpoint = next(iter(self.endpoints.get(node, [])), None)
        if endpoint is None:
            return None
        try:
            return self.cpu_clocks.read_ns(endpoint.pid, endpoint.tid)
        except (OSError, ValueError):
            return None

    def _cpu_ms_since(self, node: str, tid: int, flight: Flight | None) -> float | None:
        endpoint = next((e for e in self.endpoints.get(node, []) if e.tid == tid), None)
        if flight is None or flight.cpu_ns is None or endpoint is None:
            return None
        try:
            return cpu_ms(flight.cpu_ns, self.cpu_clocks.read_ns(endpoint.pid, endpoint.tid))
        except (OSError, ValueError):
            return None

    def _check_lost(self) -> None:
        now = self.clock()
        with self.lock:
            for name, state in self.states.items():
                run = self.schedule.subchains.get(name)
                limit = max(1000.0, LOST_AFTER * (run.latency_ms if run else 1000.0))
                for seq, flight in list(state.in_flight.items()):
                    if now - flight.triggered_ms > limit:
                        del state.in_flight[seq]
                        state.lost += 1
                        node = run.nodes[flight.index] if run else "?"
                        if self.nodes.busy_with(node) == seq:
                            self._free(node)
                        self._note(f"{name}: run {seq} lost at {node} (no answer in {limit / 1000:.1f} s)")
                        self._log("lost", subchain=name, seq=seq, node=node)

    # ------------------------------------------------------------------ triggering

    def _trigger_head(self, run: SubchainRun) -> None:
        now = self.clock()
        with self.lock:
            state = self.states[run.name]
            # A run starts only when every node of it can be triggered: one started while a later
            # node is still starting up would stall there and be given up as lost.
            if any(self._speaker(node) is None for node in run.nodes):
                state.skipped += 1
                return
            # Never queue triggers on a busy head (they would pile up in its socket): defer.
            started = state.start(Flight(0, now, None))
            if started is None or started.deferred:  # sent when the head is done (at its done message)
                return
            seq = started.seq
            if state.last_trigger_ms is not None:
                state.periods_ms.append(now - state.last_trigger_ms)
            state.last_trigger_ms = now
            self._trigger(run.nodes[0], seq)

    def _speaker(self, node: str) -> Endpoint | None:
        """``node``'s first thread registered through the client (attached ones run on their own timers)."""
        return next((endpoint for endpoint in self.endpoints.get(node, []) if endpoint.address is not None), None)

    def _trigger(self, node: str, seq: int) -> None:
        """Trigger ``node`` for run ``seq`` now, or once it has finished the run it is busy with.

        A node is never sent a second trigger while it runs: a pipelined subchain's runs
        queue here, one per stage at most, instead of piling up in the node's socket.
        """
        if self.nodes.queued(node, seq):
            return
        endpoint = self._speaker(node)
        if endpoint is None:
            return
        run = self.schedule.subchain_of(node)
        flight = self.states[run.name].in_flight.get(seq) if run is not None else None
        threads = 1
        if run is not None and flight is not None:
            threads, flight.speedup = run.threads_of(flight.index)
            if seq % KERNEL_CHECK_EVERY == 0:
                flight.cpu_ns = self._cpu_ns(node)
        if self.sock.send_bytes(protocol.trigger_datagram(node, seq, threads), endpoint.address):
            self.nodes.started(node, seq)
        else:
            self._gone(endpoint)

    def _free(self, node: str) -> None:
        """``node`` finished its run: start the next one queued for it, if any."""
        waiting = self.nodes.free(node)
        if waiting is not None:
            self._trigger(node, waiting)

    def attach(self, node: str, pid: int, tids: list[int]) -> None:
        """Pin and prioritise the threads of a process that does not speak the protocol, as ``node``'s."""
        with self.lock:
            for tid in tids:
                endpoint = Endpoint(node, pid, tid, None)
                self.endpoints.setdefault(node, []).append(endpoint)
                self._place(endpoint)

    def _clock_loop(self) -> None:
        self._raise_self(cpus=None)
        generation = -1
        heap: list[tuple[float, str]] = []
        while not self.stopping.is_set():
            with self.lock:
                if generation != self.generation:  # a new plan: restart every clock from now
                    generation = self.generation
                    start = self.clock()
                    heap = [(start, run.name) for run in self.schedule.clocked]
                    heapq.heapify(heap)
                schedule = self.schedule
            if not heap:
                self.stopping.wait(0.1)
                continue
            due, name = heap[0]
            wait_ms = due - self.clock()
            if wait_ms > 0:
                self.stopping.wait(min(wait_ms / 1000.0, 0.1))
                continue
            heapq.heappop(heap)
            run = schedule.subchains.get(name)
            if run is None:
                continue
            self._trigger_head(run)
            heapq.heappush(heap, (max(due + run.period_ms, self.clock()), name))

    # ------------------------------------------------------------------ shared cores

    def _start_core_schedulers(self) -> None:
        with self.lock:
            generation = self.generation
            cores = self.schedule.shared
        for core in cores:
            thread = threading.Thread(
                target=self._core_loop, args=(core, generation), name=f"catanc-core-{core.core}", daemon=True
            )
            thread.start()
            self.core_threads.append(thread)

    def _core_loop(self, core: CoreSchedule, generation: int) -> None:
        self._raise_self(cpus=self.cpus_of([core.core]))
        period_index = 0
        start = self.clock()
        while not self.stopping.is_set() and generation == self.generation:
            with self.lock:
                core = next((c for c in self.schedule.shared if c.core == core.core), core)
                runs = self.schedule.subchains
            period_start = start
            for slot in core.slots:
                switch_at = period_start + slot.start_ms - core.switch_ms  # the switch is budgeted before the slice
                self._sleep_until(switch_at)
                if self.stopping.is_set() or generation != self.generation:
                    break
                late = self._late_on(core, runs)
                owner = slot_owner(slot, core, runs, late)
                if owner != slot.subchain:
                    self.states[owner].steals += 1
                self._raise(core.core, owner)
                if triggers_at_slot(runs[slot.subchain], period_index):
                    self._trigger_head(runs[slot.subchain])
                self.switches.setdefault(core.core, deque(maxlen=SWITCH_SAMPLES)).append(self.clock() - switch_at)
                self._sleep_until(period_start + slot.start_ms + slot.length_ms)
            if self.stopping.is_set():
                break
            self._raise(core.core, None)
            start = period_start + core.period_ms
            behind = self.clock() - start
            if behind > core.period_ms:  # fell a whole period behind (e.g. suspended): resume from now
                start += behind
            self._sleep_until(start)
            period_index += 1
        self._raise(core.core, None)

    def _late_on(self, core: CoreSchedule, runs: Mapping[str, SubchainRun]) -> set[str]:
        now = self.clock()
        late = set()
        with self.lock:
            for slot in core.slots:
                if is_late(self.states[slot.subchain].oldest_ms(), now, runs[slot.subchain]):
                    late.add(slot.subchain)
        return late

    def _raise(self, core: int, owner: str | None) -> None:
        """Put the previous owner of ``core`` back to FIFO 1 and raise ``owner`` to FIFO 2."""
        if not self.rt:
            return
        with self.lock:
            previous = self.raised.get(core)
            if previous == owner:
                return
            self.raised[core] = owner
            resting = node_priority(self.schedule.subchains.get(previous or ""))
            for name, level in ((previous, resting), (owner, RUNNING_FIFO)):
                if name is None or name not in self.schedule.subchains:
                    continue
                for node in self.schedule.subchains[name].nodes:
                    for endpoint in list(self.endpoints.get(node, [])):
                        try:
                            set_fifo(endpoint.tid, level)
                        except ThreadGone:
                            self._gone(endpoint)

    def _sleep_until(self, when_ms: float) -> None:
        """Sleep until ``when_ms``, looking at least every 50 ms whether the run stops (so no slot outlives it).

        ``time.sleep`` rather than ``Event.wait``: a slot switch is the enforcer's most frequent
        wake-up, and a plain sleep costs a quarter less CPU per wake (no lock made and waited on).
        """
        delay = when_ms - self.clock()
        while delay > 0 and not self.stopping.is_set():
            time.sleep(min(delay, STOP_CHECK_MS) / 1000.0)
            delay = when_ms - self.clock()

    def _raise_self(self, cpus: frozenset[int] | None) -> None:
        """The calling enforcer thread: FIFO 4 (with RT), pinned to ``cpus`` if given."""
        if threading.current_thread() is not threading.main_thread():  # the main thread's name is the process's
            name_thread(threading.current_thread().name)
        tid = threading.get_native_id()
        if cpus is not None:
            os.sched_setaffinity(tid, cpus)
        if self.rt:  # processes it starts (--demo workers) must not inherit FIFO 4: reset on fork
            os.sched_setscheduler(tid, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(ENFORCER_FIFO))

    # ------------------------------------------------------------------ re-optimising

    def _reoptimiser(self) -> None:
        name_thread(threading.current_thread().name)
        if self.rt:  # started by the FIFO-4 main thread: back to SCHED_OTHER (catan-model section 6)
            os.sched_setscheduler(threading.get_native_id(), os.SCHED_OTHER, os.sched_param(0))
        runtime = self.spec.runtime
        begin = time.monotonic()
        next_stage2 = begin + runtime.first_solve_after_s
        next_stage1 = begin + runtime.first_solve_after_s + runtime.stage1_every_s
        next_cpu_check = begin + CPU_WATCH_S
        known_cpus = allowed_cpus()
        while not self.stopping.wait(0.05):
            now = time.monotonic()
            cores = None
            if self.requested_cores is not None:
                cores, self.requested_cores = self.requested_cores, None
            moved = False
            if now >= next_cpu_check:
                next_cpu_check = now + CPU_WATCH_S
                cpus = allowed_cpus()
                if cpus != known_cpus:
                    known_cpus, moved = cpus, True
                    self.cpu_ids = sorted(cpus)
                    cores = len(cpus)
            if cores is not None:
                cores = self._fit_cores(cores)
            if cores is not None and cores != self.schedule.cores:
                self._replan(stage1=True, cores=cores, reason="cores")
                next_stage1 = now + runtime.stage1_every_s
            elif moved:  # as many CPUs, but others: the same plan, pinned to them
                with self.lock:
                    self._repin_locked()
                self._start_core_schedulers()
                self._log("repin", cpus=self.cpu_ids)
            elif now >= next_stage1:
                self._replan(stage1=True, cores=None, reason="stage1")
                next_stage1 = now + runtime.stage1_every_s
                next_stage2 = now + runtime.stage2_every_s
            elif now >= next_stage2:
                self._replan(stage1=False, cores=None, reason="stage2")
                next_stage2 = now + runtime.stage2_every_s

    def _fit_cores(self, cores: int) -> int:
        """``cores``, or fewer if this process may use fewer CPUs: two plan cores never share one CPU."""
        if cores <= len(self.cpu_ids):
            return cores
        self._note(
            f"planning for {len(self.cpu_ids)} core(s), not {cores}: this process may use only CPUs {self.cpu_ids}"
        )
        return len(self.cpu_ids)

    def _repin_locked(self) -> None:
        """Stop the core schedulers (they restart with :meth:`_start_core_schedulers`) and re-pin every node thread.

        Call with ``self.lock`` held, in the same hold as the schedule change, so no scheduler
        runs a new schedule under an old generation.
        """
        self.generation += 1
        self.raised.clear()
        for endpoints in self.endpoints.values():
            for endpoint in endpoints:
                self._place(endpoint)

    def _replan(self, *, stage1: bool, cores: int | None, reason: str) -> None:
        # Nodes not measured yet keep the planner's current time (bootstrap or the spec's).
        estimates = self.measurements.estimates(measured_only=True)
        answer = self.planner.ask(Request("reallocate" if stage1 else "resolve", estimates, cores))
        self.last_resolve_s = self.elapsed_s()
        if answer.error is not None:
            self._note(f"re-plan failed, keeping the last plan: {answer.error}")
        with self.lock:
            changed = answer.layout != self.answer.layout
            self.answer = answer
            self.schedule = answer.schedule
            for name in self.schedule.subchains:
                self.states.setdefault(name, SubchainState())
            if changed:
                self._repin_locked()
        if changed:
            self._start_core_schedulers()
        self._log(
            "resolve",
            reason=reason,
            stage1=stage1,
            allocation_changed=changed,
            solve_ms=round(answer.solve_ms, 3),
            error=answer.error,
            compute_ms={k: round(v, 3) for k, v in sorted(estimates.items())},
            plan=answer.summary,
        )

    # ------------------------------------------------------------------ observing

    def elapsed_s(self) -> float:
        return (self.clock() - self.started_ms) / 1000.0

    def status(self) -> dict[str, Any]:
        """Per subchain: planned and measured rate, p95 compute, late, lost, steals; for the live view and the log."""
        estimates = self.measurements.estimates()
        rows = {}
        with self.lock:
            for name, run in sorted(self.schedule.subchains.items()):
                state = self.states[name]
                periods = state.periods_ms
                measured = 1000.0 * len(periods) / sum(periods) if periods and sum(periods) > 0 else None
                rows[name] = {
                    "planned_hz": round(1000.0 / run.period_ms, 3),
                    "measured_hz": None if measured is None else round(measured, 3),
                    "compute_p95_ms": round(sum(estimates.get(node, 0.0) for node in run.nodes), 3),
                    "late": state.late,
                    "lost": state.lost,
                    "steals": state.steals,
                    "skipped": state.skipped,
                    "registered": all(self.endpoints.get(node) for node in run.nodes),
                }
        since = None if self.last_resolve_s is None else self.elapsed_s() - self.last_resolve_s
        switches = {}
        for core, samples in sorted(self.switches.items()):
            if samples:
                switches[str(core)] = {
                    "p50_ms": round(percentile(samples, 50), 4),
                    "p95_ms": round(percentile(samples, 95), 4),
                    "max_ms": round(max(samples), 4),
                }
        return {
            "subchains": rows,
            "last_resolve_s": self.last_resolve_s,
            "since_resolve_s": since,
            "switches": switches,
        }

    def _note(self, text: str) -> None:
        self.events = [*self.events[-9:], text]

    def _log(self, event: str, **fields: Any) -> None:
        if self.log is not None:
            self.log.write(event, (self.clock() - self.started_ms) / 1000.0, fields)

    def _sample(self, event: str, key: str, values: tuple[Any, ...]) -> None:
        if self.log is not None:
            self.log.sample(event, (self.clock() - self.started_ms) / 1000.0, key, values)
