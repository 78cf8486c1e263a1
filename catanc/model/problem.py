"""The planning problem a spec states: subchains, chains, terms, bounds, executors.

A :class:`Problem` is what the solver stages and the analytic model read:
chains are already collapsed into stages (docs/explanation/model.md section 2).
:func:`catanc.model.build.build_problem` makes one from a spec.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

from catanc.errors import Diagnostic, FieldPath, UsageError, did_you_mean
from catanc.spec.speedup import best_speedup


@dataclass(frozen=True)
class Subchain:
    """Nodes run at one rate; only the first is triggered (docs/explanation/model.md 1)."""

    name: str
    nodes: tuple[str, ...]
    node_compute_ms: tuple[float, ...]  # per node, planning value, one thread
    node_speedups: tuple[tuple[float, ...], ...]  # per node, speedup with 1..max threads
    batch: bool
    min_period_ms: float = 0.0  # from max_rate_hz / rate_hz
    max_period_ms: float = math.inf  # from min_rate_hz / rate_hz
    serial: tuple[tuple[int, ...], ...] = ()  # positions of nodes that share one executor thread (2+ each)
    # What a run waits for the runtime, summed: its head's measured ``dispatch_ms`` and one hop per edge inside
    # it, the spec's measured ``hops_ms`` (docs/explanation/model.md section 5)
    hops_ms: float = 0.0
    # The rates its driver offers (2+, ascending; docs/reference/spec.md): the plan picks one. While
    # not chosen, ``min/max_period_ms`` span them; once chosen (:meth:`Problem.choosing`), both are that one.
    offered_hz: tuple[float, ...] = ()
    offered_by: str = ""  # the node whose constraint lists them
    # The period bounds without the offered list (what a free rate may take: explain's comparison).
    free_period_range_ms: tuple[float, float] = (0.0, math.inf)

    @property
    def offered_periods_ms(self) -> tuple[float, ...]:
        """The offered rates' periods, ascending (the fastest rate first)."""
        return tuple(1000.0 / rate for rate in reversed(self.offered_hz))

    @property
    def offers_choice(self) -> bool:
        """Whether its rate is still to be picked from the offered ones."""
        return len(self.offered_periods_ms) > 1 and self.min_period_ms < self.max_period_ms

    @cached_property
    def compute_ms(self) -> float:
        """``c(S)``: the subchain's total time per run, its nodes' compute plus its head's dispatch and its inside hops
        (summed once: the planner asks thousands of times)."""
        return math.fsum((*self.node_compute_ms, self.hops_ms))

    def compute_by_threads(self, cores: int) -> list[list[float]]:
        """``c^q_j`` (Eq. 1): node j's compute with at most q threads, for q = 1..cores."""
        return [
            [c / best_speedup(s, q) for c, s in zip(self.node_compute_ms, self.node_speedups, strict=True)]
            for q in range(1, cores + 1)
        ]


@dataclass(frozen=True)
class Stage:
    """One element of a collapsed chain: a subchain, or an unscheduled node's fixed clock."""

    name: str  # subchain name, or the unscheduled node's name when ``fixed``
    fixed: bool = False


@dataclass(frozen=True)
class Chain:
    """A DAG path and its sequence of stages."""

    nodes: tuple[str, ...]
    stages: tuple[Stage, ...]
    head_period_ms: float | None = None  # a batch head's observed output period

    @property
    def label(self) -> str:
        return " -> ".join(self.nodes)


@dataclass(frozen=True)
class ChainForm:
    """A chain's response ``R = L + P`` as sums over its stages: what each solver writes down.

    ``L = constant + sum latency(latency_of) + sum period(period_of)`` and
    ``P >= floor``, ``P >= period(s)`` for each ``s`` in ``longest_of``.
    Unscheduled clocks are constants; a batch head's observed period bounds
    ``P`` instead of its subchain's.  :func:`evaluate_chain` is computed
    independently, so the tests can hold the solvers' encodings to it.
    """

    constant: float
    latency_of: tuple[str, ...]
    period_of: tuple[str, ...]
    longest_of: tuple[str, ...]
    floor: float


