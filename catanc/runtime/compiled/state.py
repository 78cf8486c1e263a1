"""The compiled walk's arrays (:class:`~catanc.runtime.compiled.arrays.Walk`) from the enforcer's Python objects.

:func:`install` lays a :class:`~catanc.control.schedule.RuntimeSchedule` out as a new walk of its
shared cores, as :meth:`SharedCores.install <catanc.runtime.enforcer.cores.SharedCores.install>` starts
one, with the runs in flight, levels and rings the enforcer has; :func:`update` adds a schedule
that each core takes at its next period (:meth:`SharedCores.update`).  :func:`runs_in_flight`
reads the runs back the way :class:`~catanc.runtime.enforcer.runs.RunBook` keeps them, and
:func:`events` the log the walk wrote since the last call.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from catanc.control.policy import CoreCursor, SlotRule, slot_rules
from catanc.control.schedule import CoreSchedule, RuntimeSchedule
from catanc.control.slot_table import ACTIONS, empty_rules, lay_out_rules
from catanc.runtime.compiled import arrays as wa
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook, kernel_checked
from catanc.runtime.linux.levels import Levels
from catanc.runtime.protocol.endpoints import Endpoint
from catanc.runtime.protocol.messages import PROTOCOL
from catanc.runtime.protocol.ring import SLOTS
from catanc.spec.speedup import threads_and_speedup

EXTRA_VERSIONS = 2
"""Schedules kept beyond one a core: each core's current one (all may differ while cores move over at their own
period ends), the latest, and a free one for the next update."""
EVENTS = 8192

KernelFd = Callable[[Endpoint], int | None]
"""A node thread's opened ``schedstat`` descriptor (None: not opened)."""


class Flight(NamedTuple):
    """A run in flight as the walk has it (for comparison with :class:`~catanc.runtime.enforcer.runs.RunFlight`)."""

    seq: int
    node: int  # the subchain's node it is at
    triggered_ms: float
    last_end_ms: float | None
    until_ms: float | None
    kernel_ns: int | None


