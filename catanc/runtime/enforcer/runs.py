"""The enforcer's runs in flight, learnt from the nodes' rings: what each run did, checked and clamped.

Heads are triggered by the enforcer; every later node is woken by the one before it and
records its run in its ring (:mod:`catanc.runtime.protocol.ring`), which the enforcer reads when it
wakes up anyway.  :class:`RunBook` turns those entries into the rules of
:mod:`catanc.control.flights` (runs in flight, hand-offs, deferred head triggers, late runs)
and into samples: each node's compute time, each run's latency, each hop's delay.

Nothing a node writes is trusted (issue: a forged completion must not wreck the plan):

- an entry counts only if its seq is a run in flight *at that node* (a seq of 0, a run that
  no trigger started, such as a ROS subscription callback, is the run its data came from: the
  latest waiting there that was triggered before the entry's origin, the time its data was
  sensed; without an origin, the oldest waiting there); anything else is counted as unmatched
  and dropped.  (Paired oldest-first, one message the middleware dropped left every later run
  of nav2d's LM one run behind: 99% of the local subchain's runs counted late.)
- a compute time is clamped to the time since the run was triggered (one thread cannot use
  more CPU than the wall time it had; a run on several threads reports its wall time), so no
  single report can make a node look slower than the time it really held the run;
- a one-thread run reported at more than :data:`SUSPICIOUS` times its node's planning estimate
  is also clamped to the CPU the kernel counted for the reporting thread since its last such
  check: a node that claims CPU it did not use cannot inflate its slice (a node that really
  uses it gets it planned, as it should);
- the times of an entry are clamped to what the enforcer saw: a run starts no earlier than its
  trigger and ends no later than the moment its entry was read.

A hop is measured while the run's subchain is raised (it started by the end of its slot): later, the
next node waited for the CPU, no cost of the runtime's.  Not so a message's hop into a node that runs
on its input (a ROS subscription, seq 0): the middleware's delivery is the hop the plan must make room
for, whether it ends inside the slot or not (measured only inside, a hop the plan did not yet cover
was never measured, and ``catanc profile`` could not write it).  It is measured where its pairing
is sure: one run waiting at that node, not started behind an earlier run of the subchain.

Every :data:`KERNEL_CHECK_EVERY`-th run of a head is also measured by the kernel (the head
thread's ``schedstat`` at the trigger and when the entry is read) and reconciled with the
node's own figure (:func:`catanc.control.measure.reconcile`), unless the head ran again before
the entry was read (a later entry, or a later trigger): the kernel's figure would count that too.
Nor is a head checked whose thread hosts another node (:func:`kernel_checked`: an executor's one
thread running the head, then its successor before the entry is read): the thread's CPU is not the
head's, and the check would charge it with the other node's.  The bound on a suspicious report
(:meth:`RunBook._kernel_bound`) stays: the thread's CPU is still more than any of its nodes used.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import NamedTuple, TypeGuard

from catanc.control.flights import Flight, Flights, Started
from catanc.control.measure import reconcile
from catanc.control.policy import lost_after_ms
from catanc.control.schedule import SubchainRun, is_late
from catanc.runtime.linux.cpu_clocks import cpu_ms
from catanc.runtime.protocol.endpoints import Endpoint
from catanc.runtime.protocol.ring import Entry, RingReader
from catanc.spec.speedup import threads_and_speedup

KERNEL_CHECK_EVERY = 8
"""Every 8th run of a head is measured by the kernel too (two /proc reads)."""
SUSPICIOUS = 3.0
"""A one-thread run reported at more than 3x its node's planning estimate is checked against the kernel."""
KERNEL_SLACK_MS = 0.05
"""What a kernel bound allows above the kernel's count (its own reading lags a little)."""
RATE_WINDOW_S = 2.0
"""A subchain's measured rate is over its triggers in the last 2 s (or 4 of its periods, if longer)."""


@dataclass(slots=True)
class RunFlight(Flight):
    """One run in flight, with what the enforcer saw of it."""

    last_end_ms: float | None = None  # when its previous node finished (for the hop delay)
    until_ms: float | None = None  # hops that start by then are the runtime's own delay (the subchain was raised)
    kernel_ns: int | None = None  # the head thread's schedstat at the trigger, on checked runs


@dataclass
class SubchainRuns(Flights[RunFlight]):
    """A subchain's runs in flight, and what was seen of them."""

    ends_ms: deque[float] = field(default_factory=lambda: deque(maxlen=512))  # when each of its last runs ended
    lost: int = 0
    steals: int = 0
    unmatched: int = 0


