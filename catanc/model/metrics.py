"""The analytic model (docs/explanation/model.md sections 2 and 4): pure arithmetic.

Given each stage's period ``p`` and processing latency ``l`` (ms), a chain's

- latency  ``L = l1 + sum_{x>=2} (p_x + l_x)``
- period   ``P = max_x p_x``
- response ``R = L + P``

and the objective is ``sum w_t R_t + sum w_i p_i``.  Eq. 1 gives the period
and latency of a subchain with cores of its own.  Both solver stages and the
runtime use these functions, so the plan they report is the plan this
module evaluates.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

from catanc.model.problem import Chain, ChainForm, PeriodTerm, Problem, ResponseTerm, Stage, Subchain, chain_form

__all__ = ["ChainForm", "chain_form"]  # re-exported: the solvers' view of a chain lives with the problem


@dataclass(frozen=True)
class Timing:
    """A stage's period and processing latency (ms)."""

    period_ms: float
    latency_ms: float


@dataclass(frozen=True)
class ChainMetrics:
    latency_ms: float
    period_ms: float
    response_ms: float


@dataclass(frozen=True)
class DedicatedTiming:
    """Eq. 1's choice for a subchain on ``cores`` cores of its own."""

    cores: int
    threads: int  # q: most threads any node of the subchain uses
    period_ms: float
    latency_ms: float  # sum of the nodes' compute with q threads

    @property
    def response_ms(self) -> float:
        return self.latency_ms + self.period_ms

    @property
    def timing(self) -> Timing:
        return Timing(self.period_ms, self.latency_ms)


def chain_metrics(stages: Sequence[Timing]) -> ChainMetrics:
    """Latency, period and response time of a chain of stages (Table 1, generalised)."""
    if not stages:
        return ChainMetrics(0.0, 0.0, 0.0)
    latency = stages[0].latency_ms + math.fsum(s.period_ms + s.latency_ms for s in stages[1:])
    period = max(s.period_ms for s in stages)
    return ChainMetrics(latency, period, latency + period)


