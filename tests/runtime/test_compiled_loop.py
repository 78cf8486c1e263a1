"""The enforcer's Python state kept in step with the compiled walk (catanc.runtime.compiled_loop), run for run.

Two copies of the enforcer's hot-path state over the same rings: one walked by SharedCores as
``catanc run`` does without the compiled loop, the other by :class:`CompiledLoop` (copied into
the walk, walked compiled, copied back, its log replayed).  After every wake-up their Python
objects must agree: the runs in flight and counters, what is raised, the levels, the samples,
the trigger datagrams and the next wake-up.  Re-solves, housekeeping reads and stretches walked
by Python in between (as the enforcer's loop does between compiled waits) change nothing.
"""

from __future__ import annotations

import heapq
import math
import random
import socket
import time
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("numba", reason="the compiled loop needs numba (the sim extra)")

from catanc.control.policy import next_clock_ms
from catanc.control.schedule import RuntimeSchedule, SubchainRun
from catanc.runtime import ring
from catanc.runtime.compiled_loop import CompiledLoop, warm_up
from catanc.runtime.cores import SharedCores
from catanc.runtime.costs import Costs
from catanc.runtime.endpoints import Endpoint
from catanc.runtime.levels import Levels
from catanc.runtime.nodes import Wiring
from catanc.runtime.protocol import trigger_datagram
from catanc.runtime.runs import RunBook, Seen
from tests.runtime.test_compiled_walk import random_schedule, report_runs, rescheduled


@dataclass
class Side:
    """One copy of the enforcer's hot-path state: its own readers, sockets, book, levels and cores."""

    book: RunBook
    levels: Levels
    seen: Seen
    costs: Costs
    cores: SharedCores
    wiring: Wiring
    receivers: dict[str, socket.socket]
    untaken: list[str] = field(default_factory=list)
    gone: list[int] = field(default_factory=list)
    closing: list[object] = field(default_factory=list)


def side(schedule: RuntimeSchedule, fds: dict[str, int], config: random.Random) -> Side:
    """The same random choices (``config`` seeded alike) give two sides alike."""
    nodes = [node for run in schedule.subchains.values() for node in run.nodes]
    speedups: dict[str, tuple[float, ...]] = {node: (1.0, 1.6) for node in nodes if config.random() < 0.3}
    book = RunBook(schedule.subchains, speedups, lambda _endpoint: None)
    book.expected = {node: config.uniform(0.2, 2.0) for node in nodes if config.random() < 0.5}
    levels = Levels(rt=False)
    readers, tids, heads, receivers, endpoints = {}, {}, {}, {}, {}
    closing: list[object] = []
    tid = 1000
    for name, run in schedule.subchains.items():
        chain = []
        for index, node in enumerate(run.nodes):
            sock = None
            if index == 0:
                sock, receivers[name] = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
                closing += [sock, receivers[name]]
            reader = ring.RingReader(fds[node], ring.RingWriter(fds[node]).slots)
            endpoint = Endpoint(node, 1, tid, None, sock=sock, reader=reader)
            endpoints[node] = endpoint
            closing.append(reader)
            chain.append((index, endpoint, reader))
            levels.rest(tid, 1)
            tid += 1
        readers[name] = tuple(chain)
        tids[name] = tuple(tuple(endpoints[node].tid for node in run.nodes[first:]) for first in range(len(run.nodes)))
        heads[name] = endpoints[run.nodes[0]] if config.random() < 0.9 else None
    wiring = Wiring(0, schedule, readers, tids, heads)
    seen, costs = Seen(), Costs()

    def trigger(run: SubchainRun, now: float, raised_until: float | None = None, *, at_slot: bool = False) -> None:
        head = wiring.heads.get(run.name)  # as Enforcer._trigger_head does at a slot
        if head is None:
            book.state(run.name).skipped += 1
            return
        started = book.trigger(run, now, head, raised_until)
        if started is not None and not head.send(trigger_datagram(head.node, started.seq, run.threads_of(0)[0])):
            made.untaken.append(run.name)

    cores = SharedCores(book, levels, costs, trigger=trigger, seen=seen, gone=lambda tids: made.gone.extend(tids))  # noqa: PLW0108 - made is bound below
    made = Side(book, levels, seen, costs, cores, wiring, receivers, closing=closing)
    cores.rewire(wiring)
    cores.install(schedule, 0.0)
    return made


def trigger_head(one: Side, run: SubchainRun, now: float, raised_until: float | None) -> None:
    """``Enforcer._trigger_head`` off a slot (a clock's trigger): the oracle for the walk's clocks."""
    head = one.wiring.heads.get(run.name)
    if head is None:
        one.book.state(run.name).skipped += 1
        return
    one.book.read(run, one.wiring.readers.get(run.name, ()), now, one.seen)  # is the head still busy?
    if run.shared and one.cores.raised_on(run):
        one.cores.raise_owner(run.cores[0], run.name, triggered=True)
    started = one.book.trigger(run, now, head, raised_until)
    if started is not None and not head.send(trigger_datagram(head.node, started.seq, run.threads_of(0)[0])):
        one.untaken.append(run.name)


def fire_clocks(one: Side, schedule: RuntimeSchedule, clocks: list[tuple[float, str]], now: float) -> None:
    """``Enforcer._on_time``'s clocks, as it fires them."""
    if clocks and clocks[0][0] <= now:
        shared = False
        while clocks and clocks[0][0] <= now:
            due, name = heapq.heappop(clocks)
            run = schedule.subchains.get(name)
            if run is None or not run.on_clock:
                continue
            trigger_head(one, run, now, None if run.shared else math.inf)
            shared = shared or run.shared
            heapq.heappush(clocks, (next_clock_ms(due, run.period_ms, now), name))
        if shared:
            one.cores.rewake()


