"""``catanc run``'s shared cores walked by compiled code between the loop's visits to Python (issue 31).

The Python objects stay the enforcer's state: :class:`~catanc.runtime.enforcer.cores.SharedCores` (the
cursors, who is raised), :class:`~catanc.runtime.enforcer.runs.RunBook` (runs in flight),
:class:`~catanc.runtime.linux.levels.Levels`, the rings' readers and the cost figures.  Before the loop
sleeps, :meth:`CompiledLoop.load` copies what may have changed into the walk's arrays
(:mod:`catanc.runtime.compiled.arrays`), laid out again only when the schedule or the node threads
changed; :meth:`CompiledLoop.wait` sleeps and walks compiled until Python's next own time
(housekeeping, a clock, the end), a readable descriptor, or something only Python can act on;
:meth:`CompiledLoop.store` copies the walk back and replays its log (samples, threads gone,
triggers not taken).  So everything else the enforcer does is unchanged, and a wake-up where
only the cores change costs no interpreter.
"""

from __future__ import annotations

import math
import select
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from catanc.control.schedule import RuntimeSchedule
from catanc.runtime.compiled import arrays as wa
from catanc.runtime.compiled import state as compiled_state
from catanc.runtime.compiled.entry import WalkEntry
from catanc.runtime.enforcer.cores import SharedCores
from catanc.runtime.enforcer.costs import SAMPLES, Costs
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import ComputeSample, HopSample, RunFlight, RunSample, Seen
from catanc.runtime.protocol.endpoints import Endpoint
from catanc.runtime.protocol.ring import RingReader

Untaken = Callable[[str], None]
"""A subchain whose head did not take its trigger (the send failed)."""


@dataclass
class _Layout:
    walk: wa.Walk
    names: tuple[str, ...]
    core_ids: tuple[int, ...]
    wiring: Wiring
    schedule: RuntimeSchedule  # the plan in force laid out (each subchain's latency, threads, clock period)
    generation: int  # of the kernel descriptors laid out
    versions: list[dict[int, object]]  # per version, per core: the CoreSchedule laid out there
    reader_nodes: list[str]
    reader_inside: list[bool]  # the reader's node is not its subchain's head (its hops are node to node)
    reader_after: list[str]  # the node before the reader's in its subchain ("" for a head)


