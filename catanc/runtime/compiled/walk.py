"""The shared cores' walk compiled with numba: :class:`~catanc.runtime.enforcer.cores.SharedCores` over flat arrays.

Issue 31's compiled hot loop (docs/explanation/compiled-loop.md).  What one wake-up of the
enforcer does on its shared cores is said in Python by :mod:`catanc.runtime.enforcer.cores` (the boundary
walk, the slot owner, the levels, the slot-aligned triggers), :mod:`catanc.runtime.enforcer.runs` (the
rings read into runs in flight, every report checked and clamped) and
:mod:`catanc.control.policy` (the decisions); :func:`run_due` does exactly that, step for step,
over the arrays of one :class:`Walk`, so that a wake-up costs no interpreter.  The decision at a
boundary is :mod:`catanc.control.compiled_policy`'s, the simulator's kernel's too: this module
says who is late and carries its actions out with system calls.  The Python stays the readable
statement and the oracle: tests/runtime/test_compiled_walk.py holds the two to the same levels,
triggers, runs in flight and samples, boundary by boundary.

What needs Python is left to it, through :class:`Walk`'s event log (replayed at each return):
the samples (compute times, run latencies, hop delays, switch latencies) for the measurements
and the run log, the threads found gone, a level the kernel refused, a trigger the node did not
take.  The system calls are libc's, declared by name (numba caches the compiled function; a
ctypes pointer would tie it to one process): ``sched_setscheduler`` for the levels, ``send``
for the triggers, ``pread`` of a thread's opened ``schedstat`` for the kernel's CPU figures,
``clock_gettime`` for the switch latency.

:func:`fire_clocks` does what ``Enforcer._on_time`` does with its clocks, and :func:`wait` is the
``ppoll`` loop around both; :mod:`catanc.runtime.compiled.loop` keeps the enforcer's Python state
and these arrays in step (``catanc run --loop compiled``).
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

from catanc.control.compiled_policy import boundary_ms as slot_boundary_ms
from catanc.control.compiled_policy import decide, hand_over, thieves, triggers
from catanc.control.measure import CLIENT_WORK_MS, RECONCILE_ABS_TOL_MS, RECONCILE_REL_TOL
from catanc.control.slot_table import HANDOVER, RAISE, STEAL, TRIGGER
from catanc.model import priorities
from catanc.numba_cache import drop_stale_cache
from catanc.runtime.compiled import sources as compiled_sources
from catanc.runtime.compiled.arrays import (
    CALLS,
    CLOCKS,
    DONE,
    ENTRY_WORDS,
    EV_COMPUTE,
    EV_GONE,
    EV_HOP,
    EV_RUN,
    EV_SWITCH,
    EV_TRIGGER,
    EV_UNTAKEN,
    FLIGHTS,
    FULL,
    HEADER_WORDS,
    LOG_FULL,
    LOGGED,
    NEEDS_PYTHON,
    NONE,
    READY,
    ROOM,
    RT,
    TIME,
    WAKES,
    Walk,
)
from catanc.runtime.enforcer.runs import KERNEL_CHECK_EVERY, KERNEL_SLACK_MS, SUSPICIOUS
from catanc.runtime.protocol import ring

F = TypeVar("F", bound=Callable[..., Any])


def compiled(function: F) -> F:
    """numba's no-Python mode, cached on disk beside the module.

    numpy's error model: a division by zero gives inf or nan instead of raising, so the walk has no
    path that needs Python's exception machinery (the object code the enforcer loads runs without
    numba: :mod:`catanc.runtime.compiled.entry`)."""
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy")(function))


drop_stale_cache(Path(__file__), compiled_sources.SOURCES)

# libc, by name (pointers and sizes as 64-bit integers: the same registers on x86-64 and aarch64).
_sched_setscheduler = types.ExternalFunction("sched_setscheduler", types.intc(types.intc, types.intc, types.intp))
_send = types.ExternalFunction("send", types.intp(types.intc, types.intp, types.uintp, types.intc))
_pread = types.ExternalFunction("pread", types.intp(types.intc, types.intp, types.uintp, types.int64))
_clock_gettime = types.ExternalFunction("clock_gettime", types.intc(types.intc, types.intp))

SCHED_FIFO = os.SCHED_FIFO
MSG_DONTWAIT = int(socket.MSG_DONTWAIT)  # an int: numba compiles no IntFlag
CLOCK_MONOTONIC = time.CLOCK_MONOTONIC
RUNNING_FIFO = priorities.RUNNING_FIFO  # the slot owner's level
UNKNOWN = np.uint64(ring.UNKNOWN)  # a ring entry's compute_ns the node did not measure


@intrinsic  # type: ignore[untyped-decorator]
def _u64_pointer(_typingctx: Any, _address: Any) -> Any:
    """An integer address as a ``uint64*`` (not a typed list of the rings: numba compiles those in every process)."""
    signature = types.CPointer(types.uint64)(types.intp)

    def codegen(context: Any, builder: Any, _signature: Any, args: Any) -> Any:
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.uint64)))

    return signature, codegen


@compiled
def ring_words(w: Walk, r: int) -> Any:
    """Reader ``r``'s ring as uint64 words (its header, then its entries)."""
    return numba.carray(_u64_pointer(w.r_address[r]), HEADER_WORDS + w.r_slots[r] * ENTRY_WORDS)


