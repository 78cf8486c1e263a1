"""The enforcer's own costs, measured as it runs (docs/explanation/model.md section 5).

- **Switch**: from a boundary's due time until its owner is raised and its head triggered
  (the enforcer waking late, then its own CPU), per shared core.
- **Hop**: from a trigger to the head's start, and from a node's end to the next node's start
  (read from the nodes' rings); the latter per edge too, ``producer -> consumer``, which
  ``catanc profile --write`` writes into the spec's ``hops_ms`` (docs/explanation/model.md section 5),
  the former per head too (its *dispatch*: a ROS 2 head's trigger crosses catanc.ros's watcher
  thread and the executor's wake-up), which it writes into ``dispatch_ms``.
- **Overhead**: the enforcer's CPU share of the core its loop is pinned to, and its CPU per
  wake-up, from its thread's CPU clock between two readings.

:meth:`Costs.summary` gives the figures the log, the status, ``catanc report`` and a machine
profile (``catanc calibrate``) use: p50, p95 and max of each, and the share.  A plan charges each
once (:func:`catanc.spec.machine.costs`): the overhead as slack, each slot's hop beyond the
enforcer's CPU per wake-up as its switch_ms; but not a hop the spec budgets in a c(S) already (an
edge of its ``hops_ms``, a head of its ``dispatch_ms``: :attr:`Costs.planned`), which would count
twice on a shared core.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from catanc.control.measure import percentile
from catanc.spec.language import Spec, parse_arrow
from catanc.spec.machine import MACHINE_FORMAT, MachineProfile, MeasuredOn, RtLimit

SAMPLES = 1024
"""Samples of each kind kept (the latest): quantiles of a few seconds' switches, cheap to sort once a second."""
MIN_SWITCHES = 500
"""Switches measured before the figures stand for the machine (a re-plan with them, a profile)."""
MAX_SHARE = 0.99
RT_RUNTIME = Path("/proc/sys/kernel/sched_rt_runtime_us")
RT_PERIOD = Path("/proc/sys/kernel/sched_rt_period_us")


def quantiles(samples: Iterable[float]) -> dict[str, float] | None:
    values = list(samples)
    if not values:
        return None
    return {
        "p50_ms": round(percentile(values, 50), 4),
        "p95_ms": round(percentile(values, 95), 4),
        "max_ms": round(max(values), 4),
        "count": len(values),
    }


@dataclass
class Costs:
    """The enforcer's measured costs so far."""

    switches: dict[int, deque[float]] = field(default_factory=dict)  # core -> switch latencies (ms)
    hops: deque[float] = field(default_factory=lambda: deque(maxlen=SAMPLES))  # both kinds: what a slot pays
    inside: deque[float] = field(default_factory=lambda: deque(maxlen=SAMPLES))  # node to node in a subchain
    heads: deque[float] = field(default_factory=lambda: deque(maxlen=SAMPLES))  # a head's trigger to its start
    edges: dict[tuple[str, str], deque[float]] = field(default_factory=dict)  # (producer, consumer) -> its hops
    dispatches: dict[str, deque[float]] = field(default_factory=dict)  # head -> its triggers' delays to its starts
    planned: frozenset[str] = frozenset()  # edges ("a -> b") and heads whose hop the spec's c(S) holds
    unplanned: deque[float] = field(default_factory=lambda: deque(maxlen=SAMPLES))  # the other hops: a slot's
    wakes: int = 0
    cpu_ns: int = 0  # the loop thread's CPU time at the last reading
    wall_ns: int = 0  # when it was read
    window: deque[tuple[int, int, int]] = field(default_factory=lambda: deque(maxlen=64))  # (wall, cpu, wakes)
    core: int | None = None  # the plan core the loop runs on

    def switch(self, core: int, latency_ms: float) -> None:
        samples = self.switches.get(core)
        if samples is None:
            samples = self.switches[core] = deque(maxlen=SAMPLES)
        samples.append(latency_ms)

    def hop(self, delay_ms: float, inside: bool, edge: tuple[str, str] | None = None, head: str | None = None) -> None:
        """A node's end to the next node's start in its subchain (``inside``, over ``edge``), or a head's trigger
        to its start (``head``: which one)."""
        self.hops.append(delay_ms)
        (self.inside if inside else self.heads).append(delay_ms)
        key = None
        if edge is not None:
            _kept(self.edges, edge).append(delay_ms)
            key = edge_key(*edge)
        if head is not None and not inside:
            _kept(self.dispatches, head).append(delay_ms)
            key = head
        if key not in self.planned:
            self.unplanned.append(delay_ms)

    def cpu(self, wall_ns: int, cpu_ns: int) -> None:
        """A reading of the loop thread's CPU clock (once a second or so)."""
        self.window.append((wall_ns, cpu_ns, self.wakes))
        self.wall_ns, self.cpu_ns = wall_ns, cpu_ns

    def share(self, span: int = 8) -> tuple[float | None, float | None]:
        """The loop's CPU share of its core and its CPU per wake-up (ms), over the last ``span`` readings."""
        if len(self.window) < 2:
            return None, None
        (wall0, cpu0, wakes0), (wall1, cpu1, wakes1) = self.window[-min(span, len(self.window))], self.window[-1]
        share = (cpu1 - cpu0) / (wall1 - wall0) if wall1 > wall0 else None
        per_wake = (cpu1 - cpu0) / 1e6 / (wakes1 - wakes0) if wakes1 > wakes0 else None
        return share, per_wake

    def summary(self, cores: int) -> dict[str, Any]:
        share, per_wake = self.share()
        overhead = [0.0] * cores
        if share is not None and self.core is not None and self.core < cores:
            overhead[self.core] = round(share, 5)
        everything = [latency for samples in self.switches.values() for latency in samples]
        return {
            "switch": quantiles(everything),
            "switch_by_core": {str(core): quantiles(samples) for core, samples in sorted(self.switches.items())},
            "hop": quantiles(self.hops),
            "hop_inside": quantiles(self.inside),
            "hop_head": quantiles(self.heads),
            "hop_unplanned": quantiles(self.unplanned),
            "hop_by_edge": {edge_key(*edge): quantiles(samples) for edge, samples in sorted(self.edges.items())},
            "dispatch_by_head": {head: quantiles(samples) for head, samples in sorted(self.dispatches.items())},
            "overhead": overhead,
            "cpu_per_wake_ms": None if per_wake is None else round(per_wake, 5),
            "wakes": self.wakes,
            "loop_core": self.core,
        }