class ComputeSample(NamedTuple):
    at_ms: float  # when the run ended
    node: str
    ms: float | None  # what is planned with (one-thread time), None if unknown
    reported_ms: float | None
    kernel_ms: float | None
    threads: int  # threads the run used (``ms`` is one-thread time)
    age_ms: float | None = None  # its end minus its origin (when its data was sensed), None without one


class RunSample(NamedTuple):
    at_ms: float  # when its last node ended
    subchain: str
    seq: int
    latency_ms: float


class HopSample(NamedTuple):
    subchain: str
    node: str  # the node that started
    delay_ms: float  # the previous node's end (or the head's trigger) to its start
    inside: bool  # a node's end to the next node's start, in one subchain (not the head's trigger to its start)
    after: str = ""  # the node before it in its subchain (its edge's producer); "" after the head's trigger

    @property
    def edge(self) -> tuple[str, str] | None:
        """``(producer, consumer)`` of a hop inside a subchain; None for a head's trigger to its start."""
        return (self.after, self.node) if self.inside and self.after else None


@dataclass
class Seen:
    """What reading the rings found."""

    computes: list[ComputeSample] = field(default_factory=list)
    runs: list[RunSample] = field(default_factory=list)
    hops: list[HopSample] = field(default_factory=list)


KernelClock = Callable[[Endpoint], int | None]
"""A node thread's CPU time so far (ns) from the kernel; None if unreadable."""