def chain_form(problem: Problem, chain: Chain) -> ChainForm:
    constant, floor = 0.0, 0.0
    latency_of: list[str] = []
    period_of: list[str] = []
    longest_of: list[str] = []
    for position, stage in enumerate(chain.stages):
        if stage.fixed:
            fixed = problem.fixed_periods_ms[stage.name]
            floor = max(floor, fixed)
            constant += fixed if position == 0 else 2 * fixed  # a clock's latency is its period
            continue
        if position == 0 and chain.head_period_ms is not None:
            floor = max(floor, chain.head_period_ms)
        else:
            longest_of.append(stage.name)
        latency_of.append(stage.name)
        if position > 0:
            period_of.append(stage.name)  # at each later stage the input may wait a whole period
    return ChainForm(constant, tuple(latency_of), tuple(period_of), tuple(longest_of), floor)


@dataclass(frozen=True)
class ResponseTerm:
    """``weight * R`` of one chain, from the spec entry at ``origin``."""

    chain: int  # index into Problem.chains
    weight: float
    origin: FieldPath


@dataclass(frozen=True)
class PeriodTerm:
    """``weight * p`` of one subchain (a node's throughput term)."""

    subchain: str
    node: str
    weight: float
    origin: FieldPath


@dataclass(frozen=True)
class ResponseBound:
    """``R <= max_response_ms`` for one chain."""

    chain: int
    max_response_ms: float
    origin: FieldPath


@dataclass(frozen=True)
class Executor:
    """Scheduled nodes that share one single-threaded executor: they run one after the other.

    Declared by an ``executors:`` entry, or implied by a process that runs its nodes in one thread
    (:mod:`catanc.spec.executors`).
    """

    name: str
    nodes: tuple[str, ...]
    subchains: tuple[str, ...]  # the subchains its nodes belong to, in spec order
    where: str = field(default="", compare=False)  # ``file:line:col`` of its declaration ("" without a source)
    declared: str = field(default="", compare=False)  # the field declaring it: executors.mapper, deploy.GP.ros_node
    process: str | None = None  # the process whose nodes share its thread, when one does
    why: str = field(default="", compare=False)  # why that process runs them in one thread

    @property
    def label(self) -> str:
        return f"executor {self.name!r}" + (f" ({self.where})" if self.where else "")

    @property
    def field_name(self) -> str:
        """The field declaring it, for a message (``executors.<name>`` where none was recorded)."""
        return self.declared or f"executors.{self.name}"