K = TypeVar("K")


def _kept(by_key: dict[K, deque[float]], key: K) -> deque[float]:
    """``key``'s latest samples (a new deque the first time)."""
    samples = by_key.get(key)
    if samples is None:
        samples = by_key[key] = deque(maxlen=SAMPLES)
    return samples


def planned_hops(spec: Spec) -> frozenset[str]:
    """The hops ``spec`` budgets in a subchain's c(S): its ``hops_ms`` edges (as :func:`edge_key` names them) and
    its ``dispatch_ms`` heads."""
    return frozenset({edge_key(*parse_arrow(key)) for key in spec.hops_ms} | set(spec.dispatch_ms))


def edge_key(producer: str, consumer: str) -> str:
    """An edge as the spec's ``hops_ms`` and the log name it: ``producer -> consumer``."""
    return f"{producer} -> {consumer}"


def rt_limit() -> RtLimit:
    """The kernel's SCHED_FIFO budget (``/proc/sys/kernel/sched_rt_{runtime,period}_us``)."""
    return RtLimit(runtime_us=int(RT_RUNTIME.read_text().strip()), period_us=int(RT_PERIOD.read_text().strip()))


def this_machine() -> MeasuredOn:
    """The machine measured on, for people reading a profile: host name, CPU model, kernel, CPUs."""
    cpu = None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    name = os.uname()
    return MeasuredOn(host=name.nodename, cpu=cpu, kernel=name.release, cpus=os.cpu_count())


def measured_profile(
    summary: dict[str, Any], *, rt: RtLimit, machine: MeasuredOn, minimum: int = MIN_SWITCHES
) -> MachineProfile | None:
    """A machine profile of what :meth:`Costs.summary` measured: p95 switch and hop (of the hops no c(S) holds),
    the enforcer's CPU per wake-up, the share of each core.

    None until ``minimum`` switches were measured (a few seconds of a busy core).
    """
    switch = summary.get("switch")
    hop = summary["hop_unplanned"] if "hop_unplanned" in summary else summary.get("hop")  # an older summary: all
    if not switch or int(switch["count"]) < minimum:
        return None
    return MachineProfile(
        format=MACHINE_FORMAT,
        machine=machine,
        switch_ms=float(switch["p95_ms"]),
        hop_ms=float(hop["p95_ms"]) if hop else 0.0,
        wake_ms=float(summary.get("cpu_per_wake_ms") or 0.0),
        overhead=[min(float(share), MAX_SHARE) for share in summary.get("overhead") or [0.0]],
        rt=rt,
    )