class RunBook:
    """Every subchain's runs in flight: started by head triggers, moved on by the nodes' ring entries."""

    def __init__(self, subchains: Iterable[str], speedups: dict[str, tuple[float, ...]], kernel: KernelClock) -> None:
        self.states: dict[str, SubchainRuns] = {name: SubchainRuns() for name in subchains}
        self.speedups = speedups  # node -> its speedup with 1, 2, ... threads
        self.kernel = kernel
        self.expected: dict[str, float] = {}  # node -> its planning estimate (what is suspicious above it)

    def state(self, name: str) -> SubchainRuns:
        state = self.states.get(name)
        if state is None:
            state = self.states[name] = SubchainRuns()
        return state

    def busy(self, name: str) -> bool:
        """Whether ``name`` has a run in flight (or one waiting for its head)."""
        state = self.states.get(name)
        return state is not None and (bool(state.in_flight) or state.pending is not None)

    def late(self, name: str, now_ms: float, run: SubchainRun) -> bool:
        """Whether ``name``'s oldest run in flight is past its planned latency at ``now_ms``."""
        state = self.states.get(name)
        if state is None or not state.in_flight:
            return False
        return is_late(state.oldest_ms(), now_ms, run)

    def trigger(
        self, run: SubchainRun, now_ms: float, head: Endpoint | None, until_ms: float | None = None
    ) -> Started | None:
        """A head trigger of ``run`` now: the seq to send (a deferred one too), or None (nothing to send).

        ``until_ms``: the run's nodes run raised until then (its slot's end; a dedicated subchain's for
        ever), so a hop that starts by then measures the runtime's own delay, not a wait for the CPU;
        unless an earlier run of the subchain is still in flight: its nodes run first, at the same level.
        """
        state = self.state(run.name)
        if state.in_flight:
            until_ms = None
        started = state.start(RunFlight(0, now_ms, until_ms=until_ms))
        if started is None:
            return None
        if not started.deferred and kernel_checked(head) and started.seq % KERNEL_CHECK_EVERY == 0:
            state.in_flight[started.seq].kernel_ns = self.kernel(head)
        return started

    def measured_hz(self, name: str, period_ms: float, now_ms: float) -> float | None:
        """Runs completed per second over the last :data:`RATE_WINDOW_S` (or 4 periods): 0 once a subchain stops.

        Completions, not triggers: a subchain whose node hangs is still triggered (each run is then lost).
        """
        state = self.states.get(name)
        if state is None or not state.ends_ms:
            return None
        window = max(RATE_WINDOW_S * 1000.0, 4.0 * period_ms)
        since = now_ms - window
        count = sum(1 for t in state.ends_ms if t > since)
        first = state.ends_ms[0]
        return 1000.0 * count / min(window, max(now_ms - first, period_ms))

    def read(
        self, run: SubchainRun, readers: Iterable[tuple[int, Endpoint, RingReader]], now_ms: float, seen: Seen
    ) -> None:
        """Take the new entries of ``run``'s nodes' rings (``readers``: node index, thread, ring; in node order)."""
        state = self.state(run.name)
        for index, endpoint, reader in readers:
            if reader.words[2] == reader.last:
                continue
            entries = reader.new()
            last = len(entries) - 1
            for k, entry in enumerate(entries):
                self._take(run, state, index, endpoint=endpoint, entry=entry, now_ms=now_ms, seen=seen, last=k == last)

    def _take(
        self,
        run: SubchainRun,
        state: SubchainRuns,
        index: int,
        *,
        endpoint: Endpoint,
        entry: Entry,
        now_ms: float,
        seen: Seen,
        last: bool = True,
    ) -> None:
        """One ring entry of node ``index`` of ``run``: the run it reports moves on (or it is dropped).

        ``last``: no later entry of the node was read with it (the head's kernel figure, read now,
        then spans no later run of it).
        """
        length = len(run.nodes)
        node = run.nodes[index]
        delivered = False  # a message's hop into a node that runs on its input, from the one run waiting there
        if entry.seq:
            seq = entry.seq
            flight = state.in_flight.get(seq)
            if flight is None or flight.index != index:
                state.unmatched += 1
                return
        else:  # a run nothing triggered: the one its data came from, else the oldest waiting at this node
            waiting = [(f.triggered_ms, s) for s, f in state.in_flight.items() if f.index == index]
            if not waiting:
                state.unmatched += 1
                return
            sensed = [(t, s) for t, s in waiting if entry.origin_ns and t <= entry.origin_ns / 1e6]
            seq = max(sensed)[1] if sensed else min(waiting)[1]
            flight = state.in_flight[seq]
            delivered = index > 0 and (bool(sensed) or len(waiting) == 1)
        start_ms = min(max(entry.start_ns / 1e6, flight.triggered_ms), now_ms)
        end_ms = min(max(entry.end_ns / 1e6, start_ms), now_ms)
        before = flight.last_end_ms if index > 0 else flight.triggered_ms
        if before is not None and flight.until_ms is not None and (delivered or start_ms <= flight.until_ms):
            producer = run.nodes[index - 1] if index > 0 else ""
            seen.hops.append(HopSample(run.name, node, max(start_ms - before, 0.0), index > 0, producer))
        own = entry.compute_ms
        elapsed = max(now_ms - flight.triggered_ms, 0.0)
        compute = None if own is None else min(own, elapsed)
        if compute is not None and entry.threads <= 1 and compute > SUSPICIOUS * self.expected.get(node, compute):
            compute = self._kernel_bound(endpoint, compute)
        kernel_ms = None
        if index == 0 and flight.kernel_ns is not None and last and not _head_again(state, seq):
            after = self.kernel(endpoint)
            if after is not None:
                try:
                    kernel_ms = cpu_ms(flight.kernel_ns, after)
                except ValueError:
                    kernel_ms = None
            compute = kernel_ms if compute is None else reconcile(compute, kernel_ms)
        if compute is not None and entry.threads > 1:
            _, speedup = threads_and_speedup(self.speedups.get(node, (1.0,)), entry.threads)
            compute *= speedup  # a run on q threads: back to the one-thread time the planner budgets
        age_ms = run_age_ms(entry.origin_ns, start_ms if index == 0 else None, end_ms)
        seen.computes.append(ComputeSample(end_ms, node, compute, own, kernel_ms, max(entry.threads, 1), age_ms))
        handoff = state.node_done(seq, length)
        if handoff is None:  # pragma: no cover - matched just above
            return
        flight.last_end_ms = end_ms
        if handoff.next_index is None:
            state.ends_ms.append(end_ms)
            seen.runs.append(RunSample(end_ms, run.name, seq, state.over(handoff.flight, end_ms, run.late_after_ms)))
        if handoff.head_done:  # a trigger that came while the head ran is running since the head finished
            state.start_pending(RunFlight(0, end_ms, until_ms=flight.until_ms if not run.shared else None))

    def _kernel_bound(self, endpoint: Endpoint, compute_ms: float) -> float:
        """``compute_ms``, at most the CPU the kernel counted for the reporting thread since its last such check
        (a run cannot use more CPU than its thread did); the first check only marks where to count from."""
        now = self.kernel(endpoint)
        if now is None:
            return compute_ms
        mark, endpoint.kernel_mark_ns = endpoint.kernel_mark_ns, now
        if mark is None or now < mark:
            return compute_ms
        return min(compute_ms, (now - mark) / 1e6 + KERNEL_SLACK_MS)

    def lost(self, runs: dict[str, SubchainRun], now_ms: float) -> list[tuple[str, int, str]]:
        """Give up runs in flight for too long: ``(subchain, seq, node it was at)`` each."""
        found = []
        for name, state in self.states.items():
            run = runs.get(name)
            limit = lost_after_ms(run)
            for seq, flight in list(state.in_flight.items()):
                if now_ms - flight.triggered_ms > limit:
                    del state.in_flight[seq]
                    state.lost += 1
                    node = run.nodes[flight.index] if run is not None and flight.index < len(run.nodes) else "?"
                    found.append((name, seq, node))
        return found

    def nodes_in_flight(self, runs: dict[str, SubchainRun]) -> list[str]:
        """The node each run in flight is at (a node once per run)."""
        found = []
        for name, state in self.states.items():
            run = runs.get(name)
            if run is not None:
                found += [run.nodes[f.index] for f in state.in_flight.values() if f.index < len(run.nodes)]
        return found

    def oldest_ms(self, name: str) -> float | None:
        state = self.states.get(name)
        return None if state is None else state.oldest_ms()

    def first_index(self, name: str) -> int | None:
        """The earliest node of ``name`` a run in flight is at (None: none is)."""
        state = self.states.get(name)
        if state is None or not state.in_flight:
            return None
        first = None
        for flight in state.in_flight.values():
            if first is None or flight.index < first:
                first = flight.index
        return first


