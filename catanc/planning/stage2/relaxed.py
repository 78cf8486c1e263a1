"""Stage II's relaxation: one geometric program over every shared core (docs/explanation/model.md section 4).

For a shared core running subchains ``S_1..S_n`` with a schedule of length
``T``, each subchain runs a fraction ``f_i`` of one run per period, so it
completes every ``1/f_i`` periods: ``p_i >= T / f_i`` and its processing
latency is ``T / f_i``.  Constraints (all posynomial <= monomial):

- ``(sum_i f_i c_i + n * switch) / (1 - slack) <= T``  (T is a variable: the
  prototype's DGPError came from writing it as an expression)
- ``T / f_i <= p_i``; ``min(min_slice, c_i) <= f_i c_i``; ``f_i <= 1`` unless batch
- rate bounds ``p_min <= p_i <= s * p_max``; chain bounds ``R_t <= s * B_t``

Dedicated subchains enter as constants (:func:`catanc.model.metrics.capped_dedicated`).
Every number that changes at runtime is a cvxpy Parameter, and the problem
is DPP, so a re-solve with new compute times reuses the compiled problem.
The relaxation drops the integrality of ``1/f_i``; restoring it is a
separate step.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping

import cvxpy as cp
import numpy as np

from catanc.model.metrics import capped_dedicated, chain_form
from catanc.model.problem import Problem
from catanc.planning.stage2.base import Layout, LayoutModel, RelaxedSolution, SharedCore
from catanc.spec.language import Schedule

__all__ = ["Layout", "RelaxedSolution", "RelaxedStage2", "SharedCore"]  # the first three live in base.py

RECORD_TOLERANCES: dict[str, float] = {
    "tol_gap_abs": 1e-13,
    "tol_gap_rel": 1e-13,
    "tol_feas": 1e-13,
    "tol_ktratio": 1e-10,
    "max_iter": 400,
}
"""Clarabel's settings for the model of record, far tighter than its defaults (1e-8).

