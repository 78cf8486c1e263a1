"""The hand-tuned baselines' triggers, as pure state: who runs when, without sockets or clocks.

The rules:

- every scheduled node listed in ``baseline.rates_hz`` runs on its own timer at that rate,
  from the run's start (time 0, then every period, never skipping one);
- every other scheduled node runs when a new input arrives: from its scheduled
  predecessors if it has any, else from its unscheduled predecessors with a rate (sensors,
  which tick on their own clocks from time 0);
- a node triggered while it runs is triggered again once, when it is done (a depth-1 queue:
  further triggers meanwhile coalesce into that one).

:class:`Clock` says which timers and sensor ticks are due, :class:`Triggers` which nodes to
start on a timer, an input or a completion.  The simulator's timer policy
(:class:`catanc.sim.policies.TimerPolicy`, and the compiled kernel through
:mod:`catanc.sim.fast`) and ``catanc bench``'s driver (:mod:`catanc.realbench.driver`, the
I/O) use both, so the bench's baselines are the simulator's by construction.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass
from typing import Literal

from catanc.errors import UsageError
from catanc.spec.language import Spec

TIMER: Literal["timer"] = "timer"
TICK: Literal["tick"] = "tick"
Kind = Literal["timer", "tick"]


@dataclass(frozen=True)
class TriggerRules:
    """A spec's baseline: timers, sensor clocks, and whose outputs trigger whom."""

    timers: dict[str, float]  # scheduled node listed in baseline.rates_hz -> its period (ms)
    sensors: dict[str, float]  # unscheduled node with a rate -> its period (ms)
    fed: dict[str, tuple[str, ...]]  # node or sensor -> the input-triggered nodes its outputs trigger


def trigger_rules(spec: Spec, purpose: str = "run") -> TriggerRules:
    """The baseline's rules; :class:`UsageError` without ``baseline.rates_hz`` (nothing to ``purpose``) or for a
    node nothing triggers."""
    rates = spec.baseline.rates_hz
    if not rates:
        raise UsageError(f"{spec.app}: the spec has no baseline (baseline.rates_hz) to {purpose}")
    timers = {name: 1000.0 / rate for name, rate in sorted(rates.items()) if spec.nodes[name].scheduled}
    sensors = {
        name: 1000.0 / node.rate_hz
        for name, node in spec.nodes.items()
        if not node.scheduled and node.rate_hz is not None
    }
    predecessors: dict[str, list[str]] = {name: [] for name in spec.nodes}
    for source, target in spec.edge_pairs:
        predecessors[target].append(source)
    fed: dict[str, list[str]] = {}
    gaps = []
    for name, node in sorted(spec.nodes.items()):
        if not node.scheduled or name in timers:
            continue
        scheduled = [p for p in predecessors[name] if spec.nodes[p].scheduled]
        clocked = [p for p in predecessors[name] if p in sensors]
        feeders = scheduled or clocked
        if not feeders:
            gaps.append(name)
        for feeder in sorted(feeders):
            fed.setdefault(feeder, []).append(name)
    if gaps:
        raise UsageError(
            f"{spec.app}: the baseline gives {', '.join(gaps)} no rate in baseline.rates_hz and no input with one"
        )
    return TriggerRules(timers, sensors, {name: tuple(targets) for name, targets in sorted(fed.items())})


class Triggers:
    """Which nodes to start now, given timers, inputs and completions (busy nodes coalesce to depth 1)."""

    def __init__(self, rules: TriggerRules) -> None:
        self.rules = rules
        self.busy: set[str] = set()
        self.pending: set[str] = set()

    def fire(self, node: str) -> list[str]:
        """``node``'s timer fired or a new input reached it: ``[node]`` to start it, or ``[]`` if it runs."""
        if node in self.busy:
            self.pending.add(node)
            return []
        self.busy.add(node)
        return [node]

    def output(self, node: str) -> list[str]:
        """``node`` produced (a run ended, or a sensor ticked): the nodes it triggers that start now."""
        started: list[str] = []
        for target in self.rules.fed.get(node, ()):
            started += self.fire(target)
        return started

    def done(self, node: str) -> list[str]:
        """``node`` finished a run: what its output triggers, then ``node`` again if a trigger waited."""
        started = self.output(node)
        return started + self.free(node)

    def free(self, node: str) -> list[str]:
        """``node`` is idle again (its output was handled): ``[node]`` if a trigger waited for it, else ``[]``."""
        self.busy.discard(node)
        if node in self.pending:
            self.pending.discard(node)
            return self.fire(node)
        return []

    def abandon(self, node: str) -> None:
        """``node`` will not report its run (its thread left): it is idle, nothing waits for it."""
        self.busy.discard(node)
        self.pending.discard(node)


class Clock:
    """Timers and sensor ticks from ``start_ms``, each every period; ties in the order they were set."""

    def __init__(self, rules: TriggerRules, start_ms: float) -> None:
        self._order = itertools.count()
        self._heap: list[tuple[float, int, Kind, str, float]] = []
        # Sensors first, then timers by name: the simulator starts its sensors before its policy.
        for name, period in rules.sensors.items():
            self._push(start_ms, TICK, name, period)
        for name, period in sorted(rules.timers.items()):
            self._push(start_ms, TIMER, name, period)

    def _push(self, due_ms: float, kind: Kind, node: str, period_ms: float) -> None:
        heapq.heappush(self._heap, (due_ms, next(self._order), kind, node, period_ms))

    def next_ms(self) -> float:
        """When the next timer or tick is due (infinity if there is none)."""
        return self._heap[0][0] if self._heap else math.inf

    def due(self, now_ms: float) -> list[tuple[float, Kind, str]]:
        """Every ``(due_ms, kind, node)`` due at or before ``now_ms``, in time order; each is set again a period on."""
        events = []
        while self._heap and self._heap[0][0] <= now_ms:
            due_ms, _, kind, node, period_ms = heapq.heappop(self._heap)
            events.append((due_ms, kind, node))
            self._push(due_ms + period_ms, kind, node, period_ms)
        return events
