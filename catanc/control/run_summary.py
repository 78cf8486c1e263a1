"""A ``catanc run`` log's summary: what ``catanc report`` prints, as typed data.

The core is pure: :func:`summarise` turns the log's events (see
:mod:`catanc.runtime.logs.writer`) into a :class:`RunSummary`.
:mod:`catanc.runtime.logs.report` renders it (tables, JSON) and is the
command; :mod:`catanc.runtime.logs.timeline` plots it.

What the numbers mean:

- A run's length is the latest ``t`` in the log (the ``stop`` event's, after
  a clean end); times count from the enforcer's start.
- A subchain's measured rate is its completed runs (``run`` events) per
  second over the whole run, and over the last plan's period of validity:
  from the last ``start`` or ``resolve`` event to the end of the log.
- Planned rates are ``1000 / period_ms`` from the plan of the ``start`` event
  and of every ``resolve``; only changes are kept, so a subchain whose
  period never changed has one entry.
- Late, lost, steals and skipped are the enforcer's own counters from the
  last ``status`` or ``stop`` event (None when the log has neither).
- Percentiles are :func:`catanc.control.measure.percentile`'s (linear
  interpolation), the same definition the enforcer plans with.
- The enforcer's own costs (switch latency, hop delay, its CPU share) are
  its own figures from the last ``status`` or ``stop`` event.
- A chain's response measured from origins (:func:`chain_response`): each
  ``compute`` sample's ``age_ms`` is its run's end less the run's origin (when
  the data it carries was sensed: a ROS message's ``header.stamp``, else a
  triggered head's start).  A chain's response is the age of the runs of its
  last scheduled node, where data leaves the chain's last subchain; where
  that node reports no ages, the last node before it that does (then the
  figure leaves out the rest of the chain: a lower bound, marked so).  A
  node in several chains gives each the ages of its own runs.  The plan's
  response and the bound are the last plan's (the ``start`` or ``resolve``
  event's ``chains``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from catanc.control.measure import percentile

RATE_BIN_S = 1.0
"""Width of the plot's measured-rate bins (seconds)."""


@dataclass(frozen=True)
class Stats:
    """Count, mean, 95th percentile and range of some milliseconds."""

    count: int
    mean_ms: float
    p95_ms: float
    min_ms: float
    max_ms: float


@dataclass(frozen=True)
class PlannedRate:
    """From ``t_s`` on, a plan asks for one run every ``period_ms`` and expects ``expected_hz`` of them."""

    t_s: float
    period_ms: float
    as_run_hz: float | None = None  # what an executor's thread leaves of ``hz`` (None: all of it)

    @property
    def hz(self) -> float:
        return 1000.0 / self.period_ms

    @property
    def expected_hz(self) -> float:
        """The rate the plan promises: ``hz``, less what an executor's thread takes.

        docs/explanation/executor-planning.md says how an executor's thread takes it."""
        return self.hz if self.as_run_hz is None else self.as_run_hz


@dataclass(frozen=True)
class SubchainSummary:
    name: str
    runs: int  # completed runs (``run`` events)
    measured_hz: float | None  # runs per second over the whole run; None for a run of no length
    last_plan_hz: float | None  # runs per second since the last plan; None if it came at the very end
    planned: tuple[PlannedRate, ...]  # every change of the planned period, in time order
    latency: Stats | None  # trigger to last node done, over the ``run`` events
    late: int | None  # the rest: the enforcer's counters at its last status or stop
    lost: int | None
    steals: int | None
    skipped: int | None
    run_times_s: tuple[float, ...] = field(default=(), repr=False)  # when each run completed, for the plot


@dataclass(frozen=True)
class NodeSummary:
    name: str
    compute: Stats | None  # the node's measured compute times; None when it has none
    unmeasured: int  # ``compute`` events without a usable time
    samples: tuple[tuple[float, float], ...] = field(default=(), repr=False)  # (t_s, ms), for the plot


@dataclass(frozen=True)
class ResolveSummary:
    """One re-plan: when, why, how long it took, what it made."""

    t_s: float
    reason: str
    stage1: bool  # a new allocation was asked for (Stage I and II), not only new periods
    allocation_changed: bool
    solve_ms: float | None
    objective: float | None
    error: str | None  # the re-plan failed and the last plan was kept


