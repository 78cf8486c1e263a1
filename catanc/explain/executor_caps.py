"""A rate cap on an executor's long node that would make the plan run better: the planner's trade, offered.

The planner spaces out an executor's members' triggers at the runs and lengths it chose
(docs/explanation/executor-planning.md), but it chooses those for the slot model: it may still run a long
node (nav2d's GM) with slices the slot model sees room for, while each of its runs holds the
thread the short nodes (GL) need.  Slowing the long node trades its chains'
periods against the short nodes' lost triggers.  This module makes that trade the way a user
would: it scores a few caps below the long node's planned rate on this plan (its period
lengthened, the rest as planned), adds the best as ``{node: HEAD, max_rate_hz: CAP}`` to the spec,
plans that spec with the planner, and offers the cap if that plan's objective as run
(:func:`~catanc.explain.executors.objective_as_run`) beats this one's by more than
:data:`WORTH_OFFERING`.  A screen over one number, confirmed by one planner run: not an optimum
over all plans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from catanc.errors import CatancError
from catanc.explain.executors import core_groups, objective_as_run, plan_timings, plan_turns
from catanc.model.build import build_problem
from catanc.model.executor_thread import as_run_objective
from catanc.model.problem import Executor, Problem
from catanc.planning.planner import plan_problem
from catanc.planning.types import Plan
from catanc.spec.language import RateConstraint, Spec

SLOWER = (1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, 8.0)
"""The long node's period times these: the caps tried."""

WORTH_OFFERING = 0.01
"""A cap is offered when it lowers the objective as run by more than this share."""


@dataclass(frozen=True)
class CapOffer:
    """Capping ``node`` (the head of the long node's subchain) at ``max_rate_hz``, and what it gives."""

    node: str
    max_rate_hz: float
    objective_now: float  # the plan's objective as run
    objective_capped: float  # the capped plan's
    rates_hz: dict[str, float]  # the executor's nodes' predicted rates under the capped plan

    @property
    def sentence(self) -> str:
        rates = ", ".join(f"{node} about {hz:.1f} Hz" for node, hz in self.rates_hz.items())
        return (
            f"Capping {self.node} at {self.max_rate_hz:g} Hz (constraints: - {{node: {self.node}, max_rate_hz: "
            f"{self.max_rate_hz:g}}}) would lower the objective as run to about {self.objective_capped:.3f} ms "
            f"({self.objective_capped / self.objective_now - 1:+.1%}): {rates}."
        )


def cap_offer(spec: Spec, problem: Problem, plan: Plan, executor: Executor) -> CapOffer | None:
    """The best cap on ``executor``'s long node, or None where no cap beats the plan (or nothing loses).

    Each cap is first scored on this plan with only the long node's period lengthened (what
    the cap changes first; the time it frees for the others is not counted, so the screen only
    ranks the caps); the best is then planned for real, and offered only if that plan beats this
    one, as run, by more than :data:`WORTH_OFFERING`.  One planner run per executor that loses.
    """
    schedule = spec.schedule
    turns = plan_turns(executor, plan, problem, schedule)
    losing = [] if turns is None else [rate for rate in turns.rates if rate.lost_share > 0.0]
    if not losing:
        return None
    blocker = max(losing, key=lambda rate: rate.planned_hz - rate.rate_hz).blocked_by
    subchain = problem.subchain_of(blocker)
    head, period = subchain.nodes[0], plan.subchains[subchain.name].period_ms
    now = objective_as_run(plan, problem, schedule)
    groups = core_groups(plan, schedule)
    timings = plan_timings(plan)

    def screened(factor: float) -> float:
        slower = {**timings, subchain.name: replace(timings[subchain.name], period_ms=period * factor)}
        return as_run_objective(problem, slower, groups)

    factor = min(SLOWER, key=screened)  # the screen keeps the rest as planned: it under-rates what a cap frees
    cap = _round(1000.0 / (period * factor))
    capped = _planned(spec, head, cap, plan.cores)
    if capped is None:
        return None
    value = objective_as_run(capped, problem, schedule)
    if value >= now * (1.0 - WORTH_OFFERING):
        return None
    after = plan_turns(executor, capped, problem, schedule)
    rates = {rate.node: rate.rate_hz for rate in after.rates} if after is not None else {}
    return CapOffer(head, cap, now, value, rates)


def _planned(spec: Spec, node: str, cap_hz: float, cores: int) -> Plan | None:
    """The plan of ``spec`` with ``node`` capped at ``cap_hz`` (None where that spec cannot be planned)."""
    constraints = [*spec.constraints, RateConstraint(node=node, max_rate_hz=cap_hz)]
    capped = spec.model_copy(update={"constraints": constraints})
    try:
        return plan_problem(build_problem(capped), capped.schedule, cores)
    except CatancError:
        return None


def _round(rate_hz: float) -> float:
    """Two significant digits: a cap a user would write."""
    digits = 1 - math.floor(math.log10(rate_hz))
    return round(rate_hz, digits)
