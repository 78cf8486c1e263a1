"""The compiled walk (catanc.runtime.compiled_walk) held to the Python one (SharedCores and RunBook), run for run.

Random shared-core schedules and random node behaviour (runs reported in real rings, some late,
some forged, some overrunning a small ring), walked by both at the same times: after every
wake-up the two must have raised the same subchains and threads, sent the same trigger
datagrams (real sockets), kept the same runs in flight and counters, logged the same samples
and asked to be woken at the same time.  The oracle is the Python hot path that ``catanc run``
uses today, itself tested by hand (tests/runtime/test_cores.py, test_runs.py).
"""

from __future__ import annotations

import math
import os
import random
import socket
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("numba", reason="the compiled walk needs numba (the sim extra)")

from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun
from catanc.runtime import compiled_state, ring
from catanc.runtime import compiled_walk as cw
from catanc.runtime.cores import SharedCores
from catanc.runtime.costs import Costs
from catanc.runtime.endpoints import Endpoint
from catanc.runtime.levels import Levels
from catanc.runtime.nodes import Wiring
from catanc.runtime.protocol import trigger_datagram
from catanc.runtime.runs import RunBook, Seen

MS = 1_000_000  # ns


def random_schedule(rng: random.Random, *, scale: float = 1.0, dedicated: bool = False) -> RuntimeSchedule:
    """1-2 shared cores of 1-3 subchains of 1-3 nodes, slots one after the other within the period; with
    ``dedicated``, 0-2 subchains on cores of their own."""
    runs: dict[str, SubchainRun] = {}
    cores = []
    for core in range(rng.choice((0, 1, 1, 2) if dedicated else (1, 1, 2))):
        period = rng.uniform(4.0, 20.0) * scale
        switch = rng.choice((0.0, 0.1, 0.3))
        count = rng.randint(1, 3)
        lengths = [rng.uniform(0.3, 1.0) for _ in range(count)]
        room = period * rng.uniform(0.5, 0.95) - switch * count
        slots, at = [], 0.0
        for k, share in enumerate(lengths):
            name = f"c{core}s{k}"
            length = room * share / sum(lengths)
            slots.append(Slot(name, at + switch, length))
            at += switch + length
            every = rng.choice((1, 1, 2, 3, None))
            nodes = tuple(f"{name}n{i}" for i in range(rng.randint(1, 3)))
            threads = tuple((rng.choice((1, 1, 2)), 1.0) for _ in nodes) if rng.random() < 0.3 else ()
            runs[name] = SubchainRun(
                name,
                nodes,
                (core,),
                True,
                period * (every or 1),
                rng.uniform(0.2, 3.0) * period,
                every,
                rng.randint(0, 3),
                threads,
            )
        cores.append(CoreSchedule(core, period, switch, tuple(slots), stealing=rng.random() < 0.8))
    least = 0 if cores else 1
    for k in range(rng.choice((least, least, 1, 2)) if dedicated else 0):  # on cores of their own, on their own clocks
        name = f"d{k}"
        nodes = tuple(f"{name}n{i}" for i in range(rng.randint(1, 2)))
        period = rng.uniform(3.0, 30.0) * scale
        core = len(cores) + k
        runs[name] = SubchainRun(name, nodes, (core,), False, period, rng.uniform(0.5, 2.0) * period, None, 0)
    return RuntimeSchedule(len(cores) + sum(not run.shared for run in runs.values()), runs, tuple(cores))