def install(
    schedule: RuntimeSchedule,
    wiring: Wiring,
    book: RunBook,
    levels: Levels,
    now_ms: float,
    *,
    kernel_fd: KernelFd = lambda _endpoint: None,
) -> tuple[wa.Walk, tuple[str, ...], tuple[int, ...]]:
    """A walk of ``schedule``'s shared cores from ``now_ms``: the walk, its subchains' names and its cores
    (its wake-ups are worked out by :func:`~catanc.runtime.compiled.walk.rewake`, or copied in).

    The walk reads each ring where its reader mapped it: lay the walk out again before a reader is closed.
    """
    names = tuple(schedule.subchains)
    sub = {name: s for s, name in enumerate(names)}
    cores = tuple(core for core in schedule.shared if core.slots)
    core_ids = tuple(core.core for core in cores)
    n_subs, n_cores = len(names), len(cores)
    most = max([len(run.nodes) for run in schedule.subchains.values()] + [1])
    versions = n_cores + EXTRA_VERSIONS
    slots = max([len(core.slots) for core in cores] + [n_subs, 1])

    readers = [
        (s, index, endpoint, reader)
        for s, name in enumerate(names)
        for index, endpoint, reader in wiring.readers.get(name, ())
    ]
    sub_readers = np.zeros((n_subs, 2), dtype=np.int64)
    for s in range(n_subs):
        mine = [r for r, reader in enumerate(readers) if reader[0] == s]
        sub_readers[s] = (mine[0], len(mine)) if mine else (0, 0)
    addresses = [np.frombuffer(reader.words, dtype=np.uint64).ctypes.data for _, _, _, reader in readers]
    speedups = [book.speedups.get(endpoint.node, (1.0,)) for _, _, endpoint, _ in readers]
    widest = max([len(speedup) for speedup in speedups] + [1])
    r_speedup = np.ones((max(len(readers), 1), widest + 1))
    for r, speedup in enumerate(speedups):
        for q in range(widest + 1):
            r_speedup[r, q] = threads_and_speedup(speedup, max(q, 1))[1]

    tids = sorted({tid for chain in wiring.tids.values() for tid in chain[0]} if wiring.tids else set())
    thread = {tid: h for h, tid in enumerate(tids)}
    sub_threads = np.zeros((n_subs, most, 2), dtype=np.int64)
    order: list[int] = []
    for s, name in enumerate(names):
        for first, chain in enumerate(wiring.tids.get(name, ())):
            sub_threads[s, first] = (len(order), len(chain))
            order += [thread[tid] for tid in chain]
    th_raised = np.full(len(tids), wa.NONE, dtype=np.int64)
    raised_count = np.zeros(n_cores, dtype=np.int64)
    for c, core_id in enumerate(core_ids):
        for tid in levels.raised.get(core_id, ()):
            if tid in thread:
                th_raised[thread[tid]] = c
                raised_count[c] += 1

    datagram = np.zeros((n_subs, wa.DATAGRAM), dtype=np.uint8)
    prefix = np.zeros(n_subs, dtype=np.int64)
    head_fd = np.full(n_subs, wa.NONE, dtype=np.int64)
    head_kernel_fd = np.full(n_subs, wa.NONE, dtype=np.int64)
    for s, name in enumerate(names):
        head = wiring.heads.get(name)
        if head is None:
            continue
        text = b"%s trigger %s " % (PROTOCOL, head.node.encode())
        datagram[s, : len(text)] = np.frombuffer(text, dtype=np.uint8)
        prefix[s] = len(text)
        head_fd[s] = head.sock.fileno() if head.sock is not None else -2
        fd = kernel_fd(head) if kernel_checked(head) else None
        head_kernel_fd[s] = wa.NONE if fd is None else fd

    states = [book.state(name) for name in names]
    runs = [schedule.subchains[name] for name in names]
    rule_sub, rule_every, rule_thieves = empty_rules(versions, n_cores, slots)
    walk = wa.Walk(
        period=np.zeros((versions, n_cores)),
        switch=np.zeros((versions, n_cores)),
        nslots=np.ones((versions, n_cores), dtype=np.int64),
        slot_start=np.zeros((versions, n_cores, slots)),
        slot_length=np.zeros((versions, n_cores, slots)),
        rule_sub=rule_sub,
        rule_every=rule_every,
        rule_thieves=rule_thieves,
        core_every=np.ones((versions, n_cores), dtype=np.int64),
        latest=np.zeros(n_cores, dtype=np.int64),
        version=np.zeros(n_cores, dtype=np.int64),
        start=np.zeros(n_cores),
        period_index=np.zeros(n_cores, dtype=np.int64),
        position=np.zeros(n_cores, dtype=np.int64),
        due=np.zeros(n_cores),
        wake=np.zeros(n_cores),
        raised=np.full(n_cores, wa.NONE, dtype=np.int64),
        raised_from=np.full(n_cores, wa.NONE, dtype=np.int64),
        raised_count=raised_count,
        latency=np.zeros(n_subs),
        late_after=np.zeros(n_subs),
        length=np.array([len(schedule.subchains[name].nodes) for name in names], dtype=np.int64),
        shared=np.array([int(schedule.subchains[name].shared) for name in names], dtype=np.int64),
        seq=np.array([state.seq for state in states], dtype=np.int64),
        pending=np.array([wa.NONE if state.pending is None else state.pending for state in states], dtype=np.int64),
        late=np.array([state.late for state in states], dtype=np.int64),
        skipped=np.array([state.skipped for state in states], dtype=np.int64),
        unmatched=np.array([state.unmatched for state in states], dtype=np.int64),
        steals=np.array([state.steals for state in states], dtype=np.int64),
        flying=np.zeros(n_subs, dtype=np.int64),
        thief_late=np.zeros(n_subs, dtype=np.int64),
        actions=np.full(ACTIONS, wa.NONE, dtype=np.int64),
        fl_seq=np.zeros((n_subs, wa.FLIGHTS), dtype=np.int64),
        fl_index=np.zeros((n_subs, wa.FLIGHTS), dtype=np.int64),
        fl_triggered=np.zeros((n_subs, wa.FLIGHTS)),
        fl_last_end=np.full((n_subs, wa.FLIGHTS), math.nan),
        fl_until=np.full((n_subs, wa.FLIGHTS), math.nan),
        fl_kernel=np.full((n_subs, wa.FLIGHTS), wa.NONE, dtype=np.int64),
        sub_readers=sub_readers,
        r_index=np.array([index for _, index, _, _ in readers] or [0], dtype=np.int64),
        r_last=np.array([reader.last for _, _, _, reader in readers] or [0], dtype=np.int64),
        r_slots=np.array([reader.slots for _, _, _, reader in readers] or [SLOTS], dtype=np.int64),
        r_overrun=np.array([reader.overrun for _, _, _, reader in readers] or [0], dtype=np.int64),
        r_kernel_fd=np.array([_fd(kernel_fd(endpoint)) for _, _, endpoint, _ in readers] or [wa.NONE], dtype=np.int64),
        r_kernel_mark=np.array(
            [wa.NONE if e.kernel_mark_ns is None else e.kernel_mark_ns for _, _, e, _ in readers] or [wa.NONE],
            dtype=np.int64,
        ),
        r_expected=np.array(
            [book.expected.get(e.node, math.nan) for _, _, e, _ in readers] or [math.nan], dtype=np.float64
        ),
        r_speedup=r_speedup,
        r_address=np.array(addresses or [0], dtype=np.int64),
        entries=np.zeros(
            max([reader.slots for _, _, _, reader in readers] + [SLOTS]) * wa.ENTRY_WORDS, dtype=np.uint64
        ),
        th_tid=np.array(tids, dtype=np.int64),
        th_level=np.array([_level(levels.level(tid)) for tid in tids], dtype=np.int64),
        th_resting=np.array([_level(levels.resting.get(tid)) for tid in tids], dtype=np.int64),
        th_raised=th_raised,
        sub_threads=sub_threads,
        raise_order=np.array(order or [0], dtype=np.int64),
        head_fd=head_fd,
        head_kernel_fd=head_kernel_fd,
        head_datagram=datagram,
        head_prefix=prefix,
        head_threads=np.array([schedule.subchains[name].threads_of(0)[0] for name in names], dtype=np.int64),
        clk_sub=np.zeros(max(n_subs, 1), dtype=np.int64),
        clk_due=np.zeros(max(n_subs, 1)),
        clk_period=np.zeros(max(n_subs, 1)),
        clk_rank=np.zeros(max(n_subs, 1), dtype=np.int64),
        sub_core=np.array(
            [core_ids.index(run.cores[0]) if run.shared and run.cores[0] in core_ids else wa.NONE for run in runs],
            dtype=np.int64,
        ),
        flags=np.array([int(levels.rt), 0, 0, _room(len(readers)), 0, 0, 0], dtype=np.int64),
        events=np.zeros((EVENTS, wa.EVENT_FIELDS)),
        scratch=np.zeros(8, dtype=np.int64),
        text=np.zeros(64, dtype=np.uint8),
    )
    for s, state in enumerate(states):
        if len(state.in_flight) >= wa.FLIGHTS - 2:  # no room (compiled_walk.crowded): the caller stays in Python
            raise ValueError(f"{len(state.in_flight)} runs in flight: more than the walk holds")
        for seq, flight in state.in_flight.items():
            k = walk.flying[s]
            walk.fl_seq[s, k], walk.fl_index[s, k], walk.fl_triggered[s, k] = seq, flight.index, flight.triggered_ms
            walk.fl_last_end[s, k] = math.nan if flight.last_end_ms is None else flight.last_end_ms
            walk.fl_until[s, k] = math.nan if flight.until_ms is None else flight.until_ms
            walk.fl_kernel[s, k] = wa.NONE if flight.kernel_ns is None else flight.kernel_ns
            walk.flying[s] = k + 1
    _lay_out(walk, 0, schedule, cores, sub)
    for c, core in enumerate(cores):
        cursor = CoreCursor(core, now_ms)
        walk.start[c], walk.period_index[c], walk.position[c], walk.due[c] = now_ms, 0, 0, cursor.due
    return walk, names, core_ids


