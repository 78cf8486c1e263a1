"""The compiled walk's arrays and codes: :class:`Walk`, what its functions return and what its log records.

Shared by the walk compiled with numba (:mod:`catanc.runtime.compiled.walk`, which states what each
field means to a wake-up), the enforcer's Python state copied in and out
(:mod:`catanc.runtime.compiled.state`, :mod:`catanc.runtime.compiled.loop`) and the walk's object
code called from the enforcer (:mod:`catanc.runtime.compiled.entry`); this module imports no numba,
so an enforcer that loads the object code never does.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from catanc.control import slot_table
from catanc.runtime.protocol.ring import ENTRY_SIZE, HEADER_SIZE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

HEADER_WORDS = HEADER_SIZE // 8  # a ring's header and entries as uint64 words
ENTRY_WORDS = ENTRY_SIZE // 8

NONE = slot_table.NONE  # an integer that is not there (a subchain, a thread, a seq, a level)
FLIGHTS = 64
"""Runs in flight a subchain may have here; one more returns :data:`FULL` before its boundary."""
DATAGRAM = 128  # bytes of a trigger datagram, at most

# Event log records: (kind, a, b, c, d, e, f, g) as float64.
EV_COMPUTE = 1.0  # at_ms, reader, ms (nan: unknown), reported_ms (nan), kernel_ms (nan), threads, age_ms (nan)
EV_RUN = 2.0  # at_ms, subchain, seq, latency_ms
EV_HOP = 3.0  # subchain, reader, delay_ms
EV_SWITCH = 4.0  # core, latency_ms
EV_GONE = 5.0  # thread, level (it could not be set: gone, or refused; Python sets it again to say why)
EV_UNTAKEN = 6.0  # subchain: its head did not take its trigger (send failed)
EV_TRIGGER = 7.0  # subchain, seq, at_ms, deferred
EVENT_FIELDS = 8

# What run_due returns.
DONE, FULL, LOG_FULL = 0, 1, 2
TIME, READY = 10, 11  # what wait returns besides run_due's: Python's own time came, a descriptor is readable


class Walk(NamedTuple):
    """Everything :func:`run_due` reads and changes, built by :mod:`catanc.runtime.compiled.state`.

    Schedules are kept by version ``[V, C, ...]`` (a core keeps the version of its current
    period; a new one is taken at its next period).  Subchains ``S``, readers ``R`` (one per
    registered node thread with a ring, in node order per subchain), threads ``H`` (every
    thread a subchain may raise), cores ``C`` (the shared cores walked), slots ``M``.
    """

    # schedules, by version
    period: FloatArray  # [V, C]
    switch: FloatArray  # [V, C]
    nslots: IntArray  # [V, C]
    slot_start: FloatArray  # [V, C, M]
    slot_length: FloatArray  # [V, C, M]
    rule_sub: IntArray  # [V, C, M + 1]: the slot rules (catanc.control.slot_table)
    rule_every: IntArray  # [V, C, M + 1]
    rule_thieves: IntArray  # [V, C, M + 1, M]
    core_every: IntArray  # [V, C]: the longest trigger cycle of its rules, in periods
    # the cores' cursors
    latest: IntArray  # [C]: the version a core takes at its next period (NONE: keep its own)
    version: IntArray  # [C]
    start: FloatArray  # [C]: the current period's start
    period_index: IntArray  # [C]: periods since the cursor started
    position: IntArray  # [C]
    due: FloatArray  # [C]
    wake: FloatArray  # [C]
    raised: IntArray  # [C]: the subchain raised there (NONE: none)
    raised_from: IntArray  # [C]: its threads are raised from this node on (NONE: not yet)
    raised_count: IntArray  # [C]: threads raised above their resting level there
    # subchains
    latency: FloatArray  # [S]: planned (late beyond it: it steals)
    late_after: FloatArray  # [S]: a run that takes longer counts as late (SubchainRun.late_after_ms)
    length: IntArray  # [S]: its nodes
    shared: IntArray  # [S]: 1 if on a shared core
    seq: IntArray  # [S]: the last seq given
    pending: IntArray  # [S]: a deferred head trigger's seq (NONE: none)
    late: IntArray  # [S]
    skipped: IntArray  # [S]
    unmatched: IntArray  # [S]
    steals: IntArray  # [S]
    flying: IntArray  # [S]: runs in flight
    thief_late: IntArray  # [S]: 1 if late at the boundary being decided (only its thieves are marked)
    actions: IntArray  # [ACTIONS]: what the boundary decided (catanc.control.compiled_policy)
    # runs in flight, unordered: [S, FLIGHTS]
    fl_seq: IntArray
    fl_index: IntArray
    fl_triggered: FloatArray
    fl_last_end: FloatArray  # nan: none yet
    fl_until: FloatArray  # nan: none (hops do not measure the runtime)
    fl_kernel: IntArray  # the head thread's schedstat at the trigger (NONE: not checked)
    # readers (node threads with rings), per subchain in node order
    sub_readers: IntArray  # [S, 2]: first reader, how many
    r_index: IntArray  # [R]: its node's index in the subchain
    r_last: IntArray  # [R]: entries taken so far
    r_slots: IntArray  # [R]
    r_overrun: IntArray  # [R]
    r_kernel_fd: IntArray  # [R]: its thread's schedstat, opened (NONE: unknown)
    r_kernel_mark: IntArray  # [R]: its thread's CPU at the last suspicious report (NONE: none)
    r_expected: FloatArray  # [R]: its node's planning estimate (nan: none)
    r_speedup: FloatArray  # [R, Q + 1]: its speedup when a run says it used q threads (q >= Q: Q's)
    r_address: (
        IntArray  # [R]: where its ring is mapped (the reader keeps the mapping; the walk is laid out again first)
    )
    entries: npt.NDArray[np.uint64]  # [max slots * ENTRY_WORDS]: a ring's new entries, copied
    # threads
    th_tid: IntArray  # [H]
    th_level: IntArray  # [H]: as last set (NONE: unknown)
    th_resting: IntArray  # [H]: NONE if not placed
    th_raised: IntArray  # [H]: the core it is raised on (NONE: not raised)
    sub_threads: IntArray  # [S, N, 2]: from node n on, the threads' first position in `raise_order` and how many
    raise_order: IntArray  # thread indices, per subchain in node order
    # heads
    head_fd: IntArray  # [S]: its head's socket (NONE: no head to trigger, counted as skipped; -2: no socket)
    head_kernel_fd: IntArray  # [S]: the head thread's schedstat (NONE: unknown)
    head_datagram: npt.NDArray[np.uint8]  # [S, DATAGRAM]: "catanc/2 trigger NODE " then the seq and threads
    head_prefix: IntArray  # [S]: the prefix's length
    head_threads: IntArray  # [S]
    # clocks: subchains triggered every period on their own (dedicated, batch), not at a slot
    clk_sub: IntArray  # [S]: the clock's subchain ([:flags[CLOCKS]] are in use)
    clk_due: FloatArray  # [S]
    clk_period: FloatArray  # [S]
    clk_rank: IntArray  # [S]: its subchain's name's rank (equal times fire in name order, as a heap of (due, name))
    sub_core: IntArray  # [S]: the walked core a shared subchain runs on (NONE: none)
    # the machine and the log
    flags: IntArray  # [7]: rt, levels set, records logged, room a boundary needs, wake-ups, needs Python, clocks
    events: FloatArray  # [L, EVENT_FIELDS]
    scratch: IntArray  # [8]: a timespec [0:2], a sched_param [2], ppoll's timeout [4:6]
    text: npt.NDArray[np.uint8]  # [64]: a schedstat line


RT, CALLS, LOGGED, ROOM, WAKES, NEEDS_PYTHON, CLOCKS = 0, 1, 2, 3, 4, 5, 6  # NEEDS_PYTHON: a record only Python acts on


def wake_ms(walk: Walk) -> float:
    """When the walk next needs the loop (inf: never)."""
    return float(walk.wake.min()) if walk.wake.size else math.inf
