"""The simulation loop compiled with numba: the same model as the Python engine, over flat arrays.

:mod:`catanc.sim.engine`, :mod:`~catanc.sim.dataflow` and
:mod:`~catanc.sim.policies` say what is simulated; this module does
exactly that, step for step, so fast that nav2d runs thousands of times
faster than real time (issue 7).  The Python objects stay as the readable
statement and as this kernel's oracle: tests hold the two to the same
results on the example specs and on random apps (tests/sim/test_kernel.py).
Keep them in step: a change to one is a change to both.  The slot rule
itself is not copied: :func:`switch` asks :mod:`catanc.control.compiled_policy`,
as the enforcer's compiled walk does, and carries the actions out on job
priorities.

Every function here mirrors one Python method, named alike.  The same
operations in the same order give the same floating-point results, and
events at one time run in the order they were scheduled, as in
:class:`~catanc.sim.engine.Engine`.  One thing is done differently,
with the same result: the Python outputs carry their chains' origins, the
kernel's runs note what they read and :func:`chain_arrivals` follows the
notes back after the run.

The kernel runs until the end time, or returns early when the policy must
re-solve (``REOPTIMISE_NOW``: Python plans, then resumes it) or a node is
about to run out of compute times drawn in advance (``NEED_DRAWS``).
Everything it knows is in one :class:`Sim` (built by
:mod:`catanc.sim.fast`): stopping and resuming between two loop turns
changes nothing.  numba does not check indices: the arrays grow before an
event could overrun them (:func:`make_room`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeAlias, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
from numba.experimental import structref

from catanc.control import compiled_policy
from catanc.control import slot_table as act
from catanc.control.compiled_policy import boundary_ms as slot_boundary_ms
from catanc.control.compiled_policy import decide, hand_over, thieves
from catanc.control.slot_table import NONE
from catanc.numba_cache import drop_stale_cache
from catanc.sim import cpu, policies
from catanc.sim.cpu import DONE_EPS_MS
from catanc.sim.policies import DEDICATED, RAISED, RESTING_SHARED

F = TypeVar("F", bound=Callable[..., Any])

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def compiled(function: F) -> F:
    """numba's no-Python mode, cached on disk beside the module: a function of its own."""
    return cast(F, numba.njit(cache=True, nogil=True)(function))


def inlined(function: F) -> F:
    """A small or per-turn helper that numba inlines into its callers (its own IR, before LLVM).

    A call passes :class:`Sim` and its arrays with reference counts around
    it, which LLVM does not remove across calls: inlining the engine's small
    helpers and the per-turn ``advance_to``, ``allocate``, ``dispatch``,
    ``read_inputs`` and ``produce`` saves 11-12% of the kernel's
    instructions for ~6 s more of a fresh compile.  Inlining the policies'
    helpers too saved 3% more for ~45 s more (benchmarks/RESULTS.md, eleventh
    pass), so they stay calls.
    """
    return cast(F, numba.njit(cache=True, nogil=True, inline="always")(function))


# numba reads the cache at a function's first call (see numba_cache); the constants compiled in come from these
COMPILED_FROM = (*compiled_policy.COMPILED_FROM, *(Path(str(module.__file__)) for module in (cpu, policies)))
drop_stale_cache(Path(__file__), COMPILED_FROM)


# Event kinds (an event is (time, order, kind, a, b, c, d, e, f): what a kind needs of a..f).
SENSOR, TIMER, CLOCK, BEGIN, SWITCH, LOWER, REOPTIMISE = 0, 1, 2, 3, 4, 5, 6

# What run() returns.
FINISHED, REOPTIMISE_NOW, NEED_DRAWS = 0, 1, 2

# Policies.
CATAN, CATAN_MEASURED, TIMER_FAIR, TIMER_FIFO = 0, 1, 2, 3

NO_SEQ = -1
ROOM_TURNS = 64  # loop turns that make_room leaves room for


@structref.register
class SimType(numba.types.StructRef):  # type: ignore[misc]
    """numba's type of :class:`Sim`."""

    def preprocess_fields(self, fields: Any) -> Any:
        return tuple((name, numba.types.unliteral(typ)) for name, typ in fields)


class SimProxy(structref.StructRefProxy):  # type: ignore[misc]
    """One simulation's arrays and counters, passed to every kernel function by reference.

    One mutable struct instead of tuples of arrays: numba passes a tuple by
    value, flattened into every call's arguments, which cost microseconds per
    call (measured: 3 us for a loop over 12 nodes).  Fields, by group (CSR
    means ``x_ptr[i]:x_ptr[i+1]`` indexes ``x``; nodes are numbered in spec
    order, subchains in sorted name order):

    The graph (fixed): ``scheduled``, ``pass_through`` (unscheduled without a
    rate), ``pred_ptr/pred``, ``succ_ptr/succ``, ``feed_ptr/feed`` (the nodes
    just before a node on the measured chains: a run notes which of their
    outputs it read), ``sub_of`` per node,
    ``sub_ptr/sub_nodes``, ``sensor_period`` (NaN if not a sensor) and
    ``sensor_order`` (spec order), ``timer_period``/``timer_order``/``trig_ptr``/
    ``trig``/``priority`` (the baselines' wiring), ``cores``, ``executor_of``
    (per node, its executor's number, -1 for none: :mod:`catanc.sim.threads`).

    The schedules, by version ``[V, ...]`` (a switch keeps the version it was
    scheduled in): ``sub_ncores``, ``sub_cores``, ``sub_shared``,
    ``sub_period``, ``sub_latency`` (late beyond it: it steals), ``sub_late_after`` (a run that takes longer
    counts as late: :attr:`~catanc.control.schedule.SubchainRun.late_after_ms`), ``sub_runs`` (-1: own clock),
    ``node_threads``, ``node_speedup``, ``clocked`` (in the
    schedule's order, then -1), ``n_shared``, ``core_id``, ``core_period``,
    ``core_switch``, ``core_nslots``, ``slot_start``, ``slot_length``, and the slot rules
    ``rule_sub``, ``rule_every``, ``rule_thieves`` (:mod:`catanc.control.slot_table`; a version's rules
    are those of its slots under the subchains of the version in force, as the Python policy asks
    :func:`~catanc.control.policy.slot_rules` at a switch).

    The draws (:class:`catanc.model.workload.NodeStream` values, drawn ahead):
    ``mode``/``factor`` ``[N, width]`` (rings: run ``j`` of a node at ``j % width``), ``used``, ``filled`` (runs
    taken and drawn, ever), ``spike_at``
    (padded with inf), ``spike_next``, ``spike_ms``, ``has_growth``, ``growth``.

    The run: the counters ``now``, ``order``, ``arrival``, ``generation``,
    ``version``, ``policy``, ``pools``; the event heap (``heap_*``: time, order, kind and its fields); one job per
    node at most (``job_*``); pools of cores (``pool_*``, ``sub_pool``,
    ``core_busy``); the data (``latest_id``: a node's newest output as its
    completion record, -1 before its first; ``latest_at``; ``job_feed`` by feed,
    ``job_read_at``: what a run read and when); catanc's runs (``busy_seq``, the ``wait`` rings,
    ``sub_*`` counters, ``heads_in_flight``, the ``flight_*`` rings by seq,
    ``raised`` per core); the baselines' ``timer_busy`` and ``timer_pending``;
    per executor the node it runs (``exec_running``, -1: free) and the runs
    waiting for it (``exec_wait_node/seq`` rings with ``exec_wait_head/tail``);
    scratch (``finished``, ``sort_buf``, ``stack``); the records with their
    counts (``done_*`` with ``done_feeds``/``feeds_n``, ``stale_*``), grown here
    as they fill; and ``measured_*``: per node a ring of its last ``window``
    measured compute times, with the runs measured ever and at the last
    :func:`take_measured`.
    """


