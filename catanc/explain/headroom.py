"""How far a plan is from missing each rate floor, fixed rate and chain bound (``catanc explain``'s headroom).

For every bound, what the plan sustains at its schedule, and how much every
compute time on the bound's cores may grow before it is missed: the same
fractions, cores and threads with compute times scaled, found by bisection.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from catanc.model.metrics import Timing, evaluate_chain
from catanc.model.problem import Chain, Problem
from catanc.spec.language import Schedule
from catanc.text import hz

if TYPE_CHECKING:
    from catanc.planning.types import Plan

NEAR_SATURATION = 0.10
"""Headroom below which a bound is warned about."""


@dataclass(frozen=True)
class Headroom:
    """How far one bound is from being missed."""

    what: str  # e.g. "GL's rate floor (>= 40 Hz)"
    cores: tuple[int, ...]
    value: float  # what the plan sustains (a period, or a response time; ms)
    limit: float  # the bound, scaled by the constraint scale (ms)
    growth: float | None  # how much every compute time on those cores may grow (0.1 = 10%); None: unaffected

    @property
    def headroom(self) -> float:
        return self.limit / self.value - 1.0 if self.value > 0 else math.inf


def _sustained(plan: Plan, problem: Problem, schedule: Schedule, growth: float) -> dict[str, Timing]:
    """Timings at this schedule (same fractions, cores, threads) with every compute time times ``growth``.

    A shared core's ``T`` grows with its slices (switches stay); a
    dedicated subchain's Eq. 1 period and latency grow in proportion.  The
    period is before any rate cap: what the schedule can sustain.
    """
    by_name = {sub.name: sub for sub in problem.subchains}
    timings: dict[str, Timing] = {}
    for core in plan.shared_cores:
        load = math.fsum(plan.subchains[name].fraction * by_name[name].compute_ms for name in core.order)
        fit = (load * growth + len(core.order) * schedule.switch_ms) / (1.0 - schedule.slack)
        # T may sit above what fits (a fixed rate's p_min / k): runs then take as long until the
        # slots outgrow it, and the periods the schedule can sustain are those of the fitted T.
        length = max(core.period_ms, fit)
        for name in core.order:
            fraction = plan.subchains[name].fraction
            timings[name] = Timing(fit / fraction, length / fraction)
    for name, chosen in plan.subchains.items():
        if chosen.shared:
            continue
        cores = max(1, len(chosen.cores))
        threads = max(1, min(chosen.threads, cores))
        times = by_name[name].compute_by_threads(cores)[threads - 1]
        period = max(*times, math.fsum(times) / (cores // threads))
        timings[name] = Timing(growth * period, growth * chosen.latency_ms)
    return timings


def _capped(problem: Problem, timings: dict[str, Timing]) -> dict[str, Timing]:
    caps = {sub.name: sub.min_period_ms for sub in problem.subchains}
    return {name: Timing(max(t.period_ms, caps[name]), t.latency_ms) for name, t in timings.items()}


def _growth(value_at: Callable[[float], float], limit: float) -> float | None:
    """How far compute may grow (``g - 1``) before ``value_at(g)`` exceeds ``limit``; None if it never does."""
    if value_at(1.0) >= limit:
        return 0.0
    low, high = 1.0, 2.0
    while value_at(high) <= limit:
        low, high = high, 2.0 * high
        if high > 1e9:
            return None
    for _ in range(100):
        middle = 0.5 * (low + high)
        if value_at(middle) <= limit:
            low = middle
        else:
            high = middle
        if high - low <= 1e-12 * high:
            break
    return low - 1.0


def plan_headrooms(plan: Plan, problem: Problem, schedule: Schedule) -> list[Headroom]:
    """Every rate floor, fixed rate and chain bound: how close the plan is to missing it."""
    scale = plan.constraint_scale
    found: list[Headroom] = []

    def sustained(growth: float) -> dict[str, Timing]:
        return _sustained(plan, problem, schedule, growth)

    for sub in problem.subchains:
        if sub.max_period_ms == math.inf:
            continue
        limit = sub.max_period_ms * scale
        fixed = sub.min_period_ms == sub.max_period_ms
        what = (
            f"{sub.name}'s fixed rate ({hz(sub.max_period_ms)})"
            if fixed
            else f"{sub.name}'s rate floor (>= {hz(limit)})"
        )

        def period(growth: float, name: str = sub.name) -> float:
            return sustained(growth)[name].period_ms

        found.append(
            Headroom(
                what=what,
                cores=plan.subchains[sub.name].cores,
                value=period(1.0),
                limit=limit,
                growth=_growth(period, limit),
            )
        )
    for bound in problem.response_bounds:
        chain = problem.chains[bound.chain]
        limit = bound.max_response_ms * scale
        cores = sorted({core for s in chain.stages if not s.fixed for core in plan.subchains[s.name].cores})

        def response(growth: float, chain: Chain = chain) -> float:
            return evaluate_chain(problem, chain, _capped(problem, sustained(growth))).response_ms

        found.append(
            Headroom(
                what=f"the bound on {chain.label} (R <= {limit:.4g} ms)",
                cores=tuple(cores),
                value=response(1.0),
                limit=limit,
                growth=_growth(response, limit) if cores else None,
            )
        )
    return found
