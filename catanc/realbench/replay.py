"""Measured runs -> the simulator's metrics: replay every run's timestamps through its dataflow.

Each worker records every run as ``(node, start, end, cpu)`` on CLOCK_MONOTONIC
(:class:`catanc.runtime.worker.records.RunRecord`).  :func:`replay` puts the runs inside the measured
window in time order through :class:`catanc.sim.dataflow.Dataflow`, as the simulator
does with its simulated runs: a run *reads* its inputs' latest outputs when it starts and
*produces* when it ends, and every unscheduled node with a rate ticks on its own clock from
the window's start (:func:`catanc.sim.policies.start_sensors`).  At one instant, ends
come first, then ticks, then starts (what finished at ``t`` is there for a run starting at
``t``; a run that took no measurable time ends after it starts).  :func:`measured_result` then
builds the :class:`~catanc.sim.metrics.PolicyResult` with the simulator's own functions,
so ``catanc bench`` and ``catanc simulate`` report the same figures, computed the same way.

All pure: times are integers in ns as recorded, and the results are in ms from the window's
start.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from catanc.control.schedule import RuntimeSchedule
from catanc.runtime.worker.records import RunRecord
from catanc.sim.dataflow import Dataflow, Origins
from catanc.sim.metrics import PolicyResult, chain_result, node_result
from catanc.spec.language import Spec

END, TICK, START, END_AFTER_START = 0, 1, 2, 3
"""Event kinds, in the order they happen at one instant."""

NS_PER_MS = 1_000_000


def in_window(run: RunRecord, start_ns: int, end_ns: int) -> bool:
    """Whether ``run`` started and ended inside ``[start_ns, end_ns]`` (runs cut by either edge are left out)."""
    return start_ns <= run.start_ns and run.end_ns <= end_ns


def replay(
    spec: Spec, chains: Sequence[tuple[str, ...]], runs: Iterable[RunRecord], *, start_ns: int, end_ns: int
) -> Dataflow:
    """The dataflow of ``runs`` inside the window, with ``chains``' arrivals; ValueError for a malformed run."""
    if end_ns < start_ns:
        raise ValueError(f"the window ends ({end_ns}) before it starts ({start_ns})")
    flow = Dataflow(spec, chains)
    duration_ms = (end_ns - start_ns) / NS_PER_MS
    # (time ms, kind, order, index into kept, node)
    events: list[tuple[float, int, int, int, str]] = []
    kept: list[RunRecord] = []
    for run in sorted(runs, key=lambda r: (r.start_ns, r.end_ns, r.node)):
        node = spec.nodes.get(run.node)
        if node is None or not node.scheduled:
            raise ValueError(f"a run of {run.node!r}, which is not a scheduled node of {spec.app}")
        if run.end_ns < run.start_ns:
            raise ValueError(f"a run of {run.node!r} ends ({run.end_ns}) before it starts ({run.start_ns})")
        if not in_window(run, start_ns, end_ns):
            continue
        index = len(kept)
        kept.append(run)
        begin = (run.start_ns - start_ns) / NS_PER_MS
        finish = (run.end_ns - start_ns) / NS_PER_MS
        events.append((begin, START, index, index, run.node))
        events.append((finish, END if finish > begin else END_AFTER_START, index, index, run.node))
    for order, (name, node) in enumerate(spec.nodes.items()):
        if node.scheduled or node.rate_hz is None:
            continue
        period = 1000.0 / node.rate_hz
        tick = 0
        while tick * period <= duration_ms:
            events.append((tick * period, TICK, order, -1, name))
            tick += 1
    events.sort()
    reading: dict[int, Origins] = {}
    for at_ms, kind, _, index, name in events:
        if kind == TICK:
            flow.tick(name, at_ms)
        elif kind == START:
            reading[index] = flow.read_inputs(name, at_ms)
        else:
            flow.produce(name, reading.pop(index), at_ms)
    return flow


def utilisation(
    runs: Iterable[RunRecord], cores_of: Mapping[str, Sequence[int]], cores: int, *, start_ns: int, end_ns: int
) -> tuple[float, ...]:
    """Per core, the share of the window the app's runs used it (0..1).

    A run's CPU time (all its threads') is spread evenly over the cores its node may run on
    (``cores_of``; every core for a node not listed), as the simulator spreads a pool's work
    over its cores.  Runs cut by the window's edges are left out, as in :func:`replay`.
    """
    window_ns = end_ns - start_ns
    busy = [0.0] * cores
    if window_ns <= 0:
        return tuple(busy)
    for run in runs:
        if not in_window(run, start_ns, end_ns):
            continue
        allowed = [core for core in cores_of.get(run.node, range(cores)) if 0 <= core < cores] or list(range(cores))
        for core in allowed:
            busy[core] += run.cpu_ns / len(allowed)
    return tuple(b / window_ns for b in busy)


def measured_result(
    policy: str,
    flow: Dataflow,
    chains: Sequence[tuple[tuple[str, ...], bool]],
    *,
    duration_s: float,
    utilisation: tuple[float, ...],
    replans: int = 0,
    model: Mapping[tuple[str, ...], float] | None = None,
    promised: Mapping[str, float] | None = None,
    schedule: RuntimeSchedule | None = None,
) -> PolicyResult:
    """A replayed run as the simulator reports a simulated one (``catanc.sim.simulate.simulate``)."""
    duration_ms = duration_s * 1000.0
    found, rates = model or {}, promised or {}
    return PolicyResult(
        policy=policy,
        duration_s=duration_s,
        chains=tuple(
            chain_result(nodes, named, arrivals, found.get(nodes))
            for (nodes, named), arrivals in zip(chains, flow.arrivals, strict=True)
        ),
        nodes={
            name: node_result(record.done_ms, record.staleness_ms, duration_ms, rates.get(name))
            for name, record in flow.records.items()
        },
        utilisation=utilisation,
        replans=replans,
        node_done_ms={name: np.asarray(record.done_ms, dtype=np.float64) for name, record in flow.records.items()},
        schedule=schedule,
    )