@compiled
def boundary_ms(w: Walk, v: int, c: int, start: float, position: int) -> float:
    """:func:`catanc.control.policy.boundary_ms` for core ``c``'s schedule version ``v``."""
    return slot_boundary_ms(w.slot_start, w.slot_length, w.switch, w.nslots, v, c, start, position)


@compiled
def advance(w: Walk, c: int, now: float) -> None:
    """:meth:`catanc.control.policy.CoreCursor.advance` (the latest version taken at the period's end)."""
    v = w.version[c]
    if w.position[c] < w.nslots[v, c]:
        w.position[c] += 1
    else:
        period = w.period[v, c]
        start = w.start[c] + period
        skipped = max(0, math.floor((now - start) / period))
        w.start[c] = start + skipped * period
        w.period_index[c] += 1 + skipped
        w.position[c] = 0
        if w.latest[c] != NONE:
            w.version[c] = w.latest[c]
    w.due[c] = boundary_ms(w, w.version[c], c, w.start[c], w.position[c])


@compiled
def log(w: Walk, kind: float, a: float, b: float, c: float, d: float, e: float, f: float, g: float) -> None:
    k = w.flags[LOGGED]
    row = w.events[k]
    row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7] = kind, a, b, c, d, e, f, g
    w.flags[LOGGED] = k + 1


# --------------------------------------------------------------------------- runs in flight (RunBook)


@compiled
def slot_of(w: Walk, s: int, seq: int) -> int:
    for k in range(w.flying[s]):
        if w.fl_seq[s, k] == seq:
            return k
    return NONE


@compiled
def add_flight(w: Walk, s: int, seq: int, triggered: float, until: float) -> None:
    k = w.flying[s]
    w.fl_seq[s, k], w.fl_index[s, k], w.fl_triggered[s, k] = seq, 0, triggered
    w.fl_last_end[s, k], w.fl_until[s, k], w.fl_kernel[s, k] = math.nan, until, NONE
    w.flying[s] = k + 1


@compiled
def drop_flight(w: Walk, s: int, k: int) -> None:
    last = w.flying[s] - 1
    if k != last:
        w.fl_seq[s, k], w.fl_index[s, k], w.fl_triggered[s, k] = (
            w.fl_seq[s, last],
            w.fl_index[s, last],
            w.fl_triggered[s, last],
        )
        w.fl_last_end[s, k], w.fl_until[s, k], w.fl_kernel[s, k] = (
            w.fl_last_end[s, last],
            w.fl_until[s, last],
            w.fl_kernel[s, last],
        )
    w.flying[s] = last


@compiled
def is_late(w: Walk, s: int, now: float) -> bool:
    """:meth:`RunBook.late`: the oldest run in flight past the planned latency."""
    if w.flying[s] == 0:
        return False
    oldest = math.inf
    for k in range(w.flying[s]):
        oldest = min(oldest, w.fl_triggered[s, k])
    return bool(now - oldest > w.latency[s])