FIELDS = (
    # the graph
    "scheduled", "pass_through", "pred_ptr", "pred", "succ_ptr", "succ", "feed_ptr", "feed", "sub_of", "sub_ptr",
    "sub_nodes", "sensor_period", "sensor_order", "timer_period", "timer_order", "trig_ptr", "trig", "priority",
    "cores", "executor_of",
    # the schedules
    "sub_ncores", "sub_cores", "sub_shared", "sub_period", "sub_latency", "sub_late_after", "sub_runs",
    "node_threads", "node_speedup", "clocked", "n_shared", "core_id", "core_period", "core_switch",
    "core_nslots", "slot_start", "slot_length", "rule_sub", "rule_every", "rule_thieves",
    # the draws
    "mode", "factor", "used", "filled", "spike_at", "spike_next", "spike_ms", "has_growth", "growth",
    # the run
    "now", "order", "arrival", "generation", "version", "policy", "pools",
    "heap_n", "heap_time", "heap_order", "heap_ints", "heap_f",
    "job_pool", "job_remaining", "job_threads", "job_priority", "job_since", "job_speed", "job_seq", "job_compute",
    "job_feed", "job_read_at", "pool_ncores", "pool_cores", "pool_fair", "pool_jobs", "pool_njobs", "pool_busy",
    "pool_dirty", "sub_pool", "core_busy", "finished", "sort_buf", "stack", "latest_id", "latest_at",
    "busy_seq", "wait", "wait_head", "wait_tail", "sub_seq", "sub_pending", "sub_late", "sub_steals", "sub_skipped",
    "heads_in_flight", "flight_index", "flight_at", "flight_live", "flight_low", "raised", "thief_late", "actions",
    "timer_busy",
    "timer_pending", "exec_running", "exec_wait_node", "exec_wait_seq", "exec_wait_head", "exec_wait_tail",
    "done_n", "done_node", "done_at", "done_read", "feeds_n", "done_feeds", "stale_n", "stale_node",
    "stale_ms", "measured_ring", "measured_total", "measured_taken",
)  # fmt: skip
structref.define_constructor(SimProxy, SimType, FIELDS)
structref.define_boxing(SimType, SimProxy)


@compiled
def new_sim(*fields: Any) -> Any:
    """A :class:`SimProxy` of ``fields`` (in :data:`FIELDS` order), built by a cached function.

    ``SimProxy(*fields)`` would compile numba's constructor for ~140 fields in every process (7 s).
    """
    return SimProxy(*fields)


Sim: TypeAlias = Any
"""A :class:`SimProxy` in annotations: numba types its fields; to mypy the struct is opaque."""


# --------------------------------------------------------------------------- the engine


@inlined
def at(sim: Sim, when_ms: float, kind: int, a: int, b: int, c: int, d: int, e: int, f: float) -> None:
    order = sim.order
    sim.order = order + 1
    when = max(when_ms, sim.now)
    if sim.heap_n == sim.heap_time.shape[0]:
        size = 2 * sim.heap_n
        sim.heap_time = longer_floats(sim.heap_time, size)
        sim.heap_order = longer_ints(sim.heap_order, size)
        sim.heap_f = longer_floats(sim.heap_f, size)
        wider = np.zeros((size, 6), np.int64)
        wider[: sim.heap_n] = sim.heap_ints
        sim.heap_ints = wider
    # A binary heap on (time, order) over flat arrays: sift the new event up from the end.  The
    # arrays are read into locals once: each read of a struct's field costs a reference count.
    times, orders, ints, floats = sim.heap_time, sim.heap_order, sim.heap_ints, sim.heap_f
    i = sim.heap_n
    sim.heap_n = i + 1
    while i > 0:
        parent = (i - 1) // 2
        if times[parent] < when or (times[parent] == when and orders[parent] < order):
            break
        move_event(times, orders, ints, floats, parent, i)
        i = parent
    times[i] = when
    orders[i] = order
    ints[i, 0] = kind
    ints[i, 1] = a
    ints[i, 2] = b
    ints[i, 3] = c
    ints[i, 4] = d
    ints[i, 5] = e
    floats[i] = f


@inlined
def move_event(times: FloatArray, orders: IntArray, ints: Any, floats: FloatArray, source: int, target: int) -> None:
    times[target] = times[source]
    orders[target] = orders[source]
    for j in range(6):
        ints[target, j] = ints[source, j]
    floats[target] = floats[source]