@dataclass(frozen=True)
class Quantiles:
    """p50, p95 and the maximum of some milliseconds the enforcer measured itself."""

    count: int
    p50_ms: float
    p95_ms: float
    max_ms: float


@dataclass(frozen=True)
class CostsSummary:
    """The enforcer's own costs, as its last ``status`` or ``stop`` event gives them."""

    switch: Quantiles | None  # a boundary's due time to its owner raised and its head triggered
    hop: Quantiles | None  # a node's end (or a trigger) to the next node's start
    hop_inside: Quantiles | None  # a node's end to the next node's start in its subchain (None: an older log)
    hop_head: Quantiles | None  # a head's trigger to its start (None: an older log)
    share: float | None  # the enforcer's CPU share of the core its loop runs on
    cpu_per_wake_ms: float | None
    hop_by_edge: tuple[tuple[str, Quantiles], ...] = ()  # per edge inside a subchain ("a -> b"), sorted
    dispatch_by_head: tuple[tuple[str, Quantiles], ...] = ()  # a head's trigger to its start, per head, sorted


@dataclass(frozen=True)
class ChainSummary:
    """One chain of the objective and constraints: its response as planned, bounded and measured from origins."""

    nodes: tuple[str, ...]
    planned_ms: float | None  # the last plan's response time R
    bound_ms: float | None  # the spec's max_response_ms (None: unbounded)
    at: str | None  # the node whose run ages measure it (None: no node of the chain reports ages)
    whole: bool  # ``at`` is the chain's last scheduled node (else the measured figure is a lower bound)
    response: Quantiles | None  # p50, p95 and max of those ages (ms)


@dataclass(frozen=True)
class RunSummary:
    length_s: float
    cores: int | None  # from the ``start`` event
    complete: bool  # the log ends with the enforcer's ``stop`` (not a killed run)
    last_plan_s: float  # when the last plan (start or re-plan) took effect
    subchains: tuple[SubchainSummary, ...]  # sorted by name
    nodes: tuple[NodeSummary, ...]  # sorted by name
    resolves: tuple[ResolveSummary, ...]  # in time order
    costs: CostsSummary | None = None  # None: a log of a catanc that did not measure them
    chains: tuple[ChainSummary, ...] = ()  # the last plan's chains, in its order


def stats(samples: Sequence[float]) -> Stats | None:
    """Count, mean, p95, min and max of ``samples``; None for none."""
    if not samples:
        return None
    return Stats(
        count=len(samples),
        mean_ms=math.fsum(samples) / len(samples),
        p95_ms=percentile(samples, 95.0),
        min_ms=min(samples),
        max_ms=max(samples),
    )


def chain_response(
    nodes: Sequence[str], last_scheduled: str | None, ages: Mapping[str, Sequence[float]]
) -> tuple[str | None, bool, Quantiles | None]:
    """A chain's response measured from origins: ``(node measured at, whole chain, p50/p95/max of its ages)``.

    Measured at ``last_scheduled`` where it has ages, else at the last node before it that has (not the whole chain).
    """
    if last_scheduled is None or last_scheduled not in nodes:
        return None, False, None
    end = list(nodes).index(last_scheduled)
    for node in reversed(nodes[: end + 1]):
        samples = ages.get(node)
        if samples:
            values = list(samples)
            quantiles = Quantiles(len(values), percentile(values, 50.0), percentile(values, 95.0), max(values))
            return node, node == last_scheduled, quantiles
    return None, False, None


def usable(event: object) -> bool:
    """Whether ``event`` looks like a log event: an object with a finite ``t`` and a string ``event``."""
    if not isinstance(event, Mapping):
        return False
    return _number(event.get("t")) is not None and isinstance(event.get("event"), str)


