"""The compiled simulation (:mod:`catanc.sim.kernel`) driven from Python: arrays in, records out.

:func:`run_compiled` does what :func:`catanc.sim.simulate.simulate` does with
the Python engine, policy objects and dataflow, and hands back the same
records, so both build their :class:`~catanc.sim.metrics.PolicyResult`
the same way.  Python keeps what is rare and needs the solvers: planning,
re-solving (:class:`~catanc.sim.policies.Reoptimiser`) and growing the
kernel's arrays when it asks.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt

from catanc.control.policy import slot_rules
from catanc.control.schedule import RuntimeSchedule
from catanc.control.slot_table import ACTIONS, NONE, empty_rules, lay_out_rules
from catanc.control.timers import trigger_rules
from catanc.model.workload import ComputeSampler, NodeStream
from catanc.sim import kernel as k
from catanc.sim.policies import Reoptimiser, Replan
from catanc.sim.records import Records
from catanc.spec.executors import executor_nodes
from catanc.spec.language import Spec

Fields = dict[str, Any]
"""Kernel fields by name (:data:`kernel.FIELDS`)."""

RULE_FIELDS = ("rule_sub", "rule_every", "rule_thieves")  # the slot rules' arrays (catanc.control.slot_table)
FIRST_DRAWS = 256
"""Compute times drawn per node before the run; then, as it asks, what each may still take (:meth:`DrawTable.grow`)."""
RING_DRAWS = 1 << 15
"""At most this many drawn compute times per node at once: long runs refill a ring instead of growing
(one hour of nav2d on 2 cores kept 2.4M draws of the local chain's nodes, and as many of every other)."""
FIRST_RECORDS = 4096
FIRST_RING = 16
"""Queued runs per node and runs in flight per subchain before their rings grow."""


def _csr(rows: Sequence[Sequence[int]]) -> tuple[k.IntArray, k.IntArray]:
    pointers = np.zeros(len(rows) + 1, np.int64)
    for i, row in enumerate(rows):
        pointers[i + 1] = pointers[i] + len(row)
    flat = np.array([x for row in rows for x in row], np.int64)
    return pointers, flat


def _sub_names(schedule: RuntimeSchedule) -> list[str]:
    return sorted(schedule.subchains)


def _feeds(names: Sequence[str], chains: Sequence[tuple[str, ...]]) -> list[list[int]]:
    """Per node, the nodes just before it on the measured chains (each once, in the order first met)."""
    index = {name: i for i, name in enumerate(names)}
    feeds: list[list[int]] = [[] for _ in names]
    for chain in chains:
        for before, node in itertools.pairwise(chain):
            if index[before] not in feeds[index[node]]:
                feeds[index[node]].append(index[before])
    return feeds


def topology(
    spec: Spec,
    chains: Sequence[tuple[str, ...]],
    schedule: RuntimeSchedule | None,
    cores: int,
    priorities: dict[str, int] | None = None,
) -> Fields:
    """The graph, the measured chains and (for the baselines) the timer wiring, as arrays."""
    names = list(spec.nodes)
    index = {name: i for i, name in enumerate(names)}
    preds: list[list[int]] = [[] for _ in names]
    succs: list[list[int]] = [[] for _ in names]
    for source, target in spec.edge_pairs:
        preds[index[target]].append(index[source])
        succs[index[source]].append(index[target])
    sub_of = np.full(len(names), -1, np.int64)
    sub_rows: list[list[int]] = []
    if schedule is not None:
        for s, name in enumerate(_sub_names(schedule)):
            run = schedule.subchains[name]
            sub_rows.append([index[node] for node in run.nodes])
            for node in run.nodes:
                sub_of[index[node]] = s
    sensor_period = np.full(len(names), math.nan)
    sensors = []
    for name, spec_node in spec.nodes.items():
        if not spec_node.scheduled and spec_node.rate_hz is not None:
            sensor_period[index[name]] = 1000.0 / spec_node.rate_hz
            sensors.append(index[name])
    timer_period = np.full(len(names), math.nan)
    timers: list[int] = []
    triggers: list[list[int]] = [[] for _ in names]
    if priorities is not None:
        rules = trigger_rules(spec, "simulate")
        for name, period_ms in sorted(rules.timers.items()):
            timer_period[index[name]] = period_ms
            timers.append(index[name])
        for feeder, targets in rules.fed.items():
            triggers[index[feeder]] = [index[t] for t in targets]
    priority = np.array([(priorities or {}).get(name, 0) for name in names], np.int64)
    pred_ptr, pred = _csr(preds)
    succ_ptr, succ = _csr(succs)
    feed_ptr, feed = _csr(_feeds(names, chains))
    sub_ptr, sub_nodes = _csr(sub_rows)
    trig_ptr, trig = _csr(triggers)
    return {
        "scheduled": np.array([node.scheduled for node in spec.nodes.values()], np.bool_),
        "pass_through": np.array([not n.scheduled and n.rate_hz is None for n in spec.nodes.values()], np.bool_),
        "pred_ptr": pred_ptr,
        "pred": pred,
        "succ_ptr": succ_ptr,
        "succ": succ,
        "feed_ptr": feed_ptr,
        "feed": feed,
        "sub_of": sub_of,
        "sub_ptr": sub_ptr,
        "sub_nodes": sub_nodes,
        "sensor_period": sensor_period,
        "sensor_order": np.array(sensors, np.int64),
        "timer_period": timer_period,
        "timer_order": np.array(timers, np.int64),
        "trig_ptr": trig_ptr,
        "trig": trig,
        "priority": priority,
        "cores": cores,
        "executor_of": np.array(
            [next((e for e, nodes in enumerate(executor_nodes(spec).values()) if name in nodes), -1) for name in names],
            np.int64,
        ),
    }


class ScheduleTable:
    """The schedules a run has used, as the kernel's arrays, with room for ``capacity`` versions.

    The kernel shares the arrays: a version added here is there at once.  The slot rules of every
    version are laid out again under the newest one's subchains (their priorities and trigger
    cycles): a core's switches keep the slots of the version they were scheduled in, and the
    Python policy asks :func:`~catanc.control.policy.slot_rules` for them with the schedule in force.
    """

    def __init__(self, spec: Spec, first: RuntimeSchedule, cores: int, capacity: int) -> None:
        self.names = _sub_names(first)
        self.nodes = list(spec.nodes)
        self.cores = cores
        self.versions: list[RuntimeSchedule] = []
        subs, nodes = len(self.names), len(self.nodes)
        v = capacity
        self.arrays: Fields = {
            "sub_ncores": np.zeros((v, subs), np.int64),
            "sub_cores": np.zeros((v, subs, cores), np.int64),
            "sub_shared": np.zeros((v, subs), np.bool_),
            "sub_period": np.zeros((v, subs)),
            "sub_latency": np.zeros((v, subs)),
            "sub_late_after": np.zeros((v, subs)),
            "sub_runs": np.full((v, subs), -1, np.int64),
            "node_threads": np.ones((v, nodes), np.int64),
            "node_speedup": np.ones((v, nodes)),
            "clocked": np.full((v, subs), -1, np.int64),
            "n_shared": np.zeros(v, np.int64),
            "core_id": np.zeros((v, cores), np.int64),
            "core_period": np.zeros((v, cores)),
            "core_switch": np.zeros((v, cores)),
            "core_nslots": np.zeros((v, cores), np.int64),
            "slot_start": np.zeros((v, cores, max(subs, 1))),
            "slot_length": np.zeros((v, cores, max(subs, 1))),
        }
        self.arrays.update(zip(RULE_FIELDS, empty_rules(v, cores, max(subs, 1)), strict=True))
        self.add(first)

    def add(self, schedule: RuntimeSchedule) -> int:
        """Store ``schedule`` as the next version; its number."""
        v = len(self.versions)
        if v >= self.arrays["n_shared"].shape[0]:  # pragma: no cover - capacity counts every re-solve
            raise AssertionError("more re-plans than the schedule table has room for")
        if _sub_names(schedule) != self.names:  # pragma: no cover - subchains come from the spec
            raise AssertionError("a re-plan changed the set of subchains")
        self.versions.append(schedule)
        a = SimpleNamespace(**self.arrays)
        sub_id = {name: s for s, name in enumerate(self.names)}
        node_id = {name: i for i, name in enumerate(self.nodes)}
        for s, name in enumerate(self.names):
            run = schedule.subchains[name]
            a.sub_ncores[v, s] = len(run.cores)
            a.sub_cores[v, s, : len(run.cores)] = run.cores
            a.sub_shared[v, s] = run.shared
            a.sub_period[v, s] = run.period_ms
            a.sub_latency[v, s] = run.latency_ms
            a.sub_late_after[v, s] = run.late_after_ms
            a.sub_runs[v, s] = -1 if run.runs is None else run.runs
            for i, node in enumerate(run.nodes):
                threads, speedup = run.threads_of(i)
                a.node_threads[v, node_id[node]] = threads
                a.node_speedup[v, node_id[node]] = speedup
        for i, run in enumerate(schedule.clocked):
            a.clocked[v, i] = sub_id[run.name]
        a.n_shared[v] = len(schedule.shared)
        for c, core in enumerate(schedule.shared):
            a.core_id[v, c] = core.core
            a.core_period[v, c] = core.period_ms
            a.core_switch[v, c] = core.switch_ms
            a.core_nslots[v, c] = len(core.slots)
            for i, slot in enumerate(core.slots):
                a.slot_start[v, c, i] = slot.start_ms
                a.slot_length[v, c, i] = slot.length_ms
        rules = tuple(self.arrays[name] for name in RULE_FIELDS)
        for u, earlier in enumerate(self.versions):
            for c, core in enumerate(earlier.shared):
                lay_out_rules(rules, u, c, slot_rules(core, schedule.subchains), sub_id)
        return v


class DrawTable:
    """Each scheduled node's compute times, drawn ahead from its :class:`NodeStream`, grown on demand."""

    def __init__(self, spec: Spec, sampler: ComputeSampler, end_s: float) -> None:
        names = list(spec.nodes)
        n = len(names)
        self.end_ms = end_s * 1000.0
        self.streams: dict[int, NodeStream] = {
            i: sampler.stream(name) for i, name in enumerate(names) if spec.nodes[name].scheduled
        }
        spikes = {i: stream.spikes_until(end_s + 1.0) for i, stream in self.streams.items()}
        width = max((len(s) for s in spikes.values()), default=1)
        spike_at = np.full((n, width), math.inf)
        spike_ms = np.full(n, math.nan)
        has_growth = np.zeros(n, np.bool_)
        growth = np.zeros((n, 3))
        for i, stream in self.streams.items():
            spike_at[i, : len(spikes[i])] = spikes[i]
            spike_ms[i] = stream.spike_ms
            if stream.growth is not None:
                has_growth[i] = True
                growth[i] = stream.growth
        self.arrays: Fields = {
            "mode": np.zeros((n, FIRST_DRAWS)),
            "factor": np.zeros((n, FIRST_DRAWS)),
            "used": np.zeros(n, np.int64),
            "filled": np.zeros(n, np.int64),
            "spike_at": spike_at,
            "spike_next": np.zeros(n, np.int64),
            "spike_ms": spike_ms,
            "has_growth": has_growth,
            "growth": growth,
        }
        self.grow()

    def grow(self, sim: k.Sim | None = None) -> None:
        """Draw more for every node that is short: each node's row is a ring of draws (run ``j`` at
        ``j % width``), refilled past the runs taken with what the node may still take to the end
        (:meth:`_still_wanted`).  The rings share one width, widened at once to what the short node
        wanting most still wants, up to :data:`RING_DRAWS` (doubling them took seven widenings, and as
        many returns from the kernel, in nav2d's first minute).  Each stream's values come in its own
        order, so how many are drawn at a time changes no value."""
        a = self.arrays
        used, filled = a["used"], a["filled"]
        short = [i for i in self.streams if used[i] + 4 > filled[i]] if sim is not None else list(self.streams)
        now_ms = 0.0 if sim is None else k.clock_of(sim)[0]
        still = {i: self._still_wanted(int(used[i]), now_ms) for i in short}
        width = a["mode"].shape[1]
        wanted = max([width, *(min(ahead, RING_DRAWS) for ahead in still.values())])
        if wanted > width:
            wider = {name: np.zeros((a[name].shape[0], wanted)) for name in ("mode", "factor")}
            for i in self.streams:  # the runs drawn but not taken keep their places modulo the new width
                kept = np.arange(used[i], filled[i])
                for name, ring in wider.items():
                    ring[i, kept % wanted] = a[name][i, kept % width]
            a.update(wider)
            width = wanted
        for i in short:
            ahead = min(width, still[i])
            modes, factors = self.streams[i].bases(int(used[i]) + ahead - int(filled[i]))
            _into_ring(a["mode"][i], int(filled[i]), modes)
            _into_ring(a["factor"][i], int(filled[i]), factors)
            filled[i] = used[i] + ahead
        if sim is not None:
            k.set_draws(sim, a["mode"], a["factor"])

    def _still_wanted(self, used: int, now_ms: float) -> int:
        """Draws a node that took ``used`` by ``now_ms`` may take to the end at that rate, with a margin:
        a ring's whole width drawn near the end went unused (nav2d: half of all draws)."""
        if now_ms <= 0.0:
            return FIRST_DRAWS
        return math.ceil(1.25 * used * max(self.end_ms - now_ms, 0.0) / now_ms) + FIRST_DRAWS


def _into_ring(ring: npt.NDArray[np.float64], first: int, values: npt.NDArray[np.float64]) -> None:
    """``values`` into ``ring`` as runs ``first, first + 1, ...``: run ``j`` at ``j % len(ring)``, len(ring) at most."""
    start = first % len(ring)
    head = min(len(values), len(ring) - start)
    ring[start : start + head] = values[:head]
    ring[: len(values) - head] = values[head:]


def run_fields(graph: Fields, subchains: int, policy: int, measured_window: int = 1) -> Fields:
    """The run's state at time 0: nothing running, nothing produced, empty records; each node's
    measured compute times are kept ``measured_window`` deep (the re-solving policy's window)."""
    n, cores = graph["scheduled"].shape[0], graph["cores"]
    pools = max(subchains, 1)
    executors = int(graph["executor_of"].max(initial=-1)) + 1
    return {
        "now": 0.0,
        "order": 0,
        "arrival": 0,
        "generation": 0,
        "version": 0,
        "policy": policy,
        "pools": 0,
        "heap_n": 0,
        "heap_time": np.zeros(FIRST_RING),
        "heap_order": np.zeros(FIRST_RING, np.int64),
        "heap_ints": np.zeros((FIRST_RING, 6), np.int64),
        "heap_f": np.zeros(FIRST_RING),
        "job_pool": np.full(n, -1, np.int64),
        "job_remaining": np.zeros(n),
        "job_threads": np.ones(n, np.int64),
        "job_priority": np.zeros(n, np.int64),
        "job_since": np.zeros(n, np.int64),
        "job_speed": np.zeros(n),
        "job_seq": np.zeros(n, np.int64),
        "job_compute": np.zeros(n),
        "job_feed": np.full(graph["feed"].shape[0], -1, np.int64),
        "job_read_at": np.zeros(n),
        "pool_ncores": np.zeros(pools, np.int64),
        "pool_cores": np.zeros((pools, cores), np.int64),
        "pool_fair": np.zeros(pools, np.bool_),
        "pool_jobs": np.zeros((pools, n), np.int64),
        "pool_njobs": np.zeros(pools, np.int64),
        "pool_busy": np.zeros(pools),
        "pool_dirty": np.zeros(pools, np.bool_),
        "sub_pool": np.zeros(max(subchains, 1), np.int64),
        "core_busy": np.zeros(cores),
        "finished": np.zeros(n, np.int64),
        "sort_buf": np.zeros(n, np.int64),
        "stack": np.zeros(n + int(graph["succ"].shape[0]) + 1, np.int64),
        "latest_id": np.full(n, -1, np.int64),
        "latest_at": np.zeros(n),
        "busy_seq": np.full(n, k.NO_SEQ, np.int64),
        "wait": np.zeros((n, FIRST_RING), np.int64),
        "wait_head": np.zeros(n, np.int64),
        "wait_tail": np.zeros(n, np.int64),
        "sub_seq": np.zeros(subchains, np.int64),
        "sub_pending": np.zeros(subchains, np.bool_),
        "sub_late": np.zeros(subchains, np.int64),
        "sub_steals": np.zeros(subchains, np.int64),
        "sub_skipped": np.zeros(subchains, np.int64),
        "heads_in_flight": np.zeros(subchains, np.int64),
        "flight_index": np.zeros((subchains, FIRST_RING), np.int64),
        "flight_at": np.zeros((subchains, FIRST_RING)),
        "flight_live": np.zeros((subchains, FIRST_RING), np.bool_),
        "flight_low": np.ones(subchains, np.int64),
        "raised": np.full(cores, -1, np.int64),
        "thief_late": np.zeros(max(subchains, 1), np.int64),
        "actions": np.full(ACTIONS, NONE, np.int64),
        "timer_busy": np.zeros(n, np.bool_),
        "timer_pending": np.zeros(n, np.bool_),
        "exec_running": np.full(executors, -1, np.int64),
        "exec_wait_node": np.zeros((executors, n), np.int64),
        "exec_wait_seq": np.zeros((executors, n), np.int64),
        "exec_wait_head": np.zeros(executors, np.int64),
        "exec_wait_tail": np.zeros(executors, np.int64),
        "done_n": 0,
        "done_node": np.zeros(FIRST_RECORDS, np.int64),
        "done_at": np.zeros(FIRST_RECORDS),
        "done_read": np.zeros(FIRST_RECORDS),
        "feeds_n": 0,
        "done_feeds": np.zeros(FIRST_RECORDS, np.int64),
        "stale_n": 0,
        "stale_node": np.zeros(FIRST_RECORDS, np.int64),
        "stale_ms": np.zeros(FIRST_RECORDS),
        "measured_ring": np.zeros((n, measured_window)),
        "measured_total": np.zeros(n, np.int64),
        "measured_taken": np.zeros(n, np.int64),
    }


def new_sim(*parts: Fields) -> k.Sim:
    """A :class:`kernel.Sim` from the fields of ``parts`` (each field given once)."""
    fields: Fields = {}
    for part in parts:
        fields.update(part)
    missing = set(k.FIELDS) - set(fields)
    if missing:  # pragma: no cover - a programming error
        raise AssertionError(f"kernel fields not given: {sorted(missing)}")
    return k.new_sim(*(fields[name] for name in k.FIELDS))


def run_compiled(sim: k.Sim, table: ScheduleTable | None, draws: DrawTable, end_ms: float,
                 reoptimiser: Reoptimiser | None) -> None:  # fmt: skip
    """Run the kernel to ``end_ms``: re-solving when it says so and drawing more compute times when it asks."""
    while True:
        status = k.run(sim, end_ms)
        if status == k.FINISHED:
            return
        if status == k.NEED_DRAWS:
            draws.grow(sim)
            continue
        assert table is not None
        assert reoptimiser is not None
        runs, last = k.take_measured(sim)
        window = last.shape[1]
        for name, count, times in zip(table.nodes, runs.tolist(), last, strict=True):
            if count:  # the last of each node's times, in the order they were measured; the rest only counted
                kept = min(count, window)
                reoptimiser.measurements.record_many(name, times[:kept], earlier=count - kept)
        now, current = k.clock_of(sim)
        after, reinstall, next_ms = reoptimiser.step(now, table.versions[current])
        version = table.add(after)
        if reinstall:
            k.install(sim, version)
        else:
            k.set_version(sim, version)
        k.schedule_reoptimise(sim, next_ms)


def records_of(
    sim: k.Sim,
    spec: Spec,
    chains: Sequence[tuple[str, ...]],
    replans: list[Replan],
    schedule: RuntimeSchedule | None,
) -> Records:
    """The run's records, grouped as the Python engine keeps them (as arrays: per node, per chain (n, 2))."""
    done_node, done_at, done_read, done_feeds, stale_node, stale_ms = k.records(sim)
    names = list(spec.nodes)
    by_chain, origin, arrived = k.chain_arrivals(
        done_node, done_at, done_read, done_feeds, *chain_tables(names, chains)
    )
    done = dict(zip(names, _grouped(done_at, done_node, len(names)), strict=True))
    stale = dict(zip(names, _grouped(stale_ms, stale_node, len(names)), strict=True))
    arrivals = _grouped(np.column_stack((origin, arrived)), by_chain, len(chains))
    return Records(done, stale, arrivals, {}, replans, schedule)


ChainTables = tuple[k.IntArray, k.IntArray, k.IntArray, k.IntArray, k.IntArray, k.IntArray, k.IntArray, int]


def chain_tables(names: Sequence[str], chains: Sequence[tuple[str, ...]]) -> ChainTables:
    """The chains as :func:`kernel.chain_arrivals` follows them: ``feed_ptr`` (as :func:`topology`),
    ``root``, ``trie_feed``, ``child_ptr/child``, ``head_ptr/head_chain`` and the number of chains.

    The trie's places are the chains' suffixes, each once, numbered as first met; a suffix's children
    are the suffixes one node longer.
    """
    index = {name: i for i, name in enumerate(names)}
    feeds = _feeds(names, chains)
    place_of: dict[tuple[str, ...], int] = {}
    feed_of: list[int] = []  # per place: which of the feeds of the node after it its node is (-1 at a root)
    children: list[list[int]] = []
    heads: list[list[int]] = []
    root = np.full(len(names), -1, np.int64)
    for c, chain in enumerate(chains):
        parent = -1
        for start in range(len(chain) - 1, -1, -1):
            suffix = chain[start:]
            if suffix not in place_of:
                place_of[suffix] = len(feed_of)
                after = suffix[1:]
                feed_of.append(feeds[index[after[0]]].index(index[suffix[0]]) if after else -1)
                children.append([])
                heads.append([])
                if parent >= 0:
                    children[parent].append(place_of[suffix])
                else:
                    root[index[suffix[0]]] = place_of[suffix]
            parent = place_of[suffix]
        heads[parent].append(c)
    return (_csr(feeds)[0], root, np.array(feed_of, np.int64), *_csr(children), *_csr(heads), len(chains))


def _grouped(values: npt.NDArray[np.float64], keys: k.IntArray, groups: int) -> list[npt.NDArray[np.float64]]:
    """``values`` (or their rows, if 2-D) by key (0..groups-1), each group in order: views of one sorted copy."""
    rows = values[:, np.newaxis] if values.ndim == 1 else values
    ordered, ptr = k.group_rows(np.ascontiguousarray(rows), keys, groups)
    if values.ndim == 1:
        ordered = ordered[:, 0]
    return [ordered[ptr[g] : ptr[g + 1]] for g in range(groups)]


def no_schedules() -> Fields:
    """Placeholders of the right shapes: the baselines never read a schedule."""
    ints2, floats2, bools2 = np.zeros((1, 1), np.int64), np.zeros((1, 1)), np.zeros((1, 1), np.bool_)
    return {
        "sub_ncores": ints2,
        "sub_cores": np.zeros((1, 1, 1), np.int64),
        "sub_shared": bools2,
        "sub_period": floats2,
        "sub_latency": floats2,
        "sub_late_after": floats2,
        "sub_runs": ints2,
        "node_threads": ints2,
        "node_speedup": floats2,
        "clocked": ints2,
        "n_shared": np.zeros(1, np.int64),
        "core_id": ints2,
        "core_period": floats2,
        "core_switch": floats2,
        "core_nslots": ints2,
        "slot_start": np.zeros((1, 1, 1)),
        "slot_length": np.zeros((1, 1, 1)),
        **dict(zip(RULE_FIELDS, empty_rules(1, 1, 1), strict=True)),
    }