@inlined
def pop_event(sim: Sim) -> tuple[float, int, int, int, int, int, int, int, float]:
    """The earliest event (the first scheduled among equal times), taken off the heap."""
    times, orders, ints, floats = sim.heap_time, sim.heap_order, sim.heap_ints, sim.heap_f
    event = (times[0], orders[0], ints[0, 0], ints[0, 1], ints[0, 2], ints[0, 3], ints[0, 4], ints[0, 5],
             floats[0])  # fmt: skip
    n = sim.heap_n - 1
    sim.heap_n = n
    if n == 0:
        return event
    when, order = times[n], orders[n]
    i = 0
    while True:  # sift the last event down from the root
        child = 2 * i + 1
        if child >= n:
            break
        right = child + 1
        if right < n and (
            times[right] < times[child] or (times[right] == times[child] and orders[right] < orders[child])
        ):
            child = right
        if when < times[child] or (when == times[child] and order < orders[child]):
            break
        move_event(times, orders, ints, floats, child, i)
        i = child
    move_event(times, orders, ints, floats, n, i)
    return event


@inlined
def arrival(sim: Sim) -> int:
    ticket: int = sim.arrival
    sim.arrival = ticket + 1
    return ticket


@inlined
def submit(sim: Sim, pool: int, node: int, remaining: float, threads: int, priority: int) -> None:
    sim.job_pool[node] = pool
    sim.job_remaining[node] = remaining
    sim.job_threads[node] = threads
    sim.job_priority[node] = priority
    sim.job_since[node] = arrival(sim)
    sim.job_speed[node] = 0.0
    sim.job_read_at[node] = math.nan  # not read yet: it reads when it first runs (advance_to)
    sim.pool_jobs[pool, sim.pool_njobs[pool]] = node
    sim.pool_njobs[pool] += 1
    sim.pool_dirty[pool] = True


@inlined
def allocate(sim: Sim, pool: int) -> None:
    free = float(sim.pool_ncores[pool])
    count = sim.pool_njobs[pool]
    jobs = sim.pool_jobs  # indexed [pool, i]: a row view would cost a reference count
    speeds, threads = sim.job_speed, sim.job_threads
    if not sim.pool_fair[pool]:
        order = sim.sort_buf  # by (priority high first, then arrival): insertion sort, few jobs
        priority, since = sim.job_priority, sim.job_since
        for i in range(count):
            node = jobs[pool, i]
            j = i
            while j > 0:
                other = order[j - 1]
                if priority[other] > priority[node] or (
                    priority[other] == priority[node] and since[other] <= since[node]
                ):
                    break
                order[j] = other
                j -= 1
            order[j] = node
        for i in range(count):
            node = order[i]
            wanted = float(threads[node])
            given = min(wanted, free)
            speeds[node] = given / wanted
            free -= given
        return
    demand = 0
    for i in range(count):
        demand += threads[jobs[pool, i]]
    if demand <= free:
        for i in range(count):
            speeds[jobs[pool, i]] = 1.0
        return
    share = free / demand
    for i in range(count):
        speeds[jobs[pool, i]] = min(1.0, share)


@inlined
def next_done(sim: Sim) -> tuple[float, int]:
    best, which = math.inf, -1
    jobs, njobs, speed, remaining = sim.pool_jobs, sim.pool_njobs, sim.job_speed, sim.job_remaining
    for pool in range(sim.pools):
        done_in = math.inf
        for i in range(njobs[pool]):
            node = jobs[pool, i]
            if speed[node] > 0.0:
                done_in = min(done_in, remaining[node] / speed[node])
        if done_in < best:
            best, which = done_in, pool
    return best, which


@inlined
def advance_to(sim: Sim, when_ms: float) -> int:
    """Move time on; the jobs that finished are ``sim.finished[:count]``, in the Python engine's order."""
    dt = max(when_ms - sim.now, 0.0)
    count = 0
    speeds, remaining, threads, busy = sim.job_speed, sim.job_remaining, sim.job_threads, sim.pool_busy
    finished, jobs, njobs = sim.finished, sim.pool_jobs, sim.pool_njobs
    for pool in range(sim.pools):
        n = njobs[pool]
        ended = False
        for i in range(n):
            node = jobs[pool, i]
            speed = speeds[node]
            if speed > 0.0:
                if math.isnan(sim.job_read_at[node]) and (dt > 0.0 or remaining[node] <= DONE_EPS_MS):
                    read_inputs(sim, node, sim.now)  # it runs for the first time (or ends with no work): it reads
                remaining[node] -= dt * speed
                busy[pool] += dt * speed * threads[node]
                if remaining[node] <= DONE_EPS_MS:
                    finished[count] = node
                    count += 1
                    ended = True
        if ended:
            kept = 0
            for i in range(n):
                node = jobs[pool, i]
                if remaining[node] > DONE_EPS_MS:
                    jobs[pool, kept] = node
                    kept += 1
                else:
                    sim.job_pool[node] = -1
            njobs[pool] = kept
            sim.pool_dirty[pool] = True
    sim.now = max(sim.now, when_ms)
    return count


@inlined
def draws_short(sim: Sim) -> bool:
    """Whether a node may run out of drawn compute times in the next event (Python draws more)."""
    for node in range(sim.scheduled.shape[0]):
        if sim.scheduled[node] and sim.used[node] + 4 > sim.filled[node]:
            return True
    return False


@compiled
def produced_per_turn(sim: Sim) -> int:
    """Completions a loop turn records at most (staleness samples twice as many)."""
    n: int = sim.scheduled.shape[0]
    produced: int = n * (sim.succ.shape[0] + n + 1)  # every node finishing, each passing data on to every node
    return produced


@compiled
def feeds_per_record(sim: Sim) -> int:
    """The most feeds a completion record notes (at least 1, so that it can divide)."""
    widest = 1
    for node in range(sim.scheduled.shape[0]):
        widest = max(widest, sim.feed_ptr[node + 1] - sim.feed_ptr[node])
    return widest