def summarise(events: Iterable[Mapping[str, Any]]) -> RunSummary:
    """The summary of a run's log events (in log order); events that are not objects with ``t`` are ignored."""
    good = [event for event in events if usable(event)]
    length = max((float(event["t"]) for event in good), default=0.0)
    cores: int | None = None
    complete = False
    plans: list[tuple[float, Mapping[str, Any]]] = []  # (t, plan) from start and resolve events
    runs: dict[str, list[tuple[float, float | None]]] = {}  # subchain -> (t, latency_ms)
    samples: dict[str, list[tuple[float, float]]] = {}
    ages: dict[str, list[float]] = {}  # node -> its runs' ages (end less origin)
    unmeasured: dict[str, int] = {}
    counters: Mapping[str, Any] = {}  # subchain -> row of the last status or stop
    named: set[str] = set()
    resolves: list[ResolveSummary] = []
    costs: CostsSummary | None = None
    for event in good:
        kind, t = event["event"], float(event["t"])
        if kind == "start":
            cores = _integer(event.get("cores"))
            plans.append((t, _mapping(event.get("plan"))))
        elif kind == "resolve":
            plan = _mapping(event.get("plan"))
            plans.append((t, plan))
            resolves.append(
                ResolveSummary(
                    t_s=t,
                    reason=str(event.get("reason", "")),
                    stage1=event.get("stage1") is True,
                    allocation_changed=event.get("allocation_changed") is True,
                    solve_ms=_number(event.get("solve_ms")),
                    objective=_number(plan.get("objective")),
                    error=None if event.get("error") is None else str(event["error"]),
                )
            )
        elif kind == "run" and isinstance(event.get("subchain"), str):
            runs.setdefault(event["subchain"], []).append((t, _number(event.get("latency_ms"))))
        elif kind == "lost" and isinstance(event.get("subchain"), str):
            named.add(event["subchain"])
        elif kind == "compute" and isinstance(event.get("node"), str):
            node, ms = event["node"], _number(event.get("ms"))
            samples.setdefault(node, [])
            if ms is not None and ms >= 0:  # as measure.valid_sample
                samples[node].append((t, ms))
            else:
                unmeasured[node] = unmeasured.get(node, 0) + 1
            age = _number(event.get("age_ms"))
            if age is not None and age >= 0:
                ages.setdefault(node, []).append(age)
        elif kind == "register" and isinstance(event.get("node"), str):
            samples.setdefault(event["node"], [])
        elif kind in ("status", "stop"):
            row = event if kind == "status" else _mapping(event.get("summary"))
            counters = _mapping(row.get("subchains"))
            complete = complete or kind == "stop"
            costs = _costs(_mapping(row.get("costs"))) or costs
    planned = _planned_rates(plans)
    last_plan = plans[-1][0] if plans else 0.0
    names = sorted(named | set(runs) | set(planned) | {str(name) for name in counters})
    return RunSummary(
        length_s=length,
        cores=cores,
        complete=complete,
        last_plan_s=last_plan,
        subchains=tuple(
            _subchain(
                name,
                runs.get(name, []),
                planned=planned.get(name, []),
                counters=_mapping(counters.get(name)),
                length=length,
                last_plan=last_plan,
            )
            for name in names
        ),
        nodes=tuple(
            NodeSummary(
                name=node,
                compute=stats([ms for _, ms in samples[node]]),
                unmeasured=unmeasured.get(node, 0),
                samples=tuple(samples[node]),
            )
            for node in sorted(samples)
        ),
        resolves=tuple(resolves),
        costs=costs,
        chains=_chains(plans[-1][1] if plans else {}, ages),
    )


def _chains(plan: Mapping[str, Any], ages: Mapping[str, Sequence[float]]) -> tuple[ChainSummary, ...]:
    """The plan's chains (its ``chains`` entries that can be read), each measured from the runs' ages."""
    found = []
    entries = plan.get("chains")
    for entry in entries if isinstance(entries, list) else ():
        row = _mapping(entry)
        nodes = row.get("nodes")
        if not isinstance(nodes, list) or not nodes or not all(isinstance(node, str) for node in nodes):
            continue
        last = row.get("last_scheduled")
        at, whole, response = chain_response(nodes, last if isinstance(last, str) else None, ages)
        found.append(
            ChainSummary(
                nodes=tuple(nodes),
                planned_ms=_number(row.get("response_ms")),
                bound_ms=_number(row.get("max_response_ms")),
                at=at,
                whole=whole,
                response=response,
            )
        )
    return tuple(found)