The committed plan is printed to 6-9 digits and must be the same bytes on
any machine.  Where the objective is flat, the default tolerances leave the
optimum's last printed digits to rounding noise: a 1e-12 relative change
of one input moved nav2d's numbers by up to 2e-7.  At these tolerances a
1e-9 change moves no printed digit (measured on the example specs)."""


class RelaxedStage2(LayoutModel):
    """The relaxed Stage II GP for one layout, built once and re-solved with new numbers."""

    def __init__(self, problem: Problem, layout: Layout, schedule: Schedule) -> None:
        super().__init__(problem, layout, schedule)
        by_name = {sub.name: sub for sub in problem.subchains}

        # Parameters: what changes when compute times are re-measured.
        self.compute = {name: cp.Parameter(pos=True, name=f"c_{name}") for name in self.shared_names}
        self.slice = {name: cp.Parameter(pos=True, name=f"slice_{name}") for name in self.shared_names}
        self.fixed_period = {name: cp.Parameter(pos=True, name=f"pd_{name}") for name in self.dedicated_names}
        self.fixed_latency = {name: cp.Parameter(pos=True, name=f"ld_{name}") for name in self.dedicated_names}
        self.scale = cp.Parameter(pos=True, name="scale", value=1.0)
        # A box on each non-batch f (f = 1/n, n a whole number): the integer search narrows it.
        self.f_min = {name: cp.Parameter(pos=True, name=f"fmin_{name}", value=1e-9) for name in self.integral}
        self.f_max = {name: cp.Parameter(pos=True, name=f"fmax_{name}", value=1.0) for name in self.integral}

        self.core_period = {core.core: cp.Variable(pos=True, name=f"T_{core.core}") for core in layout.shared}
        self.fraction = {name: cp.Variable(pos=True, name=f"f_{name}") for name in self.shared_names}
        self.period = {name: cp.Variable(pos=True, name=f"p_{name}") for name in self.shared_names}

        constraints: list[cp.Constraint] = []
        floors: list[tuple[cp.Expression, float]] = []  # (period, longest period allowed)
        latency: dict[str, cp.Expression] = {}
        period: dict[str, cp.Expression] = {}
        usable = 1.0 - schedule.slack
        for core in layout.shared:
            T = self.core_period[core.core]
            load = cp.sum([self.fraction[n] * self.compute[n] for n in core.subchains])
            overhead = len(core.subchains) * schedule.switch_ms
            constraints.append((load + overhead) / usable <= T if overhead > 0 else load / usable <= T)
            for name in core.subchains:
                f, p = self.fraction[name], self.period[name]
                constraints.append(T / f <= p)
                if schedule.min_slice_ms > 0:
                    constraints.append(self.slice[name] <= f * self.compute[name])
                if not by_name[name].batch:
                    constraints += [self.f_min[name] <= f, f <= self.f_max[name]]
                sub = by_name[name]
                if sub.min_period_ms > 0:
                    constraints.append(sub.min_period_ms <= p)
                if sub.max_period_ms < math.inf:
                    floors.append((p, sub.max_period_ms))
                latency[name] = T / f
                period[name] = p
        for name in self.dedicated_names:
            latency[name] = self.fixed_latency[name]
            period[name] = self.fixed_period[name]
            if by_name[name].max_period_ms < math.inf:  # a dedicated subchain's rate floor binds too
                floors.append((self.fixed_period[name], by_name[name].max_period_ms))

        responses: dict[int, cp.Expression] = {}
        for index in range(len(problem.chains)):
            response = self._chain_response(index, period, latency, constraints)
            if response is not None:
                responses[index] = response
        bounded = floors + [
            (responses[bound.chain], bound.max_response_ms)
            for bound in problem.response_bounds
            if bound.chain in responses
        ]

        def scaled(scale: cp.Expression) -> list[cp.Constraint]:
            return [value <= scale * limit for value, limit in bounded]

        terms: list[cp.Expression] = []
        for term in problem.response_terms:
            if term.weight > 0 and term.chain in responses:
                terms.append(term.weight * responses[term.chain])
        for period_term in problem.period_terms:
            if period_term.weight > 0:
                terms.append(period_term.weight * period[period_term.subchain])
        # With no weighted term every feasible plan is optimal; shortest schedules then.
        objective = cp.sum(terms) if terms else cp.sum(list(self.core_period.values()))
        self.problem_gp = cp.Problem(cp.Minimize(objective), constraints + scaled(self.scale))
        # The same plan space with the scale free: its least value is the smallest common factor
        # on the bounds that a plan can meet (soft bounds).
        self.scale_free = cp.Variable(pos=True, name="scale_free")
        self.problem_scale = cp.Problem(
            cp.Minimize(self.scale_free), [*constraints, *scaled(self.scale_free), self.scale_free >= 1]
        )

    def _chain_response(
        self,
        index: int,
        period: Mapping[str, cp.Expression],
        latency: Mapping[str, cp.Expression],
        constraints: list[cp.Constraint],
    ) -> cp.Expression | None:
        """``L + P`` of one chain; ``P`` a variable bounded below by every stage's period."""
        chain = self.problem.chains[index]
        if not chain.stages:
            return None
        form = chain_form(self.problem, chain)
        longest = cp.Variable(pos=True, name=f"P_{index}")
        if form.floor > 0:
            constraints.append(form.floor <= longest)
        constraints += [period[name] <= longest for name in form.longest_of]
        parts = [latency[name] for name in form.latency_of] + [period[name] for name in form.period_of]
        if form.constant > 0:
            parts.append(form.constant)
        return cp.sum(parts) + longest

    def set_numbers(self, problem: Problem) -> None:
        """Load compute times (and the dedicated constants they imply) into the parameters."""
        by_name = {sub.name: sub for sub in problem.subchains}
        for name in self.shared_names:
            compute = by_name[name].compute_ms
            self.compute[name].value = compute
            self.slice[name].value = min(self.schedule.min_slice_ms, compute)
        for name, cores in self.layout.dedicated:
            timing = capped_dedicated(by_name[name], cores, problem.slack)
            self.fixed_period[name].value = timing.period_ms
            self.fixed_latency[name].value = timing.latency_ms

    def set_box(self, box: Mapping[str, tuple[int, int]]) -> None:
        """Confine each non-batch subchain's ``n = 1/f`` to ``[low, high]`` (the rest: ``n >= 1``)."""
        for name in self.integral:
            low, high = box.get(name, (1, 0))
            self.f_max[name].value = 1.0 / low
            self.f_min[name].value = 1.0 / high if high >= low else 1e-9

    def solve(self, scale: float = 1.0) -> RelaxedSolution | None:
        """The relaxed optimum with every bound scaled by ``scale``; None when infeasible."""
        self.scale.value = scale
        return self._run(self.problem_gp)

    def solve_least_scale(self) -> RelaxedSolution | None:
        """The relaxed plan needing the smallest scale on the bounds (its ``objective`` is that scale)."""
        found = self._run(self.problem_scale)
        if found is not None:
            return found
        # Where the floor s >= 1 binds with the bounds far from tight (4x in issue 48's example),
        # Clarabel can stall on this program (InsufficientProgress) though a plan exists. A plan
        # meeting the bounds as written proves the least scale is exactly the floor.
        within = self.solve(1.0)
        return None if within is None else dataclasses.replace(within, objective=1.0)

    def _run(self, problem: cp.Problem) -> RelaxedSolution | None:
        try:
            with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
                # "Solution may be inaccurate": the status below says so too, and is accepted
                # (Clarabel reports it on badly scaled boxes, e.g. f near 1/500, within 1e-6).
                # Overflow: an infeasible problem's log-space iterate diverges before the status says so.
                warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
                problem.solve(gp=True, solver=cp.CLARABEL, **RECORD_TOLERANCES)
        except cp.SolverError:
            return None
        if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return None
        values = [
            problem.value,
            *(v.value for v in self.core_period.values()),
            *(v.value for v in self.fraction.values()),
        ]
        if not all(value is not None and math.isfinite(float(value)) for value in values):
            return None
        return RelaxedSolution(
            core_period_ms={core: float(var.value) for core, var in self.core_period.items()},
            fraction={name: float(var.value) for name, var in self.fraction.items()},
            period_ms={name: float(var.value) for name, var in self.period.items()},
            objective=float(problem.value),
        )