def rescheduled(schedule: RuntimeSchedule, rng: random.Random) -> RuntimeSchedule:
    """The same subchains and cores, other periods, slices, latencies and threads (a Stage II re-solve)."""
    factor = rng.uniform(0.7, 1.3)
    cores = tuple(
        CoreSchedule(
            core.core,
            core.period_ms * factor,
            core.switch_ms,
            tuple(Slot(slot.subchain, slot.start_ms * factor, slot.length_ms * factor) for slot in core.slots),
            core.stealing,
        )
        for core in schedule.shared
    )
    runs = {
        name: SubchainRun(
            run.name,
            run.nodes,
            run.cores,
            run.shared,
            run.period_ms * factor,
            run.latency_ms * rng.uniform(0.7, 1.3),
            run.runs,
            run.priority,
            tuple((rng.choice((1, 2, 3)), 1.0) for _ in run.nodes) if rng.random() < 0.5 else run.node_threads,
        )
        for name, run in schedule.subchains.items()
    }
    return RuntimeSchedule(schedule.cores, runs, cores)


@dataclass
class Both:
    """The Python hot path and the compiled walk over one schedule, one set of rings, their own sockets."""

    schedule: RuntimeSchedule
    python: SharedCores
    book: RunBook
    levels: Levels
    seen: Seen
    wiring: Wiring
    walk: cw.Walk
    names: tuple[str, ...]
    core_ids: tuple[int, ...]
    writers: dict[str, ring.RingWriter]
    receivers: tuple[dict[str, socket.socket], dict[str, socket.socket]]  # python's, the walk's
    reader_nodes: list[str]
    closing: list[object] = field(default_factory=list)


def made(rng: random.Random) -> Both:
    schedule = random_schedule(rng)
    nodes = [node for run in schedule.subchains.values() for node in run.nodes]
    speedups: dict[str, tuple[float, ...]] = {node: (1.0, 1.6) for node in nodes if rng.random() < 0.3}
    book = RunBook(schedule.subchains, speedups, lambda _endpoint: None)
    book.expected = {node: rng.uniform(0.2, 2.0) for node in nodes if rng.random() < 0.5}
    levels = Levels(rt=False)
    closing: list[object] = []
    writers, readers, tids, heads = {}, {}, {}, {}
    receivers: tuple[dict[str, socket.socket], dict[str, socket.socket]] = ({}, {})
    walk_socks: dict[str, socket.socket] = {}
    tid = 1000
    endpoints: dict[str, Endpoint] = {}
    for name, run in schedule.subchains.items():
        chain = []
        for index, node in enumerate(run.nodes):
            fd = ring.create(slots=rng.choice((4, 8, 64)))
            writers[node] = ring.RingWriter(fd)
            sock = None
            if index == 0:
                ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
                sock, receivers[0][name] = ours, theirs
                walks, walk_theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
                walk_socks[name], receivers[1][name] = walks, walk_theirs
                closing += [ours, theirs, walks, walk_theirs]
            reader = ring.RingReader(fd, writers[node].slots)
            endpoint = Endpoint(node, 1, tid, None, sock=sock, reader=reader, ring_fd=fd)
            endpoints[node] = endpoint
            closing.append(endpoint)
            chain.append((index, endpoint, reader))
            levels.rest(tid, 1)
            tid += 1
        readers[name] = tuple(chain)
        tids[name] = tuple(tuple(endpoints[node].tid for node in run.nodes[first:]) for first in range(len(run.nodes)))
        heads[name] = endpoints[run.nodes[0]] if rng.random() < 0.9 else None
    wiring = Wiring(0, schedule, readers, tids, heads)
    seen = Seen()

    def trigger(run: SubchainRun, now: float, raised_until: float | None = None, *, at_slot: bool = False) -> None:
        assert at_slot
        head = wiring.heads.get(run.name)  # as Enforcer._trigger_head does at a slot
        if head is None:
            book.state(run.name).skipped += 1
            return
        started = book.trigger(run, now, head, raised_until)
        if started is not None:
            head.send(trigger_datagram(head.node, started.seq, run.threads_of(0)[0]))

    python = SharedCores(book, levels, Costs(), trigger=trigger, seen=seen, gone=lambda _tids: None)
    python.rewire(wiring)
    walk, names, core_ids = compiled_state.install(schedule, wiring, book, levels, 0.0)
    cw.rewake(walk)
    python.install(schedule, 0.0)
    for s, name in enumerate(names):
        if walk.head_fd[s] >= 0:
            walk.head_fd[s] = walk_socks[name].fileno()
    reader_nodes = [endpoint.node for name in names for _, endpoint, _ in readers[name]]
    return Both(
        schedule, python, book, levels, seen, wiring, walk, names, core_ids, writers, receivers, reader_nodes, closing
    )


