"""The enforcer's Python state kept in step with the compiled walk (catanc.runtime.compiled.loop), run for run.

Two copies of the enforcer's hot-path state over the same rings: one walked by SharedCores as
``catanc run`` does without the compiled loop, the other by :class:`CompiledLoop` (copied into
the walk, walked compiled, copied back, its log replayed).  After every wake-up their Python
objects must agree: the runs in flight and counters, what is raised, the levels, the samples,
the trigger datagrams and the next wake-up.  Re-solves, housekeeping reads and stretches walked
by Python in between (as the enforcer's loop does between compiled waits) change nothing.
"""

from __future__ import annotations

import contextlib
import heapq
import math
import os
import random
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("numba", reason="the compiled loop needs numba (the sim extra)")

from catanc.errors import LoopError
from catanc.runtime.compiled import arrays as wa
from catanc.runtime.compiled import ready as compiled_ready
from catanc.runtime.compiled.build import sample_walk
from catanc.runtime.compiled.entry import WalkEntry, describe, layout_of
from catanc.runtime.compiled.loop import CompiledLoop
from catanc.runtime.protocol import ring
from tests.support.hot_path import (
    Side,
    drained,
    fire_clocks,
    next_wake_up,
    random_schedule,
    report_runs,
    rescheduled,
    side,
)


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


def loop_of(one: Side, entry: WalkEntry) -> CompiledLoop:
    """``one``'s state walked by ``entry`` (no kernel CPU clocks; gone threads and untaken triggers noted)."""
    return CompiledLoop(
        one.cores,
        one.costs,
        one.seen,
        entry=entry,
        kernel_fd=lambda _endpoint: None,
        gone=one.gone.extend,
        untaken=one.untaken.append,
    )


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_loop_keeps_the_enforcers_state_as_the_python_walk_does(
    compiled_loop: WalkEntry, seed: int
) -> None:
    rng = random.Random(seed)
    schedule = random_schedule(rng, dedicated=True)
    fds = {node: ring.create(slots=rng.choice((4, 8, 64))) for run in schedule.subchains.values() for node in run.nodes}
    writers = {node: ring.RingWriter(fd) for node, fd in fds.items()}
    python = side(schedule, fds, random.Random(seed + 1))
    compiled = side(schedule, fds, random.Random(seed + 1))
    loop = loop_of(compiled, compiled_loop)
    clocks = ([(0.0, run.name) for run in schedule.clocked], [(0.0, run.name) for run in schedule.clocked])
    for heap in clocks:
        heapq.heapify(heap)
    try:
        now = 0.0
        for step in range(100):
            now = next_wake_up(rng, now, python.cores.wake_ms)
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


def test_the_entry_returns_at_once_when_its_time_is_past(compiled_loop: WalkEntry) -> None:
    """The object file's entry, linked without numba, walks a walk of nothing and comes back: its time is past."""
    from catanc.runtime.compiled.build import sample_walk

    walk = sample_walk()
    assert compiled_loop.wait(walk, np.zeros(0, dtype=np.int32), -math.inf) == wa.TIME
    assert compiled_loop.run_due(walk, 0.0) == wa.DONE


@contextlib.contextmanager
def one_loop(entry: WalkEntry, seed: int) -> Iterator[tuple[Side, CompiledLoop, list[tuple[float, str]]]]:
    """A random app's enforcer state with its compiled loop, and its clocks (its rings closed after)."""
    rng = random.Random(seed)
    schedule = random_schedule(rng, dedicated=True)
    fds = {node: ring.create() for run in schedule.subchains.values() for node in run.nodes}
    one = side(schedule, fds, rng)
    loop = loop_of(one, entry)
    try:
        yield one, loop, [(0.0, run.name) for run in schedule.clocked]
    finally:
        for thing in one.closing:
            thing.close()  # type: ignore[attr-defined]
        for fd in fds.values():
            os.close(fd)


def test_a_real_walk_has_the_layout_the_object_file_was_compiled_for(compiled_loop: WalkEntry) -> None:
    """Any app's walk is laid out as the build's sample walk (nodes whose estimates are whole numbers once made
    the expected times an integer array: numba compiled again, in the loop thread, at SCHED_FIFO)."""
    with one_loop(compiled_loop, 7) as (one, loop, clocks):
        nodes = [node for run in one.wiring.schedule.subchains.values() for node in run.nodes]
        one.book.expected = dict.fromkeys(nodes, 2)  # every node's compute_ms: 2
        assert loop.load(0.0, clocks)
        assert loop.layout is not None
        assert layout_of(loop.layout.walk) == compiled_loop.layout
        loop.wait([], -math.inf)
        assert not loop.broken


def test_a_walk_laid_out_otherwise_falls_back_to_python(compiled_loop: WalkEntry) -> None:
    """The object file reads each array as the dtype it was compiled for: a walk of other types makes the compiled
    loop give up (never a read of int64 as float64), and the enforcer's Python loop goes on."""
    with one_loop(compiled_loop, 11) as (_, loop, clocks):
        assert loop.load(0.0, clocks)
        assert loop.layout is not None
        loop.layout = replace(loop.layout, walk=loop.layout.walk._replace(latency=loop.layout.walk.latency.astype(int)))
        assert loop.wait([], -math.inf) == []
        assert loop.broken
        assert not loop.load(0.0, clocks)  # the caller's Python loop from now on


def test_a_walk_whose_array_is_not_contiguous_is_refused() -> None:
    """The entry reads each array as C-contiguous memory: a strided view would be read wrongly, so it is refused."""
    walk = sample_walk()
    layout = layout_of(walk)
    assert describe(walk, layout).size == sum(1 + array.ndim for array in walk)  # an address, then the shape
    strided = walk._replace(period=np.zeros((2, 4))[:, ::2])
    with pytest.raises(TypeError, match="contiguous"):
        describe(strided, layout)


def test_an_object_file_without_the_entry_is_a_load_error(compiled_loop: WalkEntry) -> None:
    found = compiled_ready.find()
    assert found is not None
    code, _, layout = found
    with pytest.raises(LoopError, match="has no no_such_entry"):
        WalkEntry(code, "no_such_entry", layout)
