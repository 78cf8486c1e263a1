"""Two copies of the enforcer's hot path over one set of rings, for the compiled walk's run-for-run tests.

:func:`random_schedule` and :func:`rescheduled` draw shared-core plans (and dedicated subchains on
clocks); :func:`side` builds one copy of the hot-path state (SharedCores, RunBook, Levels, readers,
sockets) as the enforcer has it; :func:`report_runs` writes what random nodes report;
:func:`trigger_head` and :func:`fire_clocks` are ``Enforcer._trigger_head`` and the clocks of
``Enforcer._on_time``, the oracle for the walk's clocks.
"""

from __future__ import annotations

import heapq
import math
import random
import socket
from dataclasses import dataclass, field

from catanc.control.policy import next_clock_ms
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun
from catanc.runtime.enforcer.cores import SharedCores
from catanc.runtime.enforcer.costs import Costs
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook, Seen
from catanc.runtime.linux.levels import Levels
from catanc.runtime.protocol import ring
from catanc.runtime.protocol.endpoints import Endpoint
from catanc.runtime.protocol.messages import trigger_datagram

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
                wait_ms=rng.uniform(0.0, 2.0) * period if rng.random() < 0.3 else 0.0,  # an executor's thread
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


def next_wake_up(rng: random.Random, now: float, wake_ms: float) -> float:
    """When the loop wakes next: soon, at the cores' next wake-up, or after sleeping through periods."""
    roll = rng.random()
    if roll < 0.6:
        return now + rng.uniform(0.0, 3.0)
    if roll < 0.9:
        return max(now, wake_ms if math.isfinite(wake_ms) else now)
    return now + rng.uniform(0.0, 80.0)


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
                origin = 0 if rng.random() < 0.5 else max(int((start - rng.uniform(-1.0, 5.0)) * MS), 1)
                writers[node].append(
                    seq,
                    max(int(start * MS), 0),
                    max(int(end * MS), 0),
                    compute,
                    rng.choice((1, 1, 2, 3)),
                    origin_ns=origin,  # when its data was sensed (0: none); after its end sometimes: a bad clock
                )


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