@dataclass(frozen=True)
class Problem:
    """The planning problem a spec states, ready for the solver stages."""

    app: str
    subchains: tuple[Subchain, ...]
    fixed_periods_ms: dict[str, float]  # unscheduled node -> period of its own clock
    chains: tuple[Chain, ...]
    response_terms: tuple[ResponseTerm, ...]
    period_terms: tuple[PeriodTerm, ...]
    response_bounds: tuple[ResponseBound, ...]
    # Where the spec text says what (its line), not what is planned: a spec re-read without its file is equal.
    warnings: tuple[Diagnostic, ...] = field(default=(), compare=False)
    slack: float = 0.0  # the schedule's idle share of every core, dedicated ones too (docs/explanation/model.md 4)
    executors: tuple[Executor, ...] = field(default=())

    @cached_property
    def together(self) -> tuple[tuple[str, ...], ...]:
        """Sets of 2+ subchains that must share one core: their executors' nodes span them.

        Executors that touch a common subchain merge (a thread cannot be on
        two cores).  Members in spec order; sets ordered by first member.
        """
        order = {sub.name: index for index, sub in enumerate(self.subchains)}
        sets: list[set[str]] = []
        for executor in self.executors:
            merged = set(executor.subchains)
            for other in [s for s in sets if s & merged]:
                merged |= other
                sets.remove(other)
            sets.append(merged)
        units = [tuple(sorted(s, key=order.__getitem__)) for s in sets if len(s) >= 2]
        return tuple(sorted(units, key=lambda unit: order[unit[0]]))

    def importance(self) -> dict[str, float]:
        """Total weight of the objective terms each subchain appears in (order, priority, branching)."""
        weight = dict.fromkeys((sub.name for sub in self.subchains), 0.0)
        for term in self.response_terms:
            for stage in {s.name for s in self.chains[term.chain].stages if not s.fixed}:
                weight[stage] += term.weight
        for period_term in self.period_terms:
            weight[period_term.subchain] += period_term.weight
        return weight

    @property
    def weighted(self) -> bool:
        """Whether any objective term has a positive weight (else every feasible plan is optimal)."""
        return any(t.weight > 0 for t in self.response_terms) or any(t.weight > 0 for t in self.period_terms)

    def bounded(self) -> set[str]:
        """Subchains a bound depends on: a rate floor, or a stage of a bounded chain."""
        names = {sub.name for sub in self.subchains if sub.max_period_ms < math.inf}
        for bound in self.response_bounds:
            names |= {s.name for s in self.chains[bound.chain].stages if not s.fixed}
        return names

    @cached_property
    def chain_forms(self) -> tuple[ChainForm, ...]:
        """Every chain's :class:`ChainForm`, computed once (its structure never changes)."""
        return tuple(chain_form(self, chain) for chain in self.chains)

    def subchain(self, name: str) -> Subchain:
        return self._subchain_by_name[name]

    @cached_property
    def _subchain_by_name(self) -> dict[str, Subchain]:
        return {sub.name: sub for sub in self.subchains}

    def subchain_of(self, node: str) -> Subchain:
        """The subchain scheduled node ``node`` runs in (:class:`KeyError` if it is not scheduled)."""
        return self._subchain_by_node[node]

    def last_scheduled(self, nodes: Sequence[str]) -> str | None:
        """The last of ``nodes`` that runs in a subchain: where a chain's data leaves its last subchain."""
        return next((node for node in reversed(nodes) if node in self._subchain_by_node), None)

    @cached_property
    def _subchain_by_node(self) -> dict[str, Subchain]:
        return {node: sub for sub in self.subchains for node in sub.nodes}

    def offered(self) -> tuple[Subchain, ...]:
        """Subchains whose rate is still to be picked from the rates their driver offers."""
        return tuple(sub for sub in self.subchains if sub.offers_choice)

    def choosing(self, periods_ms: Mapping[str, float]) -> Problem:
        """The same problem with these subchains' offered periods picked: each then a fixed rate."""
        if not periods_ms:
            return self
        return self._with_bounds({name: (period, period) for name, period in periods_ms.items()})

    def freed(self) -> Problem:
        """The same problem with every offered list dropped: those rates free within their other bounds."""
        freed = {sub.name: sub.free_period_range_ms for sub in self.subchains if sub.offered_hz}
        return self._with_bounds(freed, keep_offered=False)

    def _with_bounds(self, bounds: Mapping[str, tuple[float, float]], *, keep_offered: bool = True) -> Problem:
        subchains = tuple(
            replace(
                sub,
                min_period_ms=bounds[sub.name][0],
                max_period_ms=bounds[sub.name][1],
                offered_hz=sub.offered_hz if keep_offered else (),
            )
            if sub.name in bounds
            else sub
            for sub in self.subchains
        )
        return self._with_subchains(subchains)

    def _with_subchains(self, subchains: tuple[Subchain, ...]) -> Problem:
        """The same problem over new subchain records of the same subchains (the chains' forms kept)."""
        updated = replace(self, subchains=subchains)
        if "chain_forms" in self.__dict__:  # the same chains: keep their forms
            updated.__dict__["chain_forms"] = self.__dict__["chain_forms"]
        return updated

    def with_compute(self, compute_ms: Mapping[str, float]) -> Problem:
        """The same problem with new planning compute times (ms, one thread) for some scheduled nodes.

        Raises :class:`UsageError` for a name that is not a scheduled node or a
        time that is not a positive finite number.
        """
        owner = self._subchain_by_node
        for node, value in compute_ms.items():
            if node not in owner:
                hint = did_you_mean(node, owner)
                raise UsageError(f"compute time for {node!r}: not a scheduled node of {self.app}{hint}")
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise UsageError(f"compute time for {node!r}: {value!r} ms is not a positive finite number")
        touched = {owner[node].name for node in compute_ms}
        subchains = tuple(
            replace(
                sub,
                node_compute_ms=tuple(
                    float(compute_ms.get(n, c)) for n, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
                ),
            )
            if sub.name in touched
            else sub
            for sub in self.subchains
        )
        return self._with_subchains(subchains)