@compiled
def first_index(w: Walk, s: int) -> int:
    """:meth:`RunBook.first_index` (NONE: no run in flight)."""
    first = NONE
    for k in range(w.flying[s]):
        if first == NONE or w.fl_index[s, k] < first:
            first = w.fl_index[s, k]
    return first


@compiled
def busy(w: Walk, s: int) -> bool:
    return bool(w.flying[s] > 0 or w.pending[s] != NONE)


@compiled
def kernel_ns(w: Walk, fd: int) -> int:
    """A thread's CPU so far (ns) from its opened ``schedstat`` (NONE: unreadable)."""
    if fd < 0:
        return NONE
    got = _pread(fd, w.text.ctypes.data, w.text.size, 0)
    if got <= 0:
        return NONE
    value, digits = 0, 0
    for k in range(got):
        byte = w.text[k]
        if byte < 48 or byte > 57:
            break
        value = value * 10 + (byte - 48)
        digits += 1
    return value if digits > 0 and digits < 19 else NONE


@compiled
def trigger(w: Walk, s: int, now: float, until: float) -> None:
    """``Enforcer._trigger_head`` at a slot: :meth:`RunBook.trigger` (:meth:`Flights.start`), then the datagram."""
    fd = w.head_fd[s]
    if fd == NONE:
        w.skipped[s] += 1
        return
    if w.flying[s] > 0:
        until = math.nan
    head_busy = False
    for k in range(w.flying[s]):
        if w.fl_index[s, k] == 0:
            head_busy = True
    deferred = False
    if head_busy:
        if w.pending[s] != NONE:
            return
        w.skipped[s] += 1
        w.seq[s] += 1
        w.pending[s] = w.seq[s]
        deferred = True
    elif w.pending[s] != NONE:  # its head run vanished (lost): the deferred trigger, sent already, starts it
        add_flight(w, s, w.pending[s], now, until)
        w.pending[s] = NONE
        return
    else:
        w.seq[s] += 1
        add_flight(w, s, w.seq[s], now, until)
        if w.seq[s] % KERNEL_CHECK_EVERY == 0:
            w.fl_kernel[s, w.flying[s] - 1] = kernel_ns(w, w.head_kernel_fd[s])
    seq = w.seq[s]
    log(w, EV_TRIGGER, s, seq, now, 1.0 if deferred else 0.0, 0.0, 0.0, 0.0)
    if fd < 0 or not send_trigger(w, s, seq):  # a head without a socket takes no triggers either
        log(w, EV_UNTAKEN, s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        w.flags[NEEDS_PYTHON] = 1


@compiled
def put_decimal(buffer: Any, at: int, value: int) -> int:
    """``value`` (>= 0) in decimal into ``buffer`` from ``at``; where it ends."""
    digits = 1
    rest = value
    while rest >= 10:
        rest //= 10
        digits += 1
    for k in range(digits - 1, -1, -1):
        buffer[at + k] = 48 + value % 10
        value //= 10
    return at + digits


@compiled
def send_trigger(w: Walk, s: int, seq: int) -> bool:
    buffer = w.head_datagram[s]
    end = put_decimal(buffer, w.head_prefix[s], seq)
    buffer[end] = 32
    end = put_decimal(buffer, end + 1, w.head_threads[s])
    return bool(_send(w.head_fd[s], buffer.ctypes.data, end, MSG_DONTWAIT) == end)


@compiled
def reconcile(reported: float, kernel: float) -> float:
    """:func:`catanc.control.measure.reconcile` (nan: unknown)."""
    if math.isnan(kernel) or not math.isfinite(kernel) or kernel < 0:
        return reported
    if math.isnan(reported) or not math.isfinite(reported) or reported < 0:
        return kernel
    tol = max(RECONCILE_ABS_TOL_MS, RECONCILE_REL_TOL * kernel)
    if kernel - CLIENT_WORK_MS - tol <= reported <= kernel + tol:
        return reported
    return kernel


@compiled
def head_again(w: Walk, s: int, seq: int) -> bool:
    if w.pending[s] != NONE:
        return True
    for k in range(w.flying[s]):
        if w.fl_seq[s, k] != seq and w.fl_index[s, k] == 0:
            return True
    return False


@compiled
def take(w: Walk, s: int, r: int, entry: int, now: float, last: bool) -> None:
    """:meth:`RunBook._take`: one entry of reader ``r``'s ring (copied to ``entries`` at ``entry``) moves its run on."""
    words = w.entries
    index = w.r_index[r]
    seq = int(np.int64(words[entry]))  # numba mixes uint64 with int64 into float64: signed at once
    delivered = False  # a message's hop into a node that runs on its input (RunBook._take)
    if seq != 0:
        k = slot_of(w, s, seq)
        if k == NONE or w.fl_index[s, k] != index:
            w.unmatched[s] += 1
            return
    else:  # a run nothing triggered: the one its data came from, else the oldest waiting at this node
        k = NONE
        sensed = NONE
        waiting = 0
        origin_ms = float(words[entry + 5]) / 1e6
        for j in range(w.flying[s]):
            if w.fl_index[s, j] != index:
                continue
            waiting += 1
            if (
                k == NONE
                or w.fl_triggered[s, j] < w.fl_triggered[s, k]
                or (w.fl_triggered[s, j] == w.fl_triggered[s, k] and w.fl_seq[s, j] < w.fl_seq[s, k])
            ):
                k = j
            if (
                words[entry + 5] != 0
                and w.fl_triggered[s, j] <= origin_ms
                and (
                    sensed == NONE
                    or w.fl_triggered[s, j] > w.fl_triggered[s, sensed]
                    or (w.fl_triggered[s, j] == w.fl_triggered[s, sensed] and w.fl_seq[s, j] > w.fl_seq[s, sensed])
                )
            ):
                sensed = j
        if k == NONE:
            w.unmatched[s] += 1
            return
        if sensed != NONE:
            k = sensed
        seq = w.fl_seq[s, k]
        delivered = index > 0 and (sensed != NONE or waiting == 1)
    triggered = w.fl_triggered[s, k]
    start_ms = min(max(float(words[entry + 1]) / 1e6, triggered), now)
    end_ms = min(max(float(words[entry + 2]) / 1e6, start_ms), now)
    before = w.fl_last_end[s, k] if index > 0 else triggered
    until = w.fl_until[s, k]
    if not math.isnan(before) and not math.isnan(until) and (delivered or start_ms <= until):
        log(w, EV_HOP, s, r, max(start_ms - before, 0.0), 0.0, 0.0, 0.0, 0.0)
    threads = int(np.int64(words[entry + 4] & np.uint64(0xFFFFFFFF)))
    own = math.nan if words[entry + 3] == UNKNOWN else float(words[entry + 3]) / 1e6
    elapsed = max(now - triggered, 0.0)
    compute = math.nan if math.isnan(own) else min(own, elapsed)
    expected = w.r_expected[r]
    if not math.isnan(compute) and threads <= 1 and not math.isnan(expected) and compute > SUSPICIOUS * expected:
        mark_now = kernel_ns(w, w.r_kernel_fd[r])
        if mark_now != NONE:
            mark = w.r_kernel_mark[r]
            w.r_kernel_mark[r] = mark_now
            if mark != NONE and mark_now >= mark:
                compute = min(compute, (mark_now - mark) / 1e6 + KERNEL_SLACK_MS)
    kernel_ms = math.nan
    if index == 0 and w.fl_kernel[s, k] != NONE and last and not head_again(w, s, seq):
        after = kernel_ns(w, w.r_kernel_fd[r])
        if after != NONE and after >= w.fl_kernel[s, k]:
            kernel_ms = (after - w.fl_kernel[s, k]) / 1e6
        compute = kernel_ms if math.isnan(compute) else reconcile(compute, kernel_ms)
    if not math.isnan(compute) and threads > 1:
        speedups = w.r_speedup[r]
        compute *= speedups[min(threads, speedups.size - 1)]
    origin = words[entry + 5]  # CLOCK_MONOTONIC ns; 0: none, then a head's start (RunBook._take's run_age_ms)
    origin_ms = float(origin) / 1e6 if origin != 0 else (start_ms if index == 0 else math.nan)
    age_ms = math.nan if math.isnan(origin_ms) else max(end_ms - origin_ms, 0.0)
    log(w, EV_COMPUTE, end_ms, r, compute, own, kernel_ms, float(max(threads, 1)), age_ms)
    head_done = w.fl_index[s, k] == 0
    flight_until = w.fl_until[s, k]
    if w.fl_index[s, k] + 1 < w.length[s]:
        w.fl_index[s, k] += 1
        w.fl_last_end[s, k] = end_ms
    else:
        drop_flight(w, s, k)
        took = end_ms - triggered
        if took > w.late_after[s]:
            w.late[s] += 1
        log(w, EV_RUN, end_ms, s, seq, took, 0.0, 0.0, 0.0)
    if head_done and w.pending[s] != NONE:  # a trigger that came while the head ran starts now
        add_flight(w, s, w.pending[s], end_ms, flight_until if w.shared[s] == 0 else math.nan)
        w.pending[s] = NONE


@compiled
def read(w: Walk, s: int, now: float) -> None:
    """:meth:`RunBook.read`: the new entries of subchain ``s``'s rings (:meth:`RingReader.new`), in node order."""
    first, many = w.sub_readers[s, 0], w.sub_readers[s, 1]
    for r in range(first, first + many):
        words = ring_words(w, r)
        written = np.int64(words[2])
        last = w.r_last[r]
        if written == last:
            continue
        if written < last:  # a node that rewound its counter: start over from it
            w.r_last[r] = written
            continue
        slots = w.r_slots[r]
        begin = max(last, written - slots)
        w.r_overrun[r] += begin - last
        copied = w.entries
        for k in range(begin, written):  # copied first: a writer may overtake the reader meanwhile
            at = HEADER_WORDS + (k % slots) * ENTRY_WORDS
            for j in range(ENTRY_WORDS):
                copied[(k - begin) * ENTRY_WORDS + j] = words[at + j]
        again = np.int64(words[2])
        w.r_last[r] = written
        for k in range(max(begin, again - slots), written):  # those it overwrote are dropped
            take(w, s, r, (k - begin) * ENTRY_WORDS, now, k == written - 1)


# --------------------------------------------------------------------------- levels (Levels)


@compiled
def set_level(w: Walk, h: int, level: int) -> bool:
    """:meth:`Levels.set`; False (logged) if the kernel refused: the thread is gone, or Python says why."""
    if w.flags[RT] == 0 or w.th_level[h] == level:
        return True
    w.flags[CALLS] += 1
    w.scratch[2] = level
    param = w.scratch.ctypes.data + 16
    if _sched_setscheduler(w.th_tid[h], SCHED_FIFO, param) != 0:
        w.th_level[h] = NONE
        log(w, EV_GONE, h, level, 0.0, 0.0, 0.0, 0.0, 0.0)
        w.flags[NEEDS_PYTHON] = 1
        return False
    w.th_level[h] = level
    return True


@compiled
def lower_on(w: Walk, c: int) -> None:
    """:meth:`Levels.lower_on`: every thread raised on core ``c`` back to its resting level."""
    for h in range(w.th_tid.size):
        if w.th_raised[h] == c:
            w.th_raised[h] = NONE
            if w.th_resting[h] != NONE:
                set_level(w, h, w.th_resting[h])
    w.raised_count[c] = 0


@compiled
def raise_owner(w: Walk, c: int, triggered: bool) -> None:
    """:meth:`SharedCores.raise_owner`: a hand-over's actions (``w.actions``) carried out on core ``c``."""
    if w.actions[HANDOVER] != 0:
        w.raised_from[c] = NONE
        if w.raised_count[c] > 0:
            lower_on(w, c)
    owner = w.actions[RAISE]
    if owner == NONE:
        return
    first = 0 if triggered else first_index(w, owner)
    if first == NONE or (w.raised_from[c] != NONE and w.raised_from[c] <= first):
        return
    if first < w.length[owner]:
        w.raised_from[c] = first
        begin, many = w.sub_threads[owner, first, 0], w.sub_threads[owner, first, 1]
        for j in range(begin, begin + many):
            h = w.raise_order[j]
            if set_level(w, h, RUNNING_FIFO) and w.th_raised[h] != c:
                if w.th_raised[h] != NONE:
                    w.raised_count[w.th_raised[h]] -= 1
                w.th_raised[h] = c
                w.raised_count[c] += 1


# --------------------------------------------------------------------------- the walk (SharedCores)


@compiled
def monotonic_ms(w: Walk) -> float:
    _clock_gettime(CLOCK_MONOTONIC, w.scratch.ctypes.data)
    return float((w.scratch[0] * 1_000_000_000 + w.scratch[1]) / 1e6)


@compiled
def boundary(w: Walk, c: int, now: float, sample: bool) -> None:
    """:meth:`SharedCores._boundary`."""
    v, position = w.version[c], w.position[c]
    sub = w.rule_sub[v, c, position]
    if sub != NONE:  # who is late, and how far the runs got: what the rings say now
        raised = w.raised[c]
        count = thieves(w.rule_thieves, v, c, position)
        for t in range(count):
            thief = w.rule_thieves[v, c, position, t]
            if pending_entries(w, thief):
                read(w, thief, now)
        if pending_entries(w, sub):
            read(w, sub, now)
        if raised != NONE and pending_entries(w, raised):
            read(w, raised, now)
        for t in range(count):
            thief = w.rule_thieves[v, c, position, t]
            w.thief_late[thief] = 1 if is_late(w, thief, now) else 0
    actions = w.actions
    decide(
        w.rule_sub, w.rule_every, w.rule_thieves, v, c, position, w.period_index[c], w.thief_late, w.raised, c, actions
    )
    owner, trig = actions[RAISE], actions[TRIGGER]
    if actions[STEAL] != 0:
        w.steals[owner] += 1
    calls = w.flags[CALLS]
    raise_owner(w, c, trig != NONE and trig == owner)
    if trig != NONE:
        until = math.nan
        if owner == trig:
            until = w.slot_start[v, c, position] + w.slot_length[v, c, position] + w.start[c]
        trigger(w, trig, now, until)
    if sample and (trig != NONE or w.flags[CALLS] != calls):
        log(w, EV_SWITCH, c, monotonic_ms(w) - w.due[c], 0.0, 0.0, 0.0, 0.0, 0.0)


@compiled
def pending_entries(w: Walk, s: int) -> bool:
    """Whether some ring of ``s`` has entries not taken yet (one memory read a ring)."""
    first, many = w.sub_readers[s, 0], w.sub_readers[s, 1]
    for r in range(first, first + many):
        if np.int64(ring_words(w, r)[2]) != w.r_last[r]:
            return True
    return False


@compiled
def next_wake(w: Walk, c: int) -> float:
    """:meth:`SharedCores._wake`."""
    v = w.version[c]
    n = w.nslots[v, c]
    for j in range(n):
        if busy(w, w.rule_sub[v, c, j]):
            return float(w.due[c])
    if w.raised_count[c] > 0:
        w.raised_from[c] = NONE
        lower_on(w, c)
    same = w.latest[c] == v
    position, index, start = w.position[c], w.period_index[c], w.start[c]
    for _ in range((w.core_every[v, c] + 1) * (n + 1)):
        if triggers(w.rule_every, v, c, position, index):
            return boundary_ms(w, v, c, start, position)
        position += 1
        if position > n:
            if not same:
                return float(start + w.period[v, c])
            position, index, start = 0, index + 1, start + w.period[v, c]
    return math.inf


@compiled
def crowded(w: Walk) -> bool:
    """Whether some subchain has so many runs in flight that a boundary or a clock could overflow its row: one
    may add a trigger's run to its own subchain and, reading the rings of others (thieves, the raised one),
    one run that waited for each head."""
    for s in range(w.flying.size):
        if w.flying[s] >= FLIGHTS - 2:
            return True
    return False


@compiled
def run_due(w: Walk, now: float) -> int:
    """:meth:`SharedCores.run_due`: every boundary due by ``now``, in order, on every core.

    Returns :data:`DONE`, or before a boundary that could not be handled here: :data:`FULL` (its
    subchain has :data:`FLIGHTS` runs in flight) or :data:`LOG_FULL` (the event log needs reading).
    """
    for c in range(w.due.size):
        if w.due[c] > now:
            continue
        planned = w.wake[c]
        while w.due[c] <= now:
            if w.flags[LOGGED] + w.flags[ROOM] > w.events.shape[0]:
                return LOG_FULL
            if crowded(w):
                return FULL
            boundary(w, c, now, w.due[c] >= planned)
            advance(w, c, now)
        w.wake[c] = next_wake(w, c)
    return DONE


@compiled
def next_clock(w: Walk) -> int:
    """The clock that fires first (by time, then name; NONE: no clock)."""
    best = NONE
    for k in range(w.flags[CLOCKS]):
        if (
            best == NONE
            or w.clk_due[k] < w.clk_due[best]
            or (w.clk_due[k] == w.clk_due[best] and w.clk_rank[k] < w.clk_rank[best])
        ):
            best = k
    return best


@compiled
def fire_clocks(w: Walk, now: float) -> int:
    """``Enforcer._on_time``'s clocks: every clock due by ``now`` triggers its subchain's head (a dedicated one
    runs raised for good), then fires next a period later (or now, if it fell behind).  Returns
    :data:`DONE`, or :data:`FULL`/:data:`LOG_FULL` before a clock that could not be handled here."""
    shared = False
    while True:
        k = next_clock(w)
        if k == NONE or w.clk_due[k] > now:
            break
        s = w.clk_sub[k]
        if crowded(w):
            return FULL
        if w.flags[LOGGED] + w.flags[ROOM] > w.events.shape[0]:
            return LOG_FULL
        if w.head_fd[s] == NONE:
            w.skipped[s] += 1
        else:  # Enforcer._trigger_head off a slot: is the head still busy? keep its threads raised if it owns the core
            read(w, s, now)
            c = w.sub_core[s]
            if w.shared[s] == 1 and c != NONE and w.raised[c] == s:
                hand_over(w.raised, c, s, w.actions)
                raise_owner(w, c, True)
            trigger(w, s, now, math.nan if w.shared[s] == 1 else math.inf)
        w.clk_due[k] = max(w.clk_due[k] + w.clk_period[k], now)
        shared = shared or w.shared[s] == 1
    if shared:  # a core with a run in flight needs its boundaries again
        rewake(w)
    return DONE


@compiled
def rewake(w: Walk) -> None:
    """:meth:`SharedCores.rewake`."""
    for c in range(w.due.size):
        w.wake[c] = next_wake(w, c)


# --------------------------------------------------------------------------- the loop between Python's visits

_ppoll = types.ExternalFunction("ppoll", types.intc(types.intp, types.uintp, types.intp, types.intp))


@compiled
def wait(w: Walk, polled: Any, until: float) -> int:
    """Walk the shared cores until ``until`` (ms, CLOCK_MONOTONIC), sleeping in ``ppoll`` on ``polled``.

    ``polled`` is an array of ``struct pollfd`` as int32 pairs (the descriptor; events in the low
    half of the second word, revents in the high half).  Returns :data:`TIME`, :data:`READY` (some
    revents set), or a status of :func:`run_due`; also as soon as a record only Python can act on
    (a thread gone, a trigger not taken) was logged.
    """
    count = polled.size // 2
    while True:
        now = monotonic_ms(w)
        if now >= until:
            return TIME
        deadline = min(until, wake_of(w))
        k = next_clock(w)
        if k != NONE:
            deadline = min(deadline, w.clk_due[k])
        rest = max(deadline - now, 0.0)
        nanos = int(rest * 1e6)
        w.scratch[4], w.scratch[5] = nanos // 1_000_000_000, nanos % 1_000_000_000
        for k in range(count):
            polled[2 * k + 1] &= 0xFFFF
        _ppoll(polled.ctypes.data, count, w.scratch.ctypes.data + 32, 0)
        w.flags[WAKES] += 1
        now = monotonic_ms(w)
        status = run_due(w, now)
        if status == DONE:
            status = fire_clocks(w, now)
        if status != DONE:
            return status
        for k in range(count):
            if polled[2 * k + 1] >> 16 != 0:
                return READY
        if w.flags[NEEDS_PYTHON] != 0:
            return DONE


@compiled
def wake_of(w: Walk) -> float:
    soonest = math.inf
    for c in range(w.wake.size):
        soonest = min(soonest, w.wake[c])
    return soonest