def close(both: Both) -> None:
    for writer in both.writers.values():
        writer.close()
    for thing in both.closing:
        thing.close()  # type: ignore[attr-defined]


def report_runs(
    schedule: RuntimeSchedule, book: RunBook, writers: dict[str, ring.RingWriter], rng: random.Random, now: float
) -> None:
    """Some node threads report a run in their rings: most a run waiting at them, some forged or unmeasured."""
    for name, run in schedule.subchains.items():
        state = book.state(name)
        for index, node in enumerate(run.nodes):
            if rng.random() < 0.4:
                continue
            here = sorted((seq, f) for seq, f in state.in_flight.items() if f.index == index)
            for _ in range(rng.choice((1, 1, 1, 2, 9))):  # 9: more than a small ring holds
                roll = rng.random()
                if here and roll < 0.75:
                    seq, flight = here[0] if rng.random() < 0.8 else here[-1]
                    before = flight.last_end_ms if flight.last_end_ms is not None else flight.triggered_ms
                elif roll < 0.85:
                    seq, before = 0, now - 1.0  # a run nothing triggered: the oldest waiting
                else:
                    seq, before = rng.choice((10**9, 2**63 + 5, 1)), now - 2.0  # forged
                start = before + rng.uniform(-0.5, 2.0)
                end = start + rng.uniform(0.0, 3.0)
                compute = ring.UNKNOWN if rng.random() < 0.1 else int(rng.uniform(0.0, 4.0) * MS)
                writers[node].append(
                    seq, max(int(start * MS), 0), max(int(end * MS), 0), compute, rng.choice((1, 1, 2, 3))
                )


def compare(both: Both, step: str) -> None:
    walk, names, book = both.walk, both.names, both.book
    for s, name in enumerate(names):
        state = book.state(name)
        got = compiled_state.runs_in_flight(walk, s)
        want = {
            seq: compiled_state.Flight(seq, f.index, f.triggered_ms, f.last_end_ms, f.until_ms, f.kernel_ns)
            for seq, f in sorted(state.in_flight.items())
        }
        assert got == want, f"{step}: {name}'s runs in flight"
        counters = (state.seq, state.pending, state.late, state.skipped, state.unmatched, state.steals)
        pending = None if walk.pending[s] == cw.NONE else int(walk.pending[s])
        mine = (
            int(walk.seq[s]),
            pending,
            int(walk.late[s]),
            int(walk.skipped[s]),
            int(walk.unmatched[s]),
            int(walk.steals[s]),
        )
        assert mine == counters, f"{step}: {name}'s counters (seq, pending, late, skipped, unmatched, steals)"
    for c, core in enumerate(both.core_ids):
        raised = None if walk.raised[c] == cw.NONE else names[walk.raised[c]]
        assert raised == both.python.raised.get(core), f"{step}: the subchain raised on core {core}"
        threads = {int(walk.th_tid[h]) for h in range(walk.th_tid.size) if walk.th_raised[h] == c}
        assert threads == both.levels.raised.get(core, set()), f"{step}: the threads raised on core {core}"
    assert cw_wake(walk) == both.python.wake_ms, f"{step}: the next wake-up"
    events = compiled_state.events(walk)
    computes = [
        (e[1], both.reader_nodes[int(e[2])], _none(e[3]), _none(e[4]), _none(e[5]), int(e[6]))
        for e in events
        if e[0] == cw.EV_COMPUTE
    ]
    assert computes == [tuple(c) for c in both.seen.computes], f"{step}: compute samples"
    runs = [(e[1], names[int(e[2])], int(e[3]), e[4]) for e in events if e[0] == cw.EV_RUN]
    assert runs == [tuple(r) for r in both.seen.runs], f"{step}: runs done"
    hops = [(names[int(e[1])], both.reader_nodes[int(e[2])], e[3]) for e in events if e[0] == cw.EV_HOP]
    assert hops == [tuple(h) for h in both.seen.hops], f"{step}: hop delays"
    switches = [int(e[1]) for e in events if e[0] == cw.EV_SWITCH]
    for c, core in enumerate(both.core_ids):
        assert switches.count(c) == len(both.python.costs.switches.get(core, ())), f"{step}: switch samples"
        both.python.costs.switches.pop(core, None)
    both.seen.computes.clear()
    both.seen.runs.clear()
    both.seen.hops.clear()
    for name in names:
        assert _drain(both.receivers[1][name]) == _drain(both.receivers[0][name]), f"{step}: {name}'s triggers"


