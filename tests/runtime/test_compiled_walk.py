"""The compiled walk (catanc.runtime.compiled.walk) held to the Python one (SharedCores and RunBook), run for run.

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

from catanc.control.schedule import RuntimeSchedule
from catanc.runtime.compiled import arrays as wa
from catanc.runtime.compiled import state as compiled_state
from catanc.runtime.compiled import walk as cw
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook
from catanc.runtime.linux.levels import Levels
from catanc.runtime.protocol import ring
from tests.support.hot_path import Side, drained, next_wake_up, random_schedule, report_runs, rescheduled, side


@dataclass
class Both:
    """The Python hot path (one :class:`Side`) and the compiled walk over the same state and rings,
    the walk sending its triggers on sockets of its own."""

    schedule: RuntimeSchedule
    side: Side
    walk: wa.Walk
    names: tuple[str, ...]
    core_ids: tuple[int, ...]
    writers: dict[str, ring.RingWriter]
    receivers: dict[str, socket.socket]  # the walk's
    reader_nodes: list[str]
    reader_inside: list[bool]  # not its subchain's head
    reader_after: list[str]  # the node before it in its subchain ("" for a head)
    closing: list[socket.socket] = field(default_factory=list)


def made(rng: random.Random) -> Both:
    schedule = random_schedule(rng)
    fds = {node: ring.create(slots=rng.choice((4, 8, 64))) for run in schedule.subchains.values() for node in run.nodes}
    writers = {node: ring.RingWriter(fd) for node, fd in fds.items()}
    python = side(schedule, fds, rng)
    walk, names, core_ids = compiled_state.install(schedule, python.wiring, python.book, python.levels, 0.0)
    cw.rewake(walk)
    receivers, closing = {}, []
    for s, name in enumerate(names):
        if walk.head_fd[s] >= 0:
            ours, receivers[name] = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
            closing += [ours, receivers[name]]
            walk.head_fd[s] = ours.fileno()
    readers = [reader for name in names for reader in python.wiring.readers[name]]
    reader_nodes = [endpoint.node for _, endpoint, _ in readers]
    reader_inside = [index > 0 for index, _, _ in readers]
    reader_after = [
        schedule.subchains[name].nodes[index - 1] if index > 0 else ""
        for name in names
        for index, _, _ in python.wiring.readers[name]
    ]
    return Both(
        schedule, python, walk, names, core_ids, writers, receivers, reader_nodes, reader_inside, reader_after, closing
    )


def close(both: Both) -> None:
    for writer in both.writers.values():
        writer.close()
    for thing in [*both.closing, *both.side.closing]:
        thing.close()  # type: ignore[attr-defined]


def compare(both: Both, step: str) -> None:
    walk, names, python = both.walk, both.names, both.side
    for s, name in enumerate(names):
        state = python.book.state(name)
        got = compiled_state.runs_in_flight(walk, s)
        want = {
            seq: compiled_state.Flight(seq, f.index, f.triggered_ms, f.last_end_ms, f.until_ms, f.kernel_ns)
            for seq, f in sorted(state.in_flight.items())
        }
        assert got == want, f"{step}: {name}'s runs in flight"
        counters = (state.seq, state.pending, state.late, state.skipped, state.unmatched, state.steals)
        pending = None if walk.pending[s] == wa.NONE else int(walk.pending[s])
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
        raised = None if walk.raised[c] == wa.NONE else names[walk.raised[c]]
        assert raised == python.cores.raised.get(core), f"{step}: the subchain raised on core {core}"
        threads = {int(walk.th_tid[h]) for h in range(walk.th_tid.size) if walk.th_raised[h] == c}
        assert threads == python.levels.raised.get(core, set()), f"{step}: the threads raised on core {core}"
    assert wa.wake_ms(walk) == python.cores.wake_ms, f"{step}: the next wake-up"
    events = compiled_state.events(walk)
    computes = [
        (e[1], both.reader_nodes[int(e[2])], _none(e[3]), _none(e[4]), _none(e[5]), int(e[6]), _none(e[7]))
        for e in events
        if e[0] == wa.EV_COMPUTE
    ]
    seen = python.seen
    assert computes == [tuple(c) for c in seen.computes], f"{step}: compute samples"
    runs = [(e[1], names[int(e[2])], int(e[3]), e[4]) for e in events if e[0] == wa.EV_RUN]
    assert runs == [tuple(r) for r in seen.runs], f"{step}: runs done"
    hops = [
        (names[int(e[1])], both.reader_nodes[r], e[3], both.reader_inside[r], both.reader_after[r])
        for e in events
        if e[0] == wa.EV_HOP
        for r in (int(e[2]),)
    ]
    assert hops == [tuple(h) for h in seen.hops], f"{step}: hop delays"
    switches = [int(e[1]) for e in events if e[0] == wa.EV_SWITCH]
    for c, core in enumerate(both.core_ids):
        assert switches.count(c) == len(python.costs.switches.get(core, ())), f"{step}: switch samples"
        python.costs.switches.pop(core, None)
    seen.computes.clear()
    seen.runs.clear()
    seen.hops.clear()
    for name in names:
        sent = drained(both.receivers[name]) if name in both.receivers else []
        wanted = drained(python.receivers[name]) if name in python.receivers else []
        assert sent == wanted, f"{step}: {name}'s triggers"


def _none(value: float) -> float | None:
    return None if math.isnan(value) else value


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_walk_does_what_the_python_one_does(seed: int) -> None:
    rng = random.Random(seed)
    both = made(rng)
    try:
        now = 0.0
        for step in range(120):
            now = next_wake_up(rng, now, both.side.cores.wake_ms)
            report_runs(both.schedule, both.side.book, both.writers, rng, now)
            assert cw.run_due(both.walk, now) == wa.DONE
            both.side.cores.run_due(now)
            compare(both, f"step {step} at {now:.3f} ms")
            if rng.random() < 0.1:  # the housekeeping reads every busy subchain, then the cores wake again
                for s, name in enumerate(both.names):
                    if both.side.book.busy(name):
                        both.side.book.read(
                            both.schedule.subchains[name], both.side.wiring.readers[name], now, both.side.seen
                        )
                    if cw.busy(both.walk, s):
                        cw.read(both.walk, s, now)
                cw.rewake(both.walk)
                both.side.cores.rewake()
                compare(both, f"housekeeping after step {step}")
            if rng.random() < 0.03:  # a re-solve: each core takes it at its next period
                schedule = rescheduled(both.schedule, rng)
                both.schedule = schedule
                compiled_state.update(both.walk, schedule, both.names, both.core_ids)
                cw.rewake(both.walk)
                both.side.cores.update(schedule)
                compare(both, f"update after step {step}")
    finally:
        close(both)


@pytest.mark.parametrize("seed", range(4))
def test_a_subchain_near_its_rows_end_hands_every_boundary_to_python(seed: int) -> None:
    """A boundary reads other subchains' rings too (thieves, the one raised), and each read may start the run
    that waited for its head: with any subchain two runs short of :data:`FLIGHTS` the walk does nothing and
    says FULL (nav2d's 2-core run overflowed a row: IndexError, the enforcer ended)."""
    both = made(random.Random(seed))
    try:
        s = seed % len(both.names)
        both.walk.flying[s] = wa.FLIGHTS - 2
        before = (both.walk.due.copy(), both.walk.position.copy(), both.walk.seq.copy())
        assert cw.run_due(both.walk, 10_000.0) == wa.FULL
        after = (both.walk.due, both.walk.position, both.walk.seq)
        assert all((b == a).all() for b, a in zip(before, after, strict=True))  # nothing was done
        both.walk.flying[s] = wa.FLIGHTS - 3
        assert cw.run_due(both.walk, 10_000.0) != wa.FULL or any(
            both.walk.flying[k] >= wa.FLIGHTS - 2 for k in range(len(both.names))
        )
    finally:
        close(both)


def test_a_book_with_more_runs_in_flight_than_a_row_holds_is_not_laid_out() -> None:
    """A re-plan lays the walk out again from Python's book, which has no limit: a subchain with a row's worth of
    runs in flight is a ValueError (its wake-ups stay in Python), not an IndexError that ends the enforcer."""
    from catanc.runtime.enforcer.runs import RunFlight

    both = made(random.Random(0))
    try:
        name = both.names[0]
        state = both.side.book.state(name)
        for seq in range(1, wa.FLIGHTS + 1):
            state.in_flight[seq] = RunFlight(1 if len(both.schedule.subchains[name].nodes) > 1 else 0, float(seq))
        with pytest.raises(ValueError, match="runs in flight"):
            compiled_state.install(both.schedule, both.side.wiring, both.side.book, both.side.levels, 0.0)
    finally:
        close(both)


def test_a_schedstat_line_is_read_as_the_python_side_reads_it() -> None:
    """kernel_ns parses a real thread's schedstat as catanc.runtime.linux.cpu_clocks does (the first field, ns)."""
    from catanc.runtime.linux.cpu_clocks import parse_schedstat

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
        assert cw.kernel_ns(walk, -1) == wa.NONE
    finally:
        os.close(fd)