@compiled
def make_room(sim: Sim) -> None:
    """Room in every record and ring for :data:`ROOM_TURNS` more loop turns (:func:`produced_per_turn`).

    Room for one turn would do, but the check that follows (:func:`turns_with_room`) scans every
    node and subchain: with room for a single turn it ran every other turn, a fifth of the kernel's
    instructions (nav2d, 2 cores, callgrind).
    """
    n = sim.scheduled.shape[0]
    room = ROOM_TURNS * produced_per_turn(sim)
    if sim.done_n + room > sim.done_at.shape[0]:
        sim.done_node = longer_ints(sim.done_node, sim.done_n + room)
        sim.done_at = longer_floats(sim.done_at, sim.done_n + room)
        sim.done_read = longer_floats(sim.done_read, sim.done_n + room)
    feeds = room * feeds_per_record(sim)
    if sim.feeds_n + feeds > sim.done_feeds.shape[0]:
        sim.done_feeds = longer_ints(sim.done_feeds, sim.feeds_n + feeds)
    if sim.stale_n + 2 * room > sim.stale_ms.shape[0]:
        sim.stale_node = longer_ints(sim.stale_node, sim.stale_n + 2 * room)
        sim.stale_ms = longer_floats(sim.stale_ms, sim.stale_n + 2 * room)
    ring_room = 4 * ROOM_TURNS
    for node in range(n):
        while sim.wait_tail[node] - sim.wait_head[node] + ring_room > sim.wait.shape[1]:
            sim.wait = wider_ring(sim.wait, sim.wait_head, sim.wait_tail - 1)
    for sub in range(sim.sub_seq.shape[0]):
        oldest_in_flight(sim, sub)  # moves flight_low past finished runs
        while sim.sub_seq[sub] - sim.flight_low[sub] + ring_room > sim.flight_index.shape[1]:
            high = sim.sub_seq.copy()
            sim.flight_index = wider_ring(sim.flight_index, sim.flight_low, high)
            sim.flight_at = wider_ring(sim.flight_at, sim.flight_low, high)
            sim.flight_live = wider_ring(sim.flight_live, sim.flight_low, high)