def update(walk: wa.Walk, schedule: RuntimeSchedule, names: tuple[str, ...], core_ids: tuple[int, ...]) -> None:
    """A new schedule on the same allocation: each core takes it at its next period (:meth:`SharedCores.update`;
    then :func:`~catanc.runtime.compiled.walk.rewake`).

    Raises ``ValueError`` if it is not the same allocation (another set of subchains or cores:
    a new walk is installed then).
    """
    if tuple(schedule.subchains) != names:
        raise ValueError("another set of subchains: install a new walk")
    by_core = {core.core: core for core in schedule.shared if core.slots}
    if tuple(by_core) != core_ids:
        raise ValueError("another set of shared cores: install a new walk")
    in_use = set(walk.version.tolist()) | set(walk.latest.tolist())
    free = [v for v in range(walk.period.shape[0]) if v not in in_use]  # there is one: cores + 2 versions
    cores = tuple(by_core[core_id] for core_id in core_ids)
    _lay_out(walk, free[0], schedule, cores, {name: s for s, name in enumerate(names)})


def _lay_out(
    walk: wa.Walk, v: int, schedule: RuntimeSchedule, cores: tuple[CoreSchedule, ...], sub: dict[str, int]
) -> None:
    for c, core in enumerate(cores):
        lay_out_core(walk, v, c, core, rules=slot_rules(core, schedule.subchains), sub=sub)
        walk.latest[c] = v
    for name, s in sub.items():
        walk.latency[s] = schedule.subchains[name].latency_ms
        walk.late_after[s] = schedule.subchains[name].late_after_ms
        walk.head_threads[s] = schedule.subchains[name].threads_of(0)[0]