def _costs(row: Mapping[str, Any]) -> CostsSummary | None:
    if not row:
        return None
    overhead = row.get("overhead")
    shares = [share for share in overhead if _number(share) is not None] if isinstance(overhead, list) else []
    return CostsSummary(
        switch=_quantiles(_mapping(row.get("switch"))),
        hop=_quantiles(_mapping(row.get("hop"))),
        hop_inside=_quantiles(_mapping(row.get("hop_inside"))),
        hop_head=_quantiles(_mapping(row.get("hop_head"))),
        share=max(shares) if shares else None,
        cpu_per_wake_ms=_number(row.get("cpu_per_wake_ms")),
        hop_by_edge=tuple(
            (str(edge), quantiles)
            for edge, figures in sorted(_mapping(row.get("hop_by_edge")).items())
            if (quantiles := _quantiles(_mapping(figures))) is not None
        ),
        dispatch_by_head=tuple(
            (str(head), quantiles)
            for head, figures in sorted(_mapping(row.get("dispatch_by_head")).items())
            if (quantiles := _quantiles(_mapping(figures))) is not None
        ),
    )


def _quantiles(row: Mapping[str, Any]) -> Quantiles | None:
    p50, p95, top, count = (row.get(key) for key in ("p50_ms", "p95_ms", "max_ms", "count"))
    numbers = [_number(p50), _number(p95), _number(top)]
    if any(value is None for value in numbers) or _integer(count) is None:
        return None
    return Quantiles(int(count), *numbers)  # type: ignore[arg-type]


def _subchain(
    name: str,
    runs: Sequence[tuple[float, float | None]],
    *,
    planned: Sequence[PlannedRate],
    counters: Mapping[str, Any],
    length: float,
    last_plan: float,
) -> SubchainSummary:
    since = length - last_plan
    return SubchainSummary(
        name=name,
        runs=len(runs),
        measured_hz=len(runs) / length if length > 0 else None,
        last_plan_hz=sum(t > last_plan for t, _ in runs) / since if since > 0 else None,
        planned=tuple(planned),
        latency=stats([ms for _, ms in runs if ms is not None]),
        late=_integer(counters.get("late")),
        lost=_integer(counters.get("lost")),
        steals=_integer(counters.get("steals")),
        skipped=_integer(counters.get("skipped")),
        run_times_s=tuple(t for t, _ in runs),
    )


def _planned_rates(plans: Sequence[tuple[float, Mapping[str, Any]]]) -> dict[str, list[PlannedRate]]:
    """Per subchain, each plan's period (and rate as run) where either differs from the one before."""
    planned: dict[str, list[PlannedRate]] = {}
    for t, plan in plans:
        for name, sub in _mapping(plan.get("subchains")).items():
            period = _number(_mapping(sub).get("period_ms"))
            if period is None or period <= 0:
                continue
            as_run = _number(_mapping(sub).get("rate_as_run_hz"))
            if as_run is not None and as_run < 0:
                as_run = None
            step = PlannedRate(t_s=t, period_ms=period, as_run_hz=as_run)
            steps = planned.setdefault(str(name), [])
            if not steps or (steps[-1].period_ms, steps[-1].as_run_hz) != (step.period_ms, step.as_run_hz):
                steps.append(step)
    return planned


def rate_bins(
    times_s: Iterable[float], length_s: float, width_s: float = RATE_BIN_S
) -> tuple[tuple[float, float], ...]:
    """Runs per second in consecutive bins of ``width_s`` from 0 to ``length_s``: ``(bin start, Hz)``.

    The last bin may be shorter (its rate is over its own width); a time of
    exactly ``length_s`` counts in the last bin; times outside ``[0, length_s]`` are ignored.
    """
    if length_s <= 0:
        return ()
    count = max(1, math.ceil(length_s / width_s))
    tallies = [0] * count
    for t in times_s:
        if 0 <= t <= length_s:
            tallies[min(int(t // width_s), count - 1)] += 1
    return tuple(
        (i * width_s, tally / (min((i + 1) * width_s, length_s) - i * width_s)) for i, tally in enumerate(tallies)
    )


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def _integer(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _mapping(value: object) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}