@compiled
def turns_with_room(sim: Sim) -> int:
    """Loop turns that surely fit in the draws, records and rings as they are (at least 1 after :func:`make_room`).

    Each turn takes at most what :func:`draws_short` and :func:`make_room` leave room for
    (4 draws of a node, :func:`produced_per_turn` records, 4 places in a ring), so after ``t`` turns
    there was room for each: checking only then is checking before every turn.
    """
    n = sim.scheduled.shape[0]
    produced = produced_per_turn(sim)
    turns: int = (sim.done_at.shape[0] - sim.done_n) // produced
    turns = min(turns, (sim.stale_ms.shape[0] - sim.stale_n) // (2 * produced))
    turns = min(turns, (sim.done_feeds.shape[0] - sim.feeds_n) // (produced * feeds_per_record(sim)))
    for node in range(n):
        if sim.scheduled[node]:
            turns = min(turns, (sim.filled[node] - sim.used[node]) // 4)
        turns = min(turns, (sim.wait.shape[1] - (sim.wait_tail[node] - sim.wait_head[node])) // 4)
    for sub in range(sim.sub_seq.shape[0]):
        turns = min(turns, (sim.flight_index.shape[1] - (sim.sub_seq[sub] - sim.flight_low[sub])) // 4)
    return max(turns, 1)


@compiled
def longer_ints(array: IntArray, at_least: int) -> IntArray:
    """``array`` in a longer one; what lies past it is never read before it is written (no zeroing)."""
    grown = np.empty(max(2 * array.shape[0], at_least), np.int64)
    grown[: array.shape[0]] = array
    return grown


@compiled
def longer_floats(array: FloatArray, at_least: int) -> FloatArray:
    """As :func:`longer_ints`."""
    grown = np.empty(max(2 * array.shape[0], at_least), np.float64)
    grown[: array.shape[0]] = array
    return grown


@compiled
def wider_ring(ring: Any, low: IntArray, high: IntArray) -> Any:
    """A ring indexed by a counter modulo its width, twice as wide, each counter in ``low..high`` in its place."""
    width = ring.shape[1]
    grown = np.zeros((ring.shape[0], 2 * width), ring.dtype)
    for row in range(ring.shape[0]):
        for counter in range(low[row], high[row] + 1):
            grown[row, counter % (2 * width)] = ring[row, counter % width]
    return grown


@compiled
def run(sim: Sim, end_ms: float) -> int:
    """:meth:`Engine.run_until`: to ``end_ms``, or until a re-solve is due or Python must draw more."""
    safe = 0  # loop turns left before the draws, records and rings must be looked at again
    while True:
        if safe == 0:
            if draws_short(sim):
                return NEED_DRAWS
            make_room(sim)
            safe = turns_with_room(sim)
        safe -= 1
        for pool in range(sim.pools):
            if sim.pool_dirty[pool]:
                allocate(sim, pool)
                sim.pool_dirty[pool] = False
        done_in, pool = next_done(sim)
        next_event = sim.heap_time[0] if sim.heap_n > 0 else math.inf
        now = sim.now
        if min(now + done_in, next_event) > end_ms:
            advance_to(sim, end_ms)
            return FINISHED
        if now + done_in <= next_event and pool >= 0:
            count = advance_to(sim, now + done_in)
            finish_all(sim, count)
            continue
        count = advance_to(sim, next_event)
        if count:
            finish_all(sim, count)
            continue
        event = pop_event(sim)
        if event[2] == REOPTIMISE:
            return REOPTIMISE_NOW
        dispatch(sim, event)


@inlined
def finish_all(sim: Sim, count: int) -> None:
    for i in range(count):  # completions start jobs but never move time: sim.finished stays as it is
        node = sim.finished[i]
        if sim.policy <= CATAN_MEASURED:
            catan_done(sim, node)
        else:
            timer_done(sim, node)


@inlined
def dispatch(sim: Sim, event: Any) -> None:
    kind = event[2]
    if kind == SENSOR:
        node = event[3]
        due = event[8]
        tick(sim, node)
        at(sim, due + sim.sensor_period[node], SENSOR, node, 0, 0, 0, 0, due + sim.sensor_period[node])
    elif kind == TIMER:
        node = event[3]
        due = event[8]
        timer_trigger(sim, node)
        at(sim, due + sim.timer_period[node], TIMER, node, 0, 0, 0, 0, due + sim.timer_period[node])
    elif kind == CLOCK:
        clock_fire(sim, event[3], event[4], event[8])
    elif kind == BEGIN:
        period_begin(sim, event[3], event[4], event[5], event[8])
    elif kind == SWITCH:
        switch(sim, event[3], event[4], event[5], event[6], event[7])
    elif kind == LOWER:
        if event[4] == sim.generation:
            hand_over(sim.raised, event[3], NONE, sim.actions)
            reprioritise(sim)


# --------------------------------------------------------------------------- the data


@inlined
def read_inputs(sim: Sim, node: int, now: float) -> None:
    """:meth:`Dataflow.read_inputs` by reference: ``node``'s run reads now the newest output of each feed.

    A chain's origins are not carried from output to output (that was O(chains) per run, a sixth of
    the kernel's instructions on nav2d): a run notes which completion record of each feed it read
    (-1: none yet) and when, and :func:`chain_arrivals` follows the notes back along each chain after
    the run.  Staleness is the age of the oldest input, over every predecessor.
    """
    latest_id, feed, job_feed = sim.latest_id, sim.feed, sim.job_feed
    for k in range(sim.feed_ptr[node], sim.feed_ptr[node + 1]):
        job_feed[k] = latest_id[feed[k]]
    sim.job_read_at[node] = now
    age = -math.inf
    pred, latest_at = sim.pred, sim.latest_at
    for k in range(sim.pred_ptr[node], sim.pred_ptr[node + 1]):
        before = pred[k]
        if latest_id[before] >= 0:
            age = max(age, now - latest_at[before])
    if age > -math.inf:
        n = sim.stale_n
        sim.stale_node[n] = node
        sim.stale_ms[n] = age
        sim.stale_n = n + 1


@inlined
def produce(sim: Sim, node: int) -> None:
    """:meth:`Dataflow.produce`, what ``node`` read already noted (``job_feed``); depth first, as recursion."""
    now = sim.now
    stack = sim.stack
    feed_ptr, job_feed, latest_id, latest_at = sim.feed_ptr, sim.job_feed, sim.latest_id, sim.latest_at
    succ_ptr, succ, pass_through = sim.succ_ptr, sim.succ, sim.pass_through
    stack[0] = node
    top = 1
    first = True
    while top > 0:
        top -= 1
        current = stack[top]
        if not first:  # a pass-through node reads its inputs as it is reached
            read_inputs(sim, current, now)
        first = False
        n = sim.done_n
        sim.done_node[n] = current
        sim.done_at[n] = now
        sim.done_read[n] = sim.job_read_at[current]
        m = sim.feeds_n
        done_feeds = sim.done_feeds
        for k in range(feed_ptr[current], feed_ptr[current + 1]):
            done_feeds[m] = job_feed[k]
            m += 1
        sim.feeds_n = m
        sim.done_n = n + 1
        latest_id[current] = n
        latest_at[current] = now
        if sim.policy >= TIMER_FAIR:  # the baselines listen to every output
            for k in range(sim.trig_ptr[current], sim.trig_ptr[current + 1]):
                timer_trigger(sim, sim.trig[k])
        for k in range(succ_ptr[current + 1] - 1, succ_ptr[current] - 1, -1):
            after = succ[k]
            if pass_through[after]:
                stack[top] = after
                top += 1


@inlined
def tick(sim: Sim, node: int) -> None:
    read_inputs(sim, node, sim.now)
    produce(sim, node)


@compiled
def sample(sim: Sim, node: int, at_s: float) -> float:
    """:meth:`catanc.model.workload.NodeStream.draw` from the values drawn in advance."""
    i = sim.spike_next[node]
    if at_s >= sim.spike_at[node, i]:
        while sim.spike_at[node, i] <= at_s:
            i += 1
        sim.spike_next[node] = i
        spike: float = sim.spike_ms[node]
        return spike
    k = sim.used[node]
    sim.used[node] = k + 1
    mode = sim.mode
    k %= mode.shape[1]  # a ring: fast.DrawTable refills it past the runs taken
    ms: float = mode[node, k]
    if sim.has_growth[node]:
        start, end, over_s = sim.growth[node, 0], sim.growth[node, 1], sim.growth[node, 2]
        if at_s >= over_s:
            factor = end
        elif at_s <= 0.0:
            factor = start
        else:
            factor = start + (end - start) * (at_s / over_s)
        ms *= factor
    jitter: float = sim.factor[node, k]
    return ms * jitter


# --------------------------------------------------------------------------- catanc's schedule


@compiled
def install(sim: Sim, version: int) -> None:
    """:meth:`CatanPolicy._install`: pools for ``version``'s allocation, running jobs moved, clocks restarted."""
    sim.generation += 1
    sim.version = version
    old = np.empty(sim.scheduled.shape[0], np.int64)
    n_old = 0
    for pool in range(sim.pools):
        for i in range(sim.pool_njobs[pool]):
            old[n_old] = sim.pool_jobs[pool, i]
            n_old += 1
    fold_busy(sim)
    pools = 0
    core_pool = np.full(sim.cores, -1, np.int64)
    for sub in range(sim.sub_shared.shape[1]):  # subchains by sorted name, as the Python policy makes pools
        if sim.sub_shared[version, sub]:
            core = sim.sub_cores[version, sub, 0]
            if core_pool[core] < 0:
                core_pool[core] = pools
                new_pool(sim, pools, sim.sub_cores[version, sub], 1)
                pools += 1
            sim.sub_pool[sub] = core_pool[core]
        else:
            new_pool(sim, pools, sim.sub_cores[version, sub], sim.sub_ncores[version, sub])
            sim.sub_pool[sub] = pools
            pools += 1
    sim.pools = pools
    sim.raised[:] = -1
    for i in range(n_old):
        node = old[i]
        sub = sim.sub_of[node]
        if sub >= 0:
            priority = RESTING_SHARED if sim.sub_shared[version, sub] else DEDICATED
            resubmit(sim, sim.sub_pool[sub], node, priority)
    for pool in range(pools):
        sim.pool_dirty[pool] = True
    generation = sim.generation
    now = sim.now
    for i in range(sim.clocked.shape[1]):
        sub = sim.clocked[version, i]
        if sub < 0:
            break
        at(sim, now, CLOCK, sub, generation, 0, 0, 0, now)
    for c in range(sim.n_shared[version]):
        at(sim, now, BEGIN, sim.core_id[version, c], generation, 0, 0, 0, now)


@compiled
def new_pool(sim: Sim, pool: int, cores: IntArray, ncores: int) -> None:
    sim.pool_ncores[pool] = ncores
    sim.pool_cores[pool, :ncores] = cores[:ncores]
    sim.pool_fair[pool] = False
    sim.pool_njobs[pool] = 0
    sim.pool_busy[pool] = 0.0
    sim.pool_dirty[pool] = True


@compiled
def resubmit(sim: Sim, pool: int, node: int, priority: int) -> None:
    sim.job_pool[node] = pool
    sim.job_priority[node] = priority
    sim.job_since[node] = arrival(sim)
    sim.pool_jobs[pool, sim.pool_njobs[pool]] = node
    sim.pool_njobs[pool] += 1
    sim.pool_dirty[pool] = True


@compiled
def fold_busy(sim: Sim) -> None:
    for pool in range(sim.pools):
        n = sim.pool_ncores[pool]
        for i in range(n):
            sim.core_busy[sim.pool_cores[pool, i]] += sim.pool_busy[pool] / n
        sim.pool_busy[pool] = 0.0


@inlined
def clock_fire(sim: Sim, sub: int, generation: int, due: float) -> None:
    if generation != sim.generation:
        return
    version = sim.version
    if sim.sub_runs[version, sub] >= 0:  # no longer on its own clock
        return
    trigger_head(sim, sub)
    when = max(due + sim.sub_period[version, sub], sim.now)
    at(sim, when, CLOCK, sub, generation, 0, 0, 0, when)


@compiled
def period_begin(sim: Sim, core_id: int, generation: int, index: int, start: float) -> None:
    if generation != sim.generation:
        return
    version = sim.version
    c = -1
    for i in range(sim.n_shared[version]):
        if sim.core_id[version, i] == core_id:
            c = i
            break
    if c < 0 or sim.core_nslots[version, c] == 0:
        return
    n = sim.core_nslots[version, c]
    starts, lengths, switches, nslots = sim.slot_start, sim.slot_length, sim.core_switch, sim.core_nslots
    for s in range(n):
        when = slot_boundary_ms(starts, lengths, switches, nslots, version, c, start, s)
        at(sim, when, SWITCH, version, c, s, generation, index, 0.0)
    last_end = slot_boundary_ms(starts, lengths, switches, nslots, version, c, start, n)
    at(sim, last_end, LOWER, core_id, generation, 0, 0, 0, 0.0)
    next_start = start + sim.core_period[version, c]
    at(sim, next_start, BEGIN, core_id, generation, index + 1, 0, 0, next_start)


@inlined
def oldest_in_flight(sim: Sim, sub: int) -> float:
    """When the oldest unfinished run of ``sub`` was triggered (NaN: none); seqs are triggered in time order."""
    cap = sim.flight_index.shape[1]
    seq = sim.flight_low[sub]
    while seq <= sim.sub_seq[sub] and not sim.flight_live[sub, seq % cap]:
        seq += 1
    sim.flight_low[sub] = seq
    if seq > sim.sub_seq[sub]:
        return math.nan
    oldest: float = sim.flight_at[sub, seq % cap]
    return oldest


@compiled
def switch(sim: Sim, old_version: int, c: int, s: int, generation: int, index: int) -> None:
    """:meth:`CatanPolicy._switcher`: the core's slots as they were scheduled, the subchains as they are now.

    The decision is :func:`catanc.control.compiled_policy.decide`'s; this marks which of the slot's
    thieves are late (their oldest run in flight past their planned latency) and carries the actions out.
    """
    if generation != sim.generation:
        return
    version = sim.version
    now = sim.now
    rule_thieves, late = sim.rule_thieves, sim.thief_late
    for t in range(thieves(rule_thieves, old_version, c, s)):
        thief = rule_thieves[old_version, c, s, t]
        oldest = oldest_in_flight(sim, thief)
        late[thief] = 1 if not math.isnan(oldest) and now - oldest > sim.sub_latency[version, thief] else 0
    actions = sim.actions
    core = sim.core_id[old_version, c]
    decide(sim.rule_sub, sim.rule_every, rule_thieves, old_version, c, s, index, late, sim.raised, core, actions)
    if actions[act.STEAL] != 0:
        sim.sub_steals[actions[act.RAISE]] += 1
    reprioritise(sim)
    if actions[act.TRIGGER] != NONE:
        trigger_head(sim, actions[act.TRIGGER])


@compiled
def reprioritise(sim: Sim) -> None:
    """:meth:`CatanPolicy._raise`, a hand-over's actions carried out: the previous owner's jobs to FIFO 1 (the
    front), the new owner's to FIFO 2 (the back)."""
    actions = sim.actions
    if actions[act.HANDOVER] == 0:
        return
    for k in range(2):
        sub = actions[act.LOWER] if k == 0 else actions[act.RAISE]
        level = RESTING_SHARED if k == 0 else RAISED
        if sub < 0:
            continue
        pool = sim.sub_pool[sub]
        for i in range(sim.pool_njobs[pool]):
            node = sim.pool_jobs[pool, i]
            if sim.sub_of[node] == sub:
                sim.job_priority[node] = level
                ticket = arrival(sim)
                sim.job_since[node] = ticket if level == RAISED else -ticket
        sim.pool_dirty[pool] = True


@compiled
def trigger_head(sim: Sim, sub: int) -> None:
    if sim.heads_in_flight[sub] > 0:
        if not sim.sub_pending[sub]:
            sim.sub_skipped[sub] += 1
        sim.sub_pending[sub] = True
        return
    sim.sub_pending[sub] = False
    seq = sim.sub_seq[sub] + 1
    sim.sub_seq[sub] = seq
    cap = sim.flight_index.shape[1]
    sim.flight_index[sub, seq % cap] = 0
    sim.flight_at[sub, seq % cap] = sim.now
    sim.flight_live[sub, seq % cap] = True
    sim.heads_in_flight[sub] += 1
    catan_trigger(sim, sim.sub_nodes[sim.sub_ptr[sub]], seq)


@inlined
def exec_enter(sim: Sim, node: int, seq: int) -> bool:
    """:meth:`ExecutorGate.enter`: whether ``node``'s run starts now (else it waits for its executor)."""
    e = sim.executor_of[node]
    if e < 0:
        return True
    if sim.exec_running[e] < 0:
        sim.exec_running[e] = node
        return True
    cap = sim.exec_wait_node.shape[1]  # a node waits at most once: as many places as nodes
    tail = sim.exec_wait_tail[e] % cap
    sim.exec_wait_node[e, tail] = node
    sim.exec_wait_seq[e, tail] = seq
    sim.exec_wait_tail[e] += 1
    return False


@compiled
def exec_leave(sim: Sim, node: int) -> None:
    """:meth:`ExecutorGate.leave`: ``node`` finished; its executor starts the next waiting run."""
    e = sim.executor_of[node]
    if e < 0:
        return
    if sim.exec_wait_tail[e] == sim.exec_wait_head[e]:
        sim.exec_running[e] = -1
        return
    head = sim.exec_wait_head[e] % sim.exec_wait_node.shape[1]
    following, seq = sim.exec_wait_node[e, head], sim.exec_wait_seq[e, head]
    sim.exec_wait_head[e] += 1
    sim.exec_running[e] = following
    if sim.policy >= TIMER_FAIR:
        timer_start(sim, following)
    else:
        catan_start(sim, following, seq)


@compiled
def catan_trigger(sim: Sim, node: int, seq: int) -> None:
    if sim.busy_seq[node] != NO_SEQ:
        cap = sim.wait.shape[1]
        sim.wait[node, sim.wait_tail[node] % cap] = seq
        sim.wait_tail[node] += 1
        return
    sim.busy_seq[node] = seq
    if exec_enter(sim, node, seq):
        catan_start(sim, node, seq)


@compiled
def catan_start(sim: Sim, node: int, seq: int) -> None:
    """:meth:`CatanPolicy._start`: the run draws its time and becomes a job (it reads when it first runs)."""
    sub = sim.sub_of[node]
    version = sim.version
    compute = sample(sim, node, sim.now / 1000.0)
    if not sim.sub_shared[version, sub]:
        priority = DEDICATED
    else:
        priority = RAISED if sim.raised[sim.sub_cores[version, sub, 0]] == sub else RESTING_SHARED
    sim.job_seq[node] = seq
    sim.job_compute[node] = compute
    remaining = compute / sim.node_speedup[version, node]
    submit(sim, sim.sub_pool[sub], node, remaining, sim.node_threads[version, node], priority)


@compiled
def catan_done(sim: Sim, node: int) -> None:
    seq = sim.job_seq[node]
    if sim.policy == CATAN_MEASURED:
        ring = sim.measured_ring
        runs = sim.measured_total[node]
        ring[node, runs % ring.shape[1]] = sim.job_compute[node]
        sim.measured_total[node] = runs + 1
    produce(sim, node)
    exec_leave(sim, node)
    sub = sim.sub_of[node]
    sim.busy_seq[node] = NO_SEQ  # free: the next waiting run of this node starts
    if sim.wait_tail[node] > sim.wait_head[node]:
        waiting = sim.wait[node, sim.wait_head[node] % sim.wait.shape[1]]
        sim.wait_head[node] += 1
        catan_trigger(sim, node, waiting)
    cap = sim.flight_index.shape[1]
    if seq > sim.sub_seq[sub] or seq < sim.flight_low[sub] or not sim.flight_live[sub, seq % cap]:
        return
    index = sim.flight_index[sub, seq % cap]
    head_done = index == 0
    length = sim.sub_ptr[sub + 1] - sim.sub_ptr[sub]
    if head_done:
        sim.heads_in_flight[sub] -= 1
    if index + 1 < length:
        sim.flight_index[sub, seq % cap] = index + 1
        catan_trigger(sim, sim.sub_nodes[sim.sub_ptr[sub] + index + 1], seq)
    else:
        sim.flight_live[sub, seq % cap] = False
        if sim.now - sim.flight_at[sub, seq % cap] > sim.sub_late_after[sim.version, sub]:
            sim.sub_late[sub] += 1
    if head_done and sim.sub_pending[sub]:
        trigger_head(sim, sub)


# --------------------------------------------------------------------------- the hand-tuned baselines


@inlined
def timer_trigger(sim: Sim, node: int) -> None:
    if sim.timer_busy[node]:
        sim.timer_pending[node] = True
        return
    sim.timer_busy[node] = True
    if exec_enter(sim, node, 0):
        timer_start(sim, node)


@compiled
def timer_start(sim: Sim, node: int) -> None:
    """:meth:`TimerPolicy._start`."""
    compute = sample(sim, node, sim.now / 1000.0)
    submit(sim, 0, node, compute, 1, sim.priority[node])


@inlined
def timer_done(sim: Sim, node: int) -> None:
    produce(sim, node)
    exec_leave(sim, node)
    sim.timer_busy[node] = False
    if sim.timer_pending[node]:
        sim.timer_pending[node] = False
        timer_trigger(sim, node)


@compiled
def start_sensors(sim: Sim) -> None:
    for i in range(sim.sensor_order.shape[0]):
        node = sim.sensor_order[i]
        at(sim, 0.0, SENSOR, node, 0, 0, 0, 0, 0.0)


@compiled
def start_timers(sim: Sim, fair: bool) -> None:
    """:class:`TimerPolicy`: one pool of every core; each listed node's timer from 0."""
    new_pool(sim, 0, np.arange(sim.cores), sim.cores)
    sim.pool_fair[0] = fair
    sim.pools = 1
    for i in range(sim.timer_order.shape[0]):
        at(sim, 0.0, TIMER, sim.timer_order[i], 0, 0, 0, 0, 0.0)


@compiled
def schedule_reoptimise(sim: Sim, when_ms: float) -> None:
    at(sim, when_ms, REOPTIMISE, 0, 0, 0, 0, 0, 0.0)


@compiled
def set_version(sim: Sim, version: int) -> None:
    sim.version = version


# --------------------------------------------------------------------------- for Python


@compiled
def records(sim: Sim) -> tuple[IntArray, FloatArray, FloatArray, IntArray, IntArray, FloatArray]:
    """Completions (node, time, when the run read its inputs), what each read (its feeds' completion
    records, -1 for none, record after record) and staleness (node, ms), in order."""
    return (
        sim.done_node[: sim.done_n],
        sim.done_at[: sim.done_n],
        sim.done_read[: sim.done_n],
        sim.done_feeds[: sim.feeds_n],
        sim.stale_node[: sim.stale_n],
        sim.stale_ms[: sim.stale_n],
    )


@compiled
def chain_arrivals(
    done_node: IntArray, done_at: FloatArray, done_read: FloatArray, done_feeds: IntArray, feed_ptr: IntArray,
    root: IntArray, trie_feed: IntArray, child_ptr: IntArray, child: IntArray, head_ptr: IntArray,
    head_chain: IntArray, chains: int,
) -> tuple[IntArray, FloatArray, FloatArray]:  # fmt: skip
    """Chain arrivals (chain, origin, done) from the completion records (:func:`records`).

    Each output of a chain's last node is followed back, through what each run read, to a run of the
    chain's head: its origin is when that run read its inputs.  An output arrives if its origin is
    newer than any before, as :class:`~catanc.sim.dataflow.Dataflow` keeps them.

    The chains are followed together, in a trie of their suffixes (:func:`catanc.sim.fast.chain_tables`):
    ``root[node]`` is the trie place of a last node (-1: none), a place's children are the nodes that
    can come before it (``child_ptr/child``; ``trie_feed``: which of the node's feeds it is), and the
    chains whose head it is are ``head_ptr/head_chain``.  A place reached with the record it was last
    reached with leads to the origins it led to then, none newer: the chains below it are skipped (a
    1 Hz node feeding a 600 Hz chain is followed once a second, not 600 times).
    """
    records = done_node.shape[0]
    first_feed = np.empty(records, np.int64)
    wanted = 0
    f = 0
    for d in range(records):
        node = done_node[d]
        first_feed[d] = f
        f += feed_ptr[node + 1] - feed_ptr[node]
        if root[node] >= 0:
            wanted += chains  # at most every chain arrives at once
    newest = np.full(chains, -math.inf)
    last_record = np.full(trie_feed.shape[0], -1, np.int64)
    stack_place = np.empty(trie_feed.shape[0], np.int64)
    stack_record = np.empty(trie_feed.shape[0], np.int64)
    out_chain = np.empty(wanted, np.int64)
    out_origin = np.empty(wanted)
    out_done = np.empty(wanted)
    n = 0
    for d in range(records):
        if root[done_node[d]] < 0:
            continue
        stack_place[0] = root[done_node[d]]
        stack_record[0] = d
        top = 1
        while top > 0:
            top -= 1
            place, record = stack_place[top], stack_record[top]
            last_record[place] = record
            origin = done_read[record]
            for k in range(head_ptr[place], head_ptr[place + 1]):
                chain = head_chain[k]
                if origin > newest[chain]:
                    newest[chain] = origin
                    out_chain[n] = chain
                    out_origin[n] = origin
                    out_done[n] = done_at[d]
                    n += 1
            for k in range(child_ptr[place], child_ptr[place + 1]):
                before = child[k]
                read = done_feeds[first_feed[record] + trie_feed[before]]
                # -1: read before that node had any output, no origin that way; last_record: as last time
                if read >= 0 and read != last_record[before]:
                    stack_place[top] = before
                    stack_record[top] = read
                    top += 1
    return out_chain[:n], out_origin[:n], out_done[:n]


@compiled
def group_rows(values: FloatArray, keys: IntArray, groups: int) -> tuple[FloatArray, IntArray]:
    """The rows of ``values`` (2-D) by key (each in ``0..groups-1``), in order within a key (a stable
    counting sort), and where each key's rows start: key ``g`` has rows ``ptr[g]:ptr[g + 1]``."""
    ptr = np.zeros(groups + 1, np.int64)
    for key in keys:
        ptr[key + 1] += 1
    for g in range(groups):
        ptr[g + 1] += ptr[g]
    fill = ptr[:-1].copy()
    ordered = np.empty_like(values)
    for i in range(keys.shape[0]):
        place = fill[keys[i]]
        fill[keys[i]] = place + 1
        for j in range(values.shape[1]):
            ordered[place, j] = values[i, j]
    return ordered, ptr


@compiled
def take_measured(sim: Sim) -> tuple[IntArray, FloatArray]:
    """Per node, the runs measured since the last call, and the last ``window`` of their compute
    times in order (row ``i``'s first ``min(runs, window)``): a measurement window keeps no more."""
    ring = sim.measured_ring
    nodes, window = ring.shape
    runs = np.zeros(nodes, np.int64)
    last = np.empty((nodes, window))
    for node in range(nodes):
        total = sim.measured_total[node]
        runs[node] = total - sim.measured_taken[node]
        sim.measured_taken[node] = total
        kept = min(runs[node], window)
        for j in range(kept):
            last[node, j] = ring[node, (total - kept + j) % window]
    return runs, last


@compiled
def set_draws(sim: Sim, mode: FloatArray, factor: FloatArray) -> None:
    sim.mode = mode
    sim.factor = factor


@compiled
def clock_of(sim: Sim) -> tuple[float, int]:
    """Simulated time (ms) and the schedule version in force."""
    return sim.now, sim.version