def cw_wake(walk: cw.Walk) -> float:
    return cw.wake_ms(walk)


def _none(value: float) -> float | None:
    return None if math.isnan(value) else value


def _drain(sock: socket.socket | None) -> list[bytes]:
    if sock is None:
        return []
    got = []
    while True:
        try:
            got.append(sock.recv(256, socket.MSG_DONTWAIT))
        except BlockingIOError:
            return got


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_walk_does_what_the_python_one_does(seed: int) -> None:
    rng = random.Random(seed)
    both = made(rng)
    try:
        now = 0.0
        for step in range(120):
            roll = rng.random()
            if roll < 0.6:
                now += rng.uniform(0.0, 3.0)
            elif roll < 0.9:
                now = max(now, both.python.wake_ms if math.isfinite(both.python.wake_ms) else now)
            else:
                now += rng.uniform(0.0, 80.0)  # asleep through periods
            report_runs(both.schedule, both.book, both.writers, rng, now)
            assert cw.run_due(both.walk, now) == cw.DONE
            both.python.run_due(now)
            compare(both, f"step {step} at {now:.3f} ms")
            if rng.random() < 0.1:  # the housekeeping reads every busy subchain, then the cores wake again
                for s, name in enumerate(both.names):
                    if both.book.busy(name):
                        both.book.read(both.schedule.subchains[name], both.wiring.readers[name], now, both.seen)
                    if cw.busy(both.walk, s):
                        cw.read(both.walk, s, now)
                cw.rewake(both.walk)
                both.python.rewake()
                compare(both, f"housekeeping after step {step}")
            if rng.random() < 0.03:  # a re-solve: each core takes it at its next period
                schedule = rescheduled(both.schedule, rng)
                both.schedule = schedule
                compiled_state.update(both.walk, schedule, both.names, both.core_ids)
                cw.rewake(both.walk)
                both.python.update(schedule)
                compare(both, f"update after step {step}")
    finally:
        close(both)


def test_a_schedstat_line_is_read_as_the_python_side_reads_it() -> None:
    """kernel_ns parses a real thread's schedstat as catanc.runtime.cpu_clocks does (the first field, ns)."""
    from catanc.runtime.cpu_clocks import parse_schedstat

    path = f"/proc/self/task/{os.getpid()}/schedstat"
    fd = os.open(path, os.O_RDONLY)
    try:
        walk, _, _ = compiled_state.install(
            RuntimeSchedule(1, {}, ()),
            Wiring(0, RuntimeSchedule(1, {}, ()), {}, {}, {}),
            RunBook([], {}, lambda _e: None),
            Levels(rt=False),
            0.0,
        )
        before = parse_schedstat(os.pread(fd, 128, 0).decode())
        got = cw.kernel_ns(walk, fd)
        after = parse_schedstat(os.pread(fd, 128, 0).decode())
        assert before <= got <= after
        assert cw.kernel_ns(walk, -1) == cw.NONE
    finally:
        os.close(fd)