def dedicated_timing(
    compute_by_threads: Sequence[Sequence[float]],
    cores: int,
    serial: Sequence[Sequence[int]] = (),
    slack: float = 0.0,
    hops_ms: float = 0.0,
) -> DedicatedTiming:
    """Eq. 1 with the slack: the best thread count ``q`` for a subchain on ``cores`` cores.

    ``compute_by_threads[q - 1][j]`` is node j's compute time with at most q
    threads, for q = 1..cores.  With ``floor(cores / q)`` runs in flight and
    each core busy at most ``1 - slack`` of the time (docs/explanation/model.md section 4:
    no plan runs a SCHED_FIFO core 100% busy),

        p(q) = max(max_j c^q_j, sum_j c^q_j / floor(cores / q)) / (1 - slack)
        response(q) = sum_j c^q_j + p(q)

    and the lowest response wins (ties: the smaller q).  ``hops_ms``, the
    subchain's inside hops, counts in ``sum_j c^q_j`` as in ``c(S)``
    (docs/explanation/model.md section 5): a run holds its cores through them.  ``serial`` lists
    positions of nodes that share one executor thread: runs in flight cannot
    overlap them, so each such set is one pipeline stage whose compute adds
    up (``p(q) >= sum_{j in set} c^q_j``).
    """
    if cores < 1:
        raise ValueError("a dedicated subchain needs at least one core")
    best: DedicatedTiming | None = None
    for q in range(1, cores + 1):
        times = compute_by_threads[q - 1]
        total = math.fsum((*times, hops_ms))
        stages = (math.fsum(times[j] for j in group) for group in serial)
        period = max(*times, total / (cores // q), *stages) / (1.0 - slack)
        candidate = DedicatedTiming(cores, q, period, total)
        if best is None or candidate.response_ms < best.response_ms:
            best = candidate
    assert best is not None
    return best


def capped_dedicated(sub: Subchain, cores: int, slack: float) -> DedicatedTiming:
    """Eq. 1 with the slack for ``sub`` on ``cores`` cores of its own, then its rate cap applied to the period."""
    eq1 = dedicated_timing(sub.compute_by_threads(cores), cores, sub.serial, slack, sub.hops_ms)
    return replace(eq1, period_ms=max(eq1.period_ms, sub.min_period_ms))


def fixed_timing(period_ms: float) -> Timing:
    """An unscheduled node's own clock: its processing latency is its period."""
    return Timing(period_ms, period_ms)


def stage_timings(chain: Chain, timings: Mapping[str, Timing], fixed_periods_ms: Mapping[str, float]) -> list[Timing]:
    """Per-stage timing of a chain; a batch head uses its observed output period."""
    result = []
    for index, stage in enumerate(chain.stages):
        timing = _stage_timing(stage, timings, fixed_periods_ms)
        if index == 0 and chain.head_period_ms is not None and not stage.fixed:
            timing = Timing(chain.head_period_ms, timing.latency_ms)
        result.append(timing)
    return result


def _stage_timing(stage: Stage, timings: Mapping[str, Timing], fixed_periods_ms: Mapping[str, float]) -> Timing:
    if stage.fixed:
        return fixed_timing(fixed_periods_ms[stage.name])
    return timings[stage.name]


def evaluate_chain(problem: Problem, chain: Chain, timings: Mapping[str, Timing]) -> ChainMetrics:
    """A chain's metrics given every subchain's timing."""
    return chain_metrics(stage_timings(chain, timings, problem.fixed_periods_ms))


def form_metrics(form: ChainForm, timings: Mapping[str, Timing]) -> ChainMetrics:
    """A chain's metrics from its :class:`ChainForm` (the fast path; :func:`evaluate_chain` is the reference)."""
    latency, period = _latency_period(form, timings)
    return ChainMetrics(latency, period, latency + period)


def _latency_period(form: ChainForm, timings: Mapping[str, Timing]) -> tuple[float, float]:
    # fsum is exactly rounded and max exact: any order of the terms gives the same bits.
    parts = [timings[name].latency_ms for name in form.latency_of]
    parts += [timings[name].period_ms for name in form.period_of]
    parts.append(form.constant)
    longest = [timings[name].period_ms for name in form.longest_of]
    longest.append(form.floor)
    return math.fsum(parts), max(longest)


def _response(form: ChainForm, timings: Mapping[str, Timing]) -> float:
    latency, period = _latency_period(form, timings)
    return latency + period


def chain_metrics_of(problem: Problem, index: int, timings: Mapping[str, Timing]) -> ChainMetrics:
    """The metrics of ``problem.chains[index]``, by its precomputed form."""
    return form_metrics(problem.chain_forms[index], timings)


def objective(problem: Problem, timings: Mapping[str, Timing]) -> float:
    """``sum w_t R_t + sum w_i p_i`` over the problem's terms (ms)."""
    forms = problem.chain_forms
    chains = dict.fromkeys(term.chain for term in problem.response_terms)  # several terms may weigh one chain
    responses = {index: _response(forms[index], timings) for index in chains}
    terms = [term.weight * responses[term.chain] for term in problem.response_terms]
    terms += [term.weight * timings[term.subchain].period_ms for term in problem.period_terms]
    return math.fsum(terms)


def bound_scale(problem: Problem, timings: Mapping[str, Timing]) -> float:
    """Smallest factor (>= 1) on the spec's bounds that these timings meet.

    Chain bounds ``R <= B`` need ``R / B``; a subchain's rate floor (a longest
    period) needs ``p / p_max``.  1.0 means every bound holds as written.
    """
    scale = 1.0
    forms = problem.chain_forms
    for bound in problem.response_bounds:
        scale = max(scale, _response(forms[bound.chain], timings) / bound.max_response_ms)
    for sub in problem.subchains:
        if sub.max_period_ms < math.inf:
            scale = max(scale, timings[sub.name].period_ms / sub.max_period_ms)
    return scale


QUICK_MARGIN = 1e-9
"""Relative: a :class:`WeightedSums` value this far above a threshold is above it by :func:`objective` too.
Every term is non-negative (weights are >= 0), so either sum is within ~1e-14 of the true value."""


@dataclass(frozen=True)
class WeightedSums:
    """:func:`objective` gathered per subchain: each latency's and period's total weight, the constants, and each
    distinct longest period's weight.  Its :meth:`value` is the objective within rounding, in a few dozen
    operations instead of one pass per weighted chain (Autoware: 60 terms over 53 chains, ~25x faster), to
    rule out a choice that is clearly above a threshold before :func:`objective` scores it exactly."""

    latency: tuple[tuple[str, float], ...]
    period: tuple[tuple[str, float], ...]
    constant: float
    longest: tuple[tuple[float, float, tuple[str, ...]], ...]  # (total weight, floor, candidates)

    @classmethod
    def of(cls, problem: Problem) -> WeightedSums:
        # Cached by the terms and the chains' forms, which re-planning with new compute times keeps
        # (~0.4 ms to gather for Autoware, against a ~6 ms warm re-solve): the same objects, so the
        # last ones are recognised by identity before the cache hashes them (~50 us for Autoware).
        key = (problem.chain_forms, problem.response_terms, problem.period_terms)
        last = _LAST_SUMS[0] if _LAST_SUMS else None
        if last is not None and all(mine is theirs for mine, theirs in zip(key, last[0], strict=True)):
            return last[1]
        sums = _weighted_sums(*key)
        _LAST_SUMS[:] = [(key, sums)]
        return sums

    @classmethod
    def gather(
        cls,
        forms: tuple[ChainForm, ...],
        response_terms: tuple[ResponseTerm, ...],
        period_terms: tuple[PeriodTerm, ...],
    ) -> WeightedSums:
        latency: dict[str, float] = {}
        period: dict[str, float] = {}
        longest: dict[tuple[float, tuple[str, ...]], float] = {}
        constant = 0.0
        for term in response_terms:
            form = forms[term.chain]
            for name in form.latency_of:
                latency[name] = latency.get(name, 0.0) + term.weight
            for name in form.period_of:
                period[name] = period.get(name, 0.0) + term.weight
            constant += term.weight * form.constant
            key = (form.floor, tuple(sorted(set(form.longest_of))))
            longest[key] = longest.get(key, 0.0) + term.weight
        for period_term in period_terms:
            period[period_term.subchain] = period.get(period_term.subchain, 0.0) + period_term.weight
        return cls(
            latency=tuple(latency.items()),
            period=tuple(period.items()),
            constant=constant,
            longest=tuple((weight, floor, names) for (floor, names), weight in longest.items()),
        )

    def value(self, timings: Mapping[str, Timing]) -> float:
        total = self.constant
        for name, weight in self.latency:
            total += weight * timings[name].latency_ms
        for name, weight in self.period:
            total += weight * timings[name].period_ms
        for weight, floor, names in self.longest:
            total += weight * max([floor, *(timings[name].period_ms for name in names)])
        return total


_LAST_SUMS: list[
    tuple[tuple[tuple[ChainForm, ...], tuple[ResponseTerm, ...], tuple[PeriodTerm, ...]], WeightedSums]
] = []


@functools.lru_cache(maxsize=16)
def _weighted_sums(
    forms: tuple[ChainForm, ...], response_terms: tuple[ResponseTerm, ...], period_terms: tuple[PeriodTerm, ...]
) -> WeightedSums:
    return WeightedSums.gather(forms, response_terms, period_terms)
