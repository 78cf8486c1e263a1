"""The spec's hand-tuned baseline, evaluated under the same analytic model as the plan.

A baseline (``baseline.rates_hz``) is what the app did before catanc: each
listed node runs on its own timer at its rate, every other node runs when an
input arrives, and Linux shares the CPU (SCHED_OTHER).  The model:

- **No subchains**: every scheduled node is its own stage.  A listed node's
  period is ``1000 / rate``.  Any other node inherits the period of its
  fastest *scheduled* input (nodes in topological order); a node whose inputs
  are all unscheduled (sensors on their own clocks) inherits the fastest of
  those.  Sensors are the fallback, not the rule, because a node fed both by
  a pipeline and by a sensor stream is triggered by the pipeline and reads the
  sensor's latest sample (VR's VIO runs per camera frame, not per IMU
  sample).  An unscheduled node without a rate (an integrator, an actuator)
  passes on what triggers it.  A scheduled node with no rate and no input
  that has one gets no period: the baseline is incomplete and :class:`BaselineGap` says which
  nodes lack one.
- Unscheduled nodes are pseudo-stages as in docs/explanation/model.md section 2 (their
  own clock ``p``, ``l = p``; without a rate they drop out of chains).  A batch
  node heading a chain with an observed output rate uses that period there
  (``Chain.head_period_ms``), as the planner's model does.
- **Fair sharing** (Linux CFS as processor sharing) over all ``K`` cores:
  utilisation ``rho = sum_n (c_n / p_n) / K`` with ``c_n`` the node's planning
  compute time on one thread, and each node's processing latency
  ``l_n = c_n / (1 - rho)`` (the M/G/1 processor-sharing mean response time).
- **Overload**: at ``rho >= FAIR_SHARE_CAP`` (0.95, the share the model
  leaves Linux: one minus the default slack) the listed rates cannot be
  sustained.  Every scheduled node's period is stretched by
  ``rho / FAIR_SHARE_CAP`` and latencies are evaluated at ``rho = FAIR_SHARE_CAP``.
- Chain metrics over these stages exactly as section 2
  (``L = l1 + sum_{x>=2} (p_x + l_x)``, ``P = max p``, ``R = L + P``); the
  objective's response terms use the spec's chains, its period terms the
  named node's own period.

The same triggers under static SCHED_FIFO (``fifo-static``, the paper's
second baseline, docs/explanation/model.md section 7) run each subchain at a level of
its own by importance (:func:`static_priorities`), or at the spec's
``baseline.priorities``; never at ``schedule.priorities``, which rank
catanc's own stealing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from catanc.errors import format_path
from catanc.model.build import spec_dag
from catanc.model.metrics import ChainMetrics, Timing, chain_metrics, fixed_timing
from catanc.model.problem import Chain, PeriodTerm, Problem
from catanc.spec.language import Spec

FAIR_SHARE_CAP = 0.95
"""Utilisation at which the baseline counts as overloaded (1 - the model's default slack)."""


@dataclass(frozen=True)
class NodeTiming:
    """One scheduled node in the baseline."""

    node: str
    compute_ms: float  # planning compute time, one thread
    rate_hz: float | None  # its timer's rate, None when triggered by an input
    trigger: str | None  # the input whose period it inherits (None when on a timer)
    period_ms: float  # after stretching, if overloaded
    latency_ms: float


@dataclass(frozen=True)
class TermValue:
    """One objective term's value: ``weight * value_ms``."""

    label: str  # ``R scan -> LM -> LP -> base`` or ``p GL``
    origin: str  # the spec entry, e.g. ``objective[2]``
    weight: float
    value_ms: float

    @property
    def contribution(self) -> float:
        return self.weight * self.value_ms


@dataclass(frozen=True)
class BaselineEvaluation:
    """The baseline's numbers under fair sharing on ``cores`` cores."""

    cores: int
    nodes: dict[str, NodeTiming]  # every scheduled node, in spec order
    utilisation: float  # rho the listed rates ask for (before any stretching)
    overloaded: bool
    stretch: float  # factor on every scheduled period (1.0 unless overloaded)
    chains: tuple[ChainMetrics, ...]  # aligned with Problem.chains
    terms: tuple[TermValue, ...]  # response terms, then period terms, as in the Problem
    objective: float


@dataclass(frozen=True)
class BaselineGap:
    """Why there is nothing to compare with."""

    reason: str
    nodes: tuple[str, ...] = ()  # scheduled nodes without a period, if that is the reason


def evaluate_baseline(spec: Spec, problem: Problem, cores: int) -> BaselineEvaluation | BaselineGap:
    """Evaluate ``spec.baseline`` on ``cores`` cores with the model in this module's docstring."""
    if cores < 1:
        raise ValueError("the baseline needs at least one core")
    rates = spec.baseline.rates_hz
    if not rates:
        return BaselineGap("the spec has no baseline (baseline.rates_hz)")
    periods, triggers = _trigger_periods(spec)
    scheduled = [name for name, node in spec.nodes.items() if node.scheduled]
    missing = tuple(name for name in scheduled if periods.get(name) is None)
    if missing:
        return BaselineGap(
            "the baseline is incomplete: "
            + ", ".join(missing)
            + (" has" if len(missing) == 1 else " have")
            + " no rate in baseline.rates_hz and no input with one",
            missing,
        )
    asked = {name: _known(periods[name]) for name in scheduled}
    compute = {name: spec.nodes[name].mean_compute_ms for name in scheduled}
    utilisation = math.fsum(compute[name] / asked[name] for name in scheduled) / cores
    overloaded = utilisation >= FAIR_SHARE_CAP
    stretch = utilisation / FAIR_SHARE_CAP if overloaded else 1.0
    busy = min(utilisation, FAIR_SHARE_CAP)
    nodes = {
        name: NodeTiming(
            node=name,
            compute_ms=compute[name],
            rate_hz=rates.get(name),
            trigger=triggers.get(name),
            period_ms=asked[name] * stretch,
            latency_ms=compute[name] / (1.0 - busy),
        )
        for name in scheduled
    }
    timings = {name: Timing(row.period_ms, row.latency_ms) for name, row in nodes.items()}
    chains = tuple(_chain_metrics(chain, timings, problem.fixed_periods_ms) for chain in problem.chains)
    terms = objective_terms(problem, [m.response_ms for m in chains], lambda term: timings[term.node].period_ms)
    return BaselineEvaluation(
        cores=cores,
        nodes=nodes,
        utilisation=utilisation,
        overloaded=overloaded,
        stretch=stretch,
        chains=chains,
        terms=terms,
        objective=math.fsum(term.contribution for term in terms),
    )


def static_priorities(spec: Spec, problem: Problem) -> dict[str, int]:
    """fifo-static's order of the subchains, higher runs first: ``baseline.priorities`` (unlisted: 0), else
    by importance, every subchain its own level ``1..n``.

    Importance: the total weight of the objective's terms through the subchain
    (:meth:`Problem.importance`); on a tie, the one closer to its chains' ends
    first (fewest subchains after it in a weighted chain through it): FIFO
    then finishes the data already in flight before it takes new input; then
    spec order.
    """
    if spec.baseline.priorities:
        return {sub.name: spec.baseline.priorities.get(sub.name, 0) for sub in problem.subchains}
    weight = problem.importance()
    after = _stages_after(problem)
    ranked = sorted(
        range(len(problem.subchains)),
        key=lambda i: (-weight[problem.subchains[i].name], after[problem.subchains[i].name], i),
    )
    return {problem.subchains[i].name: len(ranked) - rank for rank, i in enumerate(ranked)}


def _stages_after(problem: Problem) -> dict[str, float]:
    """Per subchain: the fewest subchains that follow it in a weighted chain through it (inf: in none)."""
    after = dict.fromkeys((sub.name for sub in problem.subchains), math.inf)
    for term in problem.response_terms:
        if term.weight <= 0:
            continue
        stages = [stage.name for stage in problem.chains[term.chain].stages if not stage.fixed]
        for index, name in enumerate(stages):
            after[name] = min(after[name], len(stages) - 1 - index)
    return after


def objective_terms(
    problem: Problem, responses_ms: Sequence[float], period_of: Callable[[PeriodTerm], float]
) -> tuple[TermValue, ...]:
    """Every weighted term of ``problem`` with its value: response terms first, then period terms.

    ``responses_ms[i]`` is the response time of ``problem.chains[i]``;
    ``period_of`` gives a period term's period.
    """
    values = [
        TermValue(
            f"R {problem.chains[term.chain].label}",
            format_path(term.origin),
            term.weight,
            responses_ms[term.chain],
        )
        for term in problem.response_terms
    ]
    values += [
        TermValue(f"p {term.node}", format_path(term.origin), term.weight, period_of(term))
        for term in problem.period_terms
    ]
    return tuple(values)


def _known(period: float | None) -> float:
    assert period is not None
    return period


def _trigger_periods(spec: Spec) -> tuple[dict[str, float | None], dict[str, str]]:
    """Each node's period in the baseline (None: none known) and, if inherited, the input it comes from."""
    dag = spec_dag(spec)
    periods: dict[str, float | None] = {}
    triggers: dict[str, str] = {}
    for name in dag.topological_order():
        node = spec.nodes[name]
        own = node.rate_hz if not node.scheduled else spec.baseline.rates_hz.get(name)
        if own is not None:
            periods[name] = 1000.0 / own
            continue
        inputs = dag.predecessors(name)  # in declaration order
        rated = [(p, n) for n in inputs if (p := periods.get(n)) is not None]
        pipeline = [(p, n) for p, n in rated if spec.nodes[n].scheduled]
        candidates = pipeline or rated
        if not candidates:
            periods[name] = None
            continue
        period, source = min(candidates, key=lambda item: (item[0], dag.order[item[1]]))
        periods[name] = period
        triggers[name] = source
    return periods, triggers


def _chain_metrics(chain: Chain, timings: dict[str, Timing], fixed_periods_ms: dict[str, float]) -> ChainMetrics:
    """Section 2 over the chain's nodes: each scheduled node a stage, each clocked sensor a pseudo-stage."""
    stages: list[Timing] = []
    for node in chain.nodes:
        if node in timings:
            timing = timings[node]
            if node == chain.nodes[0] and chain.head_period_ms is not None:
                timing = Timing(chain.head_period_ms, timing.latency_ms)
            stages.append(timing)
        elif node in fixed_periods_ms:
            stages.append(fixed_timing(fixed_periods_ms[node]))
    return chain_metrics(stages)