def lay_out_core(
    walk: wa.Walk, v: int, c: int, core: CoreSchedule, *, rules: tuple[SlotRule, ...], sub: dict[str, int]
) -> None:
    """Core ``c``'s schedule ``core`` with its slot ``rules`` as version ``v``."""
    width = walk.slot_start.shape[2]
    if len(core.slots) > width:
        raise ValueError(f"core {core.core} has {len(core.slots)} slots, the walk room for {width}")
    walk.period[v, c], walk.switch[v, c], walk.nslots[v, c] = core.period_ms, core.switch_ms, len(core.slots)
    for j, slot in enumerate(core.slots):
        walk.slot_start[v, c, j], walk.slot_length[v, c, j] = slot.start_ms, slot.length_ms
    lay_out_rules((walk.rule_sub, walk.rule_every, walk.rule_thieves), v, c, rules, sub)
    walk.core_every[v, c] = max((rule.every or 1 for rule in rules), default=1)


def _fd(fd: int | None) -> int:
    return wa.NONE if fd is None else fd


def _level(level: int | None) -> int:
    return wa.NONE if level is None else level


def _room(readers: int) -> int:
    """Log records one boundary may write at most: each ring's entries (a compute, a hop, a run) and a few more."""
    return 3 * SLOTS * max(readers, 1) + 8


def set_clocks(
    walk: wa.Walk, clocks: list[tuple[float, str]], schedule: RuntimeSchedule, names: tuple[str, ...]
) -> None:
    """The enforcer's clocks (a heap of (due, subchain)) into the walk: those of subchains still on a clock."""
    sub = {name: s for s, name in enumerate(names)}
    rank = {name: r for r, name in enumerate(sorted(names))}
    k = 0
    for due, name in clocks:
        run = schedule.subchains.get(name)
        if run is None or not run.on_clock or name not in sub:
            continue  # dropped, as the enforcer drops it when it comes due
        if k == walk.clk_sub.size:
            raise ValueError("more clocks than subchains")
        walk.clk_sub[k], walk.clk_due[k], walk.clk_period[k], walk.clk_rank[k] = (
            sub[name],
            due,
            run.period_ms,
            rank[name],
        )
        k += 1
    walk.flags[wa.CLOCKS] = k


def get_clocks(walk: wa.Walk, names: tuple[str, ...]) -> list[tuple[float, str]]:
    """The walk's clocks as the enforcer's heap."""
    clocks = [(float(walk.clk_due[k]), names[int(walk.clk_sub[k])]) for k in range(int(walk.flags[wa.CLOCKS]))]
    heapq.heapify(clocks)
    return clocks


def runs_in_flight(walk: wa.Walk, s: int) -> dict[int, Flight]:
    """Subchain ``s``'s runs in flight, by seq."""
    found = {}
    for k in range(int(walk.flying[s])):
        last_end, until, kernel = walk.fl_last_end[s, k], walk.fl_until[s, k], int(walk.fl_kernel[s, k])
        found[int(walk.fl_seq[s, k])] = Flight(
            int(walk.fl_seq[s, k]),
            int(walk.fl_index[s, k]),
            float(walk.fl_triggered[s, k]),
            None if math.isnan(last_end) else float(last_end),
            None if math.isnan(until) else float(until),
            None if kernel == wa.NONE else kernel,
        )
    return dict(sorted(found.items()))


def events(walk: wa.Walk) -> npt.NDArray[np.float64]:
    """The records the walk logged since the last call, a row each (the log is emptied)."""
    count = int(walk.flags[wa.LOGGED])
    found = walk.events[:count].copy()
    walk.flags[wa.LOGGED] = 0
    return found