def kernel_checked(head: Endpoint | None) -> TypeGuard[Endpoint]:
    """Whether a head's runs are checked by its thread's CPU count: a thread of its own only (both loops ask)."""
    return head is not None and not head.shares_thread


def run_age_ms(origin_ns: int, head_start_ms: float | None, end_ms: float) -> float | None:
    """A run's age at its end: ``end_ms`` minus its origin (``origin_ns``, CLOCK_MONOTONIC; 0: none, then a
    triggered head's start, which senses when it runs), never negative; None for a later node without one."""
    origin_ms = origin_ns / 1e6 if origin_ns else head_start_ms
    return None if origin_ms is None else max(end_ms - origin_ms, 0.0)


def _head_again(state: SubchainRuns, seq: int) -> bool:
    """Whether the head was triggered again after run ``seq`` (its thread's CPU since spans that run too)."""
    if state.pending is not None:
        return True
    return any(other != seq and flight.index == 0 for other, flight in state.in_flight.items())


class Reader:
    """Reads the rings of a subchain's nodes and hands what it finds on: compute times to the measurements,
    runs and compute samples to the log, hop delays (per edge inside a subchain, per head for its trigger) to the
    cost figures."""

    def __init__(
        self,
        book: RunBook,
        *,
        readers: Callable[[str], tuple[tuple[int, Endpoint, RingReader], ...]],
        record: Callable[[str, float], object],
        measured: tuple[str, ...],
        hop: Callable[[float, bool, tuple[str, str] | None, str | None], None],
        sample: Callable[[str, float, str, tuple[object, ...]], None],
    ) -> None:
        self.book, self.readers, self.record, self.hop, self.sample = book, readers, record, hop, sample
        self.measured = frozenset(measured)
        self.seen = Seen()

    def read(self, run: SubchainRun, now_ms: float) -> None:
        """Move ``run``'s runs on as its rings say (what they measured waits for :meth:`flush`)."""
        self.book.read(run, self.readers(run.name), now_ms, self.seen)

    def flush(self) -> None:
        """Hand on what the rings said since the last flush (housekeeping does, a few times a second)."""
        seen = self.seen
        if seen.hops:
            for hop in seen.hops:
                self.hop(hop.delay_ms, hop.inside, hop.edge, None if hop.inside else hop.node)
            seen.hops.clear()
        if seen.computes:
            for compute in seen.computes:
                if compute.ms is not None and compute.node in self.measured:
                    self.record(compute.node, compute.ms)
                self.sample(
                    "compute",
                    compute.at_ms,
                    compute.node,
                    (compute.ms, compute.reported_ms, compute.kernel_ms, compute.threads, compute.age_ms),
                )
            seen.computes.clear()
        if seen.runs:
            for done in seen.runs:
                self.sample("run", done.at_ms, done.subchain, (done.seq, done.latency_ms))
            seen.runs.clear()