def drained(sock: socket.socket) -> list[bytes]:
    got = []
    while True:
        try:
            got.append(sock.recv(256, socket.MSG_DONTWAIT))
        except BlockingIOError:
            return got


def agree(python: Side, compiled: Side, step: str) -> None:
    for name, state in python.book.states.items():
        other = compiled.book.states[name]
        flights = {
            seq: (f.index, f.triggered_ms, f.last_end_ms, f.until_ms, f.kernel_ns) for seq, f in state.in_flight.items()
        }
        mirrored = {
            seq: (f.index, f.triggered_ms, f.last_end_ms, f.until_ms, f.kernel_ns) for seq, f in other.in_flight.items()
        }
        assert mirrored == flights, f"{step}: {name}'s runs in flight"
        counters = (
            state.seq,
            state.pending,
            state.late,
            state.skipped,
            state.unmatched,
            state.steals,
            list(state.ends_ms),
        )
        assert (
            other.seq,
            other.pending,
            other.late,
            other.skipped,
            other.unmatched,
            other.steals,
            list(other.ends_ms),
        ) == counters, f"{step}: {name}'s counters"
        assert drained(compiled.receivers[name]) == drained(python.receivers[name]), f"{step}: {name}'s triggers"
    assert compiled.cores.raised == python.cores.raised, f"{step}: who is raised"
    assert compiled.cores._raised_from == python.cores._raised_from, f"{step}: raised from"
    assert {c: s for c, s in compiled.levels.raised.items() if s} == {
        c: s for c, s in python.levels.raised.items() if s
    }
    assert compiled.cores.wake_ms == python.cores.wake_ms, f"{step}: the next wake-up"
    for core_id, core in python.cores.cores.items():
        mine = compiled.cores.cores[core_id]
        assert (
            mine.cursor.schedule,
            mine.cursor.index,
            mine.cursor.position,
            mine.cursor.start_ms,
            mine.cursor.due,
        ) == (
            core.cursor.schedule,
            core.cursor.index,
            core.cursor.position,
            core.cursor.start_ms,
            core.cursor.due,
        ), f"{step}: core {core_id}'s cursor"
        assert mine.rules == core.rules, f"{step}: core {core_id}'s rules"
        got, want = compiled.costs.switches.get(core_id, ()), python.costs.switches.get(core_id, ())
        assert len(got) == len(want), f"{step}: core {core_id}'s switch samples"
    assert compiled.seen.computes == python.seen.computes, f"{step}: compute samples"
    assert compiled.seen.runs == python.seen.runs, f"{step}: runs"
    assert compiled.seen.hops == python.seen.hops, f"{step}: hops"
    assert (compiled.untaken, compiled.gone) == (python.untaken, python.gone), f"{step}: untaken triggers, gone threads"


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_loop_keeps_the_enforcers_state_as_the_python_walk_does(seed: int) -> None:
    rng = random.Random(seed)
    schedule = random_schedule(rng, dedicated=True)
    fds = {node: ring.create(slots=rng.choice((4, 8, 64))) for run in schedule.subchains.values() for node in run.nodes}
    writers = {node: ring.RingWriter(fd) for node, fd in fds.items()}
    python = side(schedule, fds, random.Random(seed + 1))
    compiled = side(schedule, fds, random.Random(seed + 1))
    loop = CompiledLoop(
        compiled.cores,
        compiled.costs,
        compiled.seen,
        kernel_fd=lambda _endpoint: None,
        gone=compiled.gone.extend,
        untaken=compiled.untaken.append,
    )
    clocks = ([(0.0, run.name) for run in schedule.clocked], [(0.0, run.name) for run in schedule.clocked])
    for heap in clocks:
        heapq.heapify(heap)
    try:
        now = 0.0
        for step in range(100):
            roll = rng.random()
            if roll < 0.6:
                now += rng.uniform(0.0, 3.0)
            elif roll < 0.9:
                now = max(now, python.cores.wake_ms if math.isfinite(python.cores.wake_ms) else now)
            else:
                now += rng.uniform(0.0, 80.0)
            report_runs(schedule, python.book, writers, rng, now)
            python.cores.run_due(now)
            fire_clocks(python, schedule, clocks[0], now)
            if rng.random() > 0.8 or not loop.run_due(now, clocks[1]):  # else the enforcer's Python loop does it
                compiled.cores.run_due(now)
                fire_clocks(compiled, schedule, clocks[1], now)
            agree(python, compiled, f"step {step} at {now:.3f} ms")
            assert sorted(clocks[1]) == sorted(clocks[0]), f"step {step}: the clocks"
            if rng.random() < 0.1:  # housekeeping reads the busy subchains' rings, then the cores wake again
                for one in (python, compiled):
                    for name in one.book.states:
                        if one.book.busy(name):
                            one.book.read(schedule.subchains[name], one.wiring.readers[name], now, one.seen)
                    one.cores.rewake()
                agree(python, compiled, f"housekeeping after step {step}")
            if rng.random() < 0.05:  # a re-solve: each core takes it at its next period
                schedule = rescheduled(schedule, rng)
                python.cores.update(schedule)
                compiled.cores.update(schedule)
    finally:
        for writer in writers.values():
            writer.close()
        for one in (python, compiled):
            for thing in one.closing:
                thing.close()  # type: ignore[attr-defined]


def test_the_loop_warms_up_at_once_and_returns_when_its_time_is_past() -> None:
    """warm_up (the enforcer calls it at SCHED_OTHER, before raising its loop) loads or compiles ``wait`` and
    comes back: its time (-inf) is past."""
    started = time.monotonic()
    warm_up()
    assert time.monotonic() - started < 120.0  # a compile from scratch takes a minute on the development VM
