"""The app's data as the simulation runs: what each node last produced, and where it came from.

Every edge is *latest-value*: a run reads, when it starts, the newest output
of each predecessor (docs/explanation/model.md section 1).  A batch node consumes every
buffered input, which for the chains it is on is the same as reading the
newest (one run's output reflects all of them); its compute time is one draw
of its profile per run, as the planner budgets it.

To measure chains, an output carries its *origins*: for each reported chain
the node is on, when the chain's head produced the data this output derives
from along that chain.  A head's own run (or sensor tick) is the origin.
An unscheduled node with a rate (a sensor, a display at vsync) produces on
its own clock, reading its inputs; one without a rate (an integrator, an
actuator) passes on at once whatever reaches it.  Neither uses modelled CPU.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from catanc.spec.language import Spec

Origins = dict[int, float]  # chain index -> origin time (ms)


@dataclass(frozen=True)
class Output:
    at_ms: float
    origins: Origins


@dataclass
class NodeRecord:
    """What one node did over the run."""

    done_ms: list[float] = field(default_factory=list)  # completion time of every run (or tick)
    staleness_ms: list[float] = field(default_factory=list)  # per run: age of its oldest input when it started


class Dataflow:
    """Latest outputs, chain origins and records for the nodes of ``spec`` and the chains to measure."""

    def __init__(self, spec: Spec, chains: Sequence[tuple[str, ...]]) -> None:
        self.spec = spec
        self.chains = [tuple(chain) for chain in chains]
        self.predecessors: dict[str, list[str]] = {name: [] for name in spec.nodes}
        self.successors: dict[str, list[str]] = {name: [] for name in spec.nodes}
        for source, target in spec.edge_pairs:
            self.predecessors[target].append(source)
            self.successors[source].append(target)
        # Per node: (chain, the node before it on that chain, or None at the head).
        self.positions: dict[str, list[tuple[int, str | None]]] = {name: [] for name in spec.nodes}
        self.sink_of: dict[str, list[int]] = {name: [] for name in spec.nodes}
        for index, chain in enumerate(self.chains):
            for at, node in enumerate(chain):
                self.positions[node].append((index, chain[at - 1] if at else None))
            self.sink_of[chain[-1]].append(index)
        self.latest: dict[str, Output] = {}
        self.records: dict[str, NodeRecord] = {name: NodeRecord() for name in spec.nodes}
        # Per chain: (origin, done) of each output of its last node that carries an origin newer than
        # any before it.  The others show no response time (metrics.response_arrays), and on a
        # dedicated core a fast sink repeats one origin many times: keeping them cost most of the records.
        # Their origins rise, so the last one kept is the newest so far.
        self.arrivals: list[list[tuple[float, float]]] = [[] for _ in self.chains]
        self.listeners: list[Callable[[str, float], None]] = []  # told of every output: (node, time)

    def read_inputs(self, node: str, now_ms: float) -> Origins:
        """A run of ``node`` starts now: the origins of what it reads (its staleness is recorded)."""
        origins: Origins = {}
        latest = self.latest
        for index, before in self.positions[node]:
            if before is None:
                origins[index] = now_ms
            else:
                seen = latest.get(before)
                if seen is not None and index in seen.origins:
                    origins[index] = seen.origins[index]
        ages = [now_ms - latest[p].at_ms for p in self.predecessors[node] if p in latest]
        if ages:
            self.records[node].staleness_ms.append(max(ages))
        return origins

    def produce(self, node: str, origins: Origins, now_ms: float) -> None:
        """``node`` finished a run (or ticked) now with ``origins``: publish, record, pass on."""
        self.latest[node] = Output(now_ms, origins)
        self.records[node].done_ms.append(now_ms)
        for index in self.sink_of[node]:
            origin, kept = origins.get(index), self.arrivals[index]
            if origin is not None and (not kept or origin > kept[-1][0]):
                kept.append((origin, now_ms))
        for listener in self.listeners:
            listener(node, now_ms)
        for after in self.successors[node]:
            target = self.spec.nodes[after]
            if not target.scheduled and target.rate_hz is None:  # passes on at once
                self.produce(after, self.read_inputs(after, now_ms), now_ms)

    def tick(self, node: str, now_ms: float) -> None:
        """An unscheduled node with a rate produces on its own clock."""
        self.produce(node, self.read_inputs(node, now_ms), now_ms)