class CompiledLoop:
    """The walk's arrays kept in step with the enforcer's Python state."""

    def __init__(
        self,
        cores: SharedCores,
        costs: Costs,
        seen: Seen,
        *,
        entry: WalkEntry,
        kernel_fd: compiled_state.KernelFd,
        gone: Callable[[list[int]], None],
        untaken: Untaken,
        fds_generation: Callable[[], int] = lambda: 0,
    ) -> None:
        self.cores, self.book, self.levels, self.costs, self.seen = cores, cores.book, cores.levels, costs, seen
        self.entry = entry
        self.kernel_fd, self.gone, self.untaken = kernel_fd, gone, untaken
        self.fds_generation = fds_generation  # kernel_fd's descriptors changed: the walk's copies are stale
        self.layout: _Layout | None = None
        self.broken = False  # the compiled wait refused the walk: Python's loop from then on
        self.polled = np.zeros(0, dtype=np.int32)
        self._fds: tuple[int, ...] = ()

    # ------------------------------------------------------------------ Python -> the walk

    def load(self, now_ms: float, clocks: list[tuple[float, str]]) -> bool:
        """Copy the Python state and the enforcer's ``clocks`` into the walk; False if the walk cannot take them
        (nothing to walk, or more than it holds): the loop stays in Python."""
        cores, wiring = self.cores, self.cores.wiring
        if wiring is None or cores.schedule is None or self.broken:
            return False
        layout = self.layout
        generation = self.fds_generation()
        if (
            layout is None
            or layout.wiring is not wiring
            or layout.generation != generation
            or layout.schedule is not cores.schedule  # a re-plan: rates, latencies, threads
            or not self._same_schedules(layout)
        ):
            try:
                layout = self.layout = self._lay_out(now_ms, wiring, generation)
            except ValueError:  # a layout the walk has no room for: these wake-ups stay in Python
                self.layout = None
                return False
        walk, names = layout.walk, layout.names
        book, levels = self.book, self.levels
        for s, name in enumerate(names):
            state = book.state(name)
            walk.seq[s], walk.late[s], walk.skipped[s] = state.seq, state.late, state.skipped
            walk.unmatched[s], walk.steals[s] = state.unmatched, state.steals
            walk.pending[s] = wa.NONE if state.pending is None else state.pending
            flights = state.in_flight
            if len(flights) >= wa.FLIGHTS - 2:
                return False  # more than the walk holds with room to spare (crowded()): this wake-up stays in Python
            k = 0
            for seq, flight in flights.items():
                walk.fl_seq[s, k], walk.fl_index[s, k], walk.fl_triggered[s, k] = seq, flight.index, flight.triggered_ms
                walk.fl_last_end[s, k] = math.nan if flight.last_end_ms is None else flight.last_end_ms
                walk.fl_until[s, k] = math.nan if flight.until_ms is None else flight.until_ms
                walk.fl_kernel[s, k] = wa.NONE if flight.kernel_ns is None else flight.kernel_ns
                k += 1
            walk.flying[s] = k
        for r, (_, endpoint, reader) in enumerate(self._readers(layout)):
            walk.r_last[r], walk.r_overrun[r] = reader.last, reader.overrun
            walk.r_kernel_mark[r] = wa.NONE if endpoint.kernel_mark_ns is None else endpoint.kernel_mark_ns
            walk.r_expected[r] = book.expected.get(endpoint.node, math.nan)
        index = {name: s for s, name in enumerate(names)}
        where = dict(enumerate(layout.core_ids))
        raised_on = {tid: c for c, core in where.items() for tid in levels.raised.get(core, ())}
        for h, tid in enumerate(walk.th_tid.tolist()):
            level = levels.level(tid)
            walk.th_level[h] = wa.NONE if level is None else level
            resting = levels.resting.get(tid)
            walk.th_resting[h] = wa.NONE if resting is None else resting
            walk.th_raised[h] = raised_on.get(tid, wa.NONE)
        for c, core_id in where.items():
            python = cores.cores[core_id]
            cursor = python.cursor
            walk.version[c] = self._version_of(layout, c, cursor.schedule)
            walk.start[c], walk.period_index[c], walk.position[c], walk.due[c] = (
                cursor.start_ms,
                cursor.index,
                cursor.position,
                cursor.due,
            )
            walk.wake[c] = python.wake_ms
            owner = cores.raised.get(core_id)
            walk.raised[c] = wa.NONE if owner is None else index[owner]
            walk.raised_from[c] = cores._raised_from.get(core_id, wa.NONE)
            walk.raised_count[c] = len(levels.raised.get(core_id, ()))
        walk.flags[wa.CALLS] = levels.calls
        walk.flags[wa.NEEDS_PYTHON] = 0
        try:
            compiled_state.set_clocks(walk, clocks, cores.schedule, names)
        except ValueError:
            return False
        return True

    def _same_schedules(self, layout: _Layout) -> bool:
        """Whether every core's current and latest schedule is laid out in the walk."""
        cores = self.cores
        if tuple(cores.cores) != layout.core_ids:
            return False
        for core_id in layout.core_ids:
            latest = cores.latest(core_id)
            laid = [version.get(core_id) for version in layout.versions]
            if cores.cores[core_id].cursor.schedule not in laid or (latest is not None and latest not in laid):
                return False
        return True

    def _version_of(self, layout: _Layout, c: int, schedule: object) -> int:
        core_id = layout.core_ids[c]
        for v, version in enumerate(layout.versions):
            if version.get(core_id) is schedule:
                return v
        raise AssertionError("checked by _same_schedules")  # pragma: no cover

    def _lay_out(self, now_ms: float, wiring: Wiring, generation: int) -> _Layout:
        """A new walk: version 0 the cores' latest schedules, version 1 those still in an older period."""
        cores = self.cores
        schedule = cores.schedule
        assert schedule is not None
        walk, names, core_ids = compiled_state.install(
            schedule, wiring, self.book, self.levels, now_ms, kernel_fd=self.kernel_fd
        )
        if core_ids != tuple(cores.cores):
            raise ValueError("the walk's cores are not the enforcer's")
        sub = {name: s for s, name in enumerate(names)}
        versions: list[dict[int, object]] = [{}, {}]
        for c, core_id in enumerate(core_ids):
            python = cores.cores[core_id]
            latest = cores.latest(core_id)
            versions[0][core_id] = latest
            current = python.cursor.schedule
            if current is not latest:  # the cursor's period still runs an older schedule, with its rules
                compiled_state.lay_out_core(walk, 1, c, current, rules=python.rules, sub=sub)
                versions[1][core_id] = current
        readers = [reader for name in names for reader in wiring.readers.get(name, ())]
        reader_nodes = [endpoint.node for _, endpoint, _ in readers]
        reader_inside = [index > 0 for index, _, _ in readers]
        reader_after = [
            schedule.subchains[name].nodes[index - 1] if index > 0 else ""
            for name in names
            for index, _, _ in wiring.readers.get(name, ())
        ]
        return _Layout(
            walk, names, core_ids, wiring, schedule, generation, versions, reader_nodes, reader_inside, reader_after
        )

    @staticmethod
    def _readers(layout: _Layout) -> list[tuple[int, Endpoint, RingReader]]:
        return [reader for name in layout.names for reader in layout.wiring.readers.get(name, ())]

    def run_due(self, now_ms: float, clocks: list[tuple[float, str]]) -> bool:
        """:meth:`SharedCores.run_due`, then the clocks due, compiled; False if the walk could not take it all
        (the caller does the rest in Python, as it would without the walk)."""
        if not self.load(now_ms, clocks):
            return False
        assert self.layout is not None
        try:
            status = self.entry.run_due(self.layout.walk, now_ms)
        except TypeError:  # as in wait: the walk's Python state is as it was, for the caller's Python walk
            self.broken = True
            return False
        self.store(clocks)
        return status == wa.DONE

    # ------------------------------------------------------------------ the wait

    def wait(self, fds: Sequence[int], until_ms: float) -> list[int]:
        """Sleep and walk until ``until_ms``; the descriptors of ``fds`` that are readable."""
        layout = self.layout
        assert layout is not None
        if tuple(fds) != self._fds:
            self._fds = tuple(fds)
            self.polled = np.zeros(2 * len(fds), dtype=np.int32)
            self.polled[0::2] = fds
            self.polled[1::2] = select.POLLIN
        try:
            status = self.entry.wait(layout.walk, self.polled, until_ms)
        except TypeError:  # a walk not laid out as the object file was compiled for (a bug): the loop stays in Python
            self.broken = True
            return []
        if status != wa.READY:
            return []
        return [fd for k, fd in enumerate(self._fds) if int(self.polled[2 * k + 1]) >> 16]

    # ------------------------------------------------------------------ the walk -> Python

    def store(self, clocks: list[tuple[float, str]]) -> None:
        """Copy the walk back into the Python state (``clocks``: the enforcer's, rewritten) and replay its log."""
        layout = self.layout
        assert layout is not None
        clocks[:] = compiled_state.get_clocks(layout.walk, layout.names)
        walk, names = layout.walk, layout.names
        cores, book, levels = self.cores, self.book, self.levels
        for s, name in enumerate(names):
            state = book.state(name)
            state.seq, state.late, state.skipped = int(walk.seq[s]), int(walk.late[s]), int(walk.skipped[s])
            state.unmatched, state.steals = int(walk.unmatched[s]), int(walk.steals[s])
            state.pending = None if walk.pending[s] == wa.NONE else int(walk.pending[s])
            old = state.in_flight
            flights = {}
            for k in sorted(range(int(walk.flying[s])), key=lambda k: int(walk.fl_seq[s, k])):
                seq = int(walk.fl_seq[s, k])
                flight = old.get(seq) or RunFlight(0, 0.0)
                flight.index, flight.triggered_ms = int(walk.fl_index[s, k]), float(walk.fl_triggered[s, k])
                last_end, until, kernel = walk.fl_last_end[s, k], walk.fl_until[s, k], int(walk.fl_kernel[s, k])
                flight.last_end_ms = None if math.isnan(last_end) else float(last_end)
                flight.until_ms = None if math.isnan(until) else float(until)
                flight.kernel_ns = None if kernel == wa.NONE else kernel
                flights[seq] = flight
            state.in_flight = flights
        for r, (_, endpoint, reader) in enumerate(self._readers(layout)):
            reader.last, reader.overrun = int(walk.r_last[r]), int(walk.r_overrun[r])
            mark = int(walk.r_kernel_mark[r])
            endpoint.kernel_mark_ns = None if mark == wa.NONE else mark
        raised: dict[int, set[int]] = {}
        for h, tid in enumerate(walk.th_tid.tolist()):
            level = int(walk.th_level[h])
            if level == wa.NONE:
                levels._level.pop(tid, None)
            else:
                levels._level[tid] = level
            c = int(walk.th_raised[h])
            if c != wa.NONE:
                raised.setdefault(layout.core_ids[c], set()).add(tid)
        for core_id in layout.core_ids:
            levels.raised.pop(core_id, None)
        for core_id, tids in raised.items():
            levels.raised[core_id] = tids
        levels.calls = int(walk.flags[wa.CALLS])
        for c, core_id in enumerate(layout.core_ids):
            python = cores.cores[core_id]
            cursor = python.cursor
            schedule = layout.versions[int(walk.version[c])][core_id]
            if (
                schedule is not cursor.schedule
            ):  # the core took the latest schedule: its rules as SharedCores makes them
                cursor.schedule = schedule  # type: ignore[assignment]
                fresh = cores._core(cursor)
                python.names, python.rules, python.watch, python.every = (
                    fresh.names,
                    fresh.rules,
                    fresh.watch,
                    fresh.every,
                )
            cursor.start_ms, cursor.index = float(walk.start[c]), int(walk.period_index[c])
            cursor.position, cursor.due = int(walk.position[c]), float(walk.due[c])
            python.wake_ms = float(walk.wake[c])
            owner = int(walk.raised[c])
            cores.raised[core_id] = None if owner == wa.NONE else names[owner]
            first = int(walk.raised_from[c])
            if first == wa.NONE:
                cores._raised_from.pop(core_id, None)
            else:
                cores._raised_from[core_id] = first
        cores.wake_ms = min((core.wake_ms for core in cores.cores.values()), default=math.inf)
        self.costs.wakes += int(walk.flags[wa.WAKES])
        walk.flags[wa.WAKES] = 0
        self._replay(layout)

    def _replay(self, layout: _Layout) -> None:
        """Hand the walk's log on, a kind at a time: a few hundred records a store, each kind in its order."""
        records = compiled_state.events(layout.walk)
        if not len(records):
            return
        kinds = records[:, 0]
        names, nodes, seen = layout.names, layout.reader_nodes, self.seen
        switches = records[kinds == wa.EV_SWITCH]
        for c, core_id in enumerate(layout.core_ids):
            latencies = switches[switches[:, 1] == c, 2]
            if len(latencies):
                samples = self.costs.switches.get(core_id)
                if samples is None:
                    samples = self.costs.switches[core_id] = deque(maxlen=SAMPLES)
                samples.extend(latencies.tolist())
        computes = records[kinds == wa.EV_COMPUTE]
        if len(computes):
            at, reader, threads = computes[:, 1].tolist(), computes[:, 2].astype(np.int64).tolist(), computes[:, 6]
            # NaN (unknown) as None, as the Python walk has it; object arrays keep the rows' floats as they are.
            values = computes[:, [3, 4, 5, 7]].astype(object)  # ms, reported, kernel, age
            values[np.isnan(computes[:, [3, 4, 5, 7]])] = None
            seen.computes.extend(
                ComputeSample(t, nodes[r], ms, reported, kernel, k, age)
                for t, r, (ms, reported, kernel, age), k in zip(
                    at, reader, values.tolist(), threads.astype(np.int64).tolist(), strict=True
                )
            )
        runs = records[kinds == wa.EV_RUN]
        if len(runs):
            book = self.book
            for t, s, seq, took in zip(
                runs[:, 1].tolist(),
                runs[:, 2].astype(np.int64).tolist(),
                runs[:, 3].astype(np.int64).tolist(),
                runs[:, 4].tolist(),
                strict=True,
            ):
                book.state(names[s]).ends_ms.append(t)
                seen.runs.append(RunSample(t, names[s], seq, took))
        hops = records[kinds == wa.EV_HOP]
        if len(hops):
            inside, after = layout.reader_inside, layout.reader_after
            seen.hops.extend(
                HopSample(names[s], nodes[r], delay, inside[r], after[r])
                for s, r, delay in zip(
                    hops[:, 1].astype(np.int64).tolist(),
                    hops[:, 2].astype(np.int64).tolist(),
                    hops[:, 3].tolist(),
                    strict=True,
                )
            )
        rare = records[(kinds == wa.EV_GONE) | (kinds == wa.EV_UNTAKEN)]
        gone = []
        for kind, a, b in rare[:, :3].tolist():
            if kind == wa.EV_GONE:
                tid = int(layout.walk.th_tid[int(a)])
                if not self.levels.set(tid, int(b)):  # refused for another reason: Levels says why (raises)
                    gone.append(tid)
            else:
                self.untaken(names[int(a)])
        if gone:
            self.gone(gone)
