"""Stage I as a mixed-integer linear program (pulp; HiGHS or CBC).

Formulation (cores are identical, so no core indices and no symmetry):

- ``x[i, o]`` binary: subchain ``i`` takes option ``o`` (dedicated on ``k``
  cores, or shared in a group of ``m``); exactly one per subchain.  Its period
  and latency are then the constants of :mod:`catanc.stage1.estimate`, so
  ``p_i = sum_o P(i, o) x[i, o]`` is linear: the fair share ``c(S) * m`` needs
  no product of variables.
- ``g[m]`` integer: the number of groups of size ``m``;
  ``sum_i x[i, shared m] = m * g[m]``.
- cores: ``sum k x[i, dedicated k] + sum g[m] = K`` (``<= K`` with fewer
  subchains than cores).
- each chain's period ``P_t`` is a variable bounded below by each stage's
  period; its response ``R_t = L_t + P_t`` is linear.
- bounds ``R_t <= s B_t`` and ``p_i <= s p_max`` with ``s = 1``; when that is
  infeasible, a first solve minimises ``s`` and the second keeps it.

The objective is section 2's, plus a tie-breaking term 1e-8 of the
objective's size (:func:`catanc.stage1.estimate.tie_rank`).  The reported
objective is always re-evaluated from the allocation by the analytic model.
"""

from __future__ import annotations

import math
import time
import warnings
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import highspy
import pulp

from catanc.errors import UsageError
from catanc.problem import Problem
from catanc.stage1.estimate import (
    SCALE_SLACK,
    TIE_WEIGHT,
    Allocation,
    Option,
    OptionTable,
    allocation_from_options,
    evaluate,
    objective_scale,
    option_rank,
    option_table,
)
from catanc.stage1.result import Stage1Result

SOLVERS = ("highs", "cbc")
DEFAULT_SOLVER = "highs"
DEFAULT_TIME_LIMIT_S = 2.0
"""Keeps ``catanc compile`` of a 60-subchain app on 16 cores within 5 s (bench/RESULTS.md)."""

RELATIVE_GAP = 1e-9
ABSOLUTE_GAP = 1e-10  # below the tie-breaking term, so ties are decided by it
SEED = 1


@dataclass
class _Model:
    prob: pulp.LpProblem
    choice: dict[tuple[str, Option], pulp.LpVariable]
    scale: pulp.LpVariable | None
    objective: pulp.LpAffineExpression
    tie_coefficient: dict[tuple[str, Option], float]


def solve_milp(
    problem: Problem,
    cores: int,
    *,
    solver: str = DEFAULT_SOLVER,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
) -> Stage1Result:
    """The best allocation by the MILP; within ``time_limit_s``, else the best found with its gap."""
    if solver not in SOLVERS:
        raise UsageError(f"unknown Stage I solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    method = f"milp/{solver}"
    if not problem.subchains:
        return Stage1Result(Allocation((), ()), 0.0, 1.0, True, 0.0, method)
    table = option_table(problem, cores)
    model = _build(problem, cores, table)
    deadline = time.monotonic() + time_limit_s
    outcome = _solve(model.prob, solver, deadline)
    if outcome.status == "infeasible" and model.scale is not None:
        # Soft bounds: find the smallest common scale, then optimise under it.
        model.scale.upBound = None
        model.prob.setObjective(model.scale + 0)
        outcome = _solve(model.prob, solver, deadline)
        least = float(model.scale.varValue)
        model.scale.upBound = least * (1 + SCALE_SLACK)
        model.prob.setObjective(model.objective)
        outcome = _solve(model.prob, solver, deadline)
    if outcome.status != "solved":
        raise RuntimeError(f"Stage I MILP ({solver}) found no allocation: {outcome.status}")
    options = {name: option for (name, option), var in model.choice.items() if var.varValue > 0.5}
    evaluation = evaluate(problem, table, options)
    tie_value = sum(model.tie_coefficient[key] * var.varValue for key, var in model.choice.items())
    return Stage1Result(
        allocation=allocation_from_options(problem, options),
        objective=evaluation.objective,
        constraint_scale=evaluation.scale,
        optimal=outcome.optimal,
        gap=0.0 if outcome.optimal else outcome.gap,
        method=method,
        model_objective=float(pulp.value(model.objective)) - tie_value,
    )


def _build(problem: Problem, cores: int, table: OptionTable) -> _Model:
    prob = pulp.LpProblem("catan_stage1", pulp.LpMinimize)
    subchains = problem.subchains
    count = len(subchains)
    choice: dict[tuple[str, Option], pulp.LpVariable] = {}
    for i, sub in enumerate(subchains):
        for j, option in enumerate(table[sub.name]):
            choice[sub.name, option] = prob.add_variable(f"x_{i}_{j}", cat=pulp.LpBinary)

    def estimate(name: str, which: str) -> pulp.LpAffineExpression:
        """A subchain's period or latency as a linear expression of its choice."""
        return pulp.LpAffineExpression(
            [(choice[name, option], getattr(timing, which)) for option, timing in table[name].items()]
        )

    period = {sub.name: estimate(sub.name, "period_ms") for sub in subchains}
    latency = {sub.name: estimate(sub.name, "latency_ms") for sub in subchains}

    for sub in subchains:
        prob += pulp.lpSum(choice[sub.name, option] for option in table[sub.name]) == 1, f"one_option_{sub.name}"
    sizes = sorted({option.size for option in next(iter(table.values())) if option.shared})
    groups = {m: prob.add_variable(f"groups_{m}", lowBound=0, cat=pulp.LpInteger) for m in sizes}
    for m in sizes:
        prob += pulp.lpSum(choice[sub.name, Option(True, m)] for sub in subchains) == m * groups[m], f"groups_of_{m}"
    used = pulp.lpSum(option.size * var for (_, option), var in choice.items() if not option.shared) + pulp.lpSum(
        groups.values()
    )
    prob += (used == cores) if count >= cores else (used <= cores), "cores"

    response: dict[int, pulp.LpAffineExpression] = {}
    for index, chain in enumerate(problem.chains):
        floor = 0.0
        chain_period = prob.add_variable(f"P_{index}", lowBound=0)
        chain_latency = pulp.LpAffineExpression()
        for position, stage in enumerate(chain.stages):
            if stage.fixed:
                fixed = problem.fixed_periods_ms[stage.name]
                floor = max(floor, fixed)
                chain_latency += fixed if position == 0 else 2 * fixed
                continue
            if position == 0 and chain.head_period_ms is not None:
                floor = max(floor, chain.head_period_ms)
            else:
                prob += chain_period >= period[stage.name], f"P_{index}_{position}"
            chain_latency += latency[stage.name] if position == 0 else period[stage.name] + latency[stage.name]
        chain_period.lowBound = floor
        response[index] = chain_latency + chain_period

    scale = None
    if problem.response_bounds or any(sub.max_period_ms < math.inf for sub in subchains):
        scale = prob.add_variable("scale", lowBound=1, upBound=1)
        for n, bound in enumerate(problem.response_bounds):
            prob += response[bound.chain] <= bound.max_response_ms * scale, f"bound_{n}"
        for sub in subchains:
            if sub.max_period_ms < math.inf:
                prob += period[sub.name] <= sub.max_period_ms * scale, f"rate_floor_{sub.name}"

    weights: Mapping[int, float] = _chain_weights(problem)
    objective = pulp.lpSum(weight * response[chain] for chain, weight in weights.items()) + pulp.lpSum(
        term.weight * period[term.subchain] for term in problem.period_terms
    )
    tie = TIE_WEIGHT * objective_scale(problem, table)
    tie_coefficient = {
        (sub.name, option): tie * option_rank(i, count, cores, option)
        for i, sub in enumerate(subchains)
        for option in table[sub.name]
    }
    objective += pulp.lpSum(coefficient * choice[key] for key, coefficient in tie_coefficient.items())
    prob.setObjective(objective)
    return _Model(prob, choice, scale, objective, tie_coefficient)


def _chain_weights(problem: Problem) -> dict[int, float]:
    weights: dict[int, float] = defaultdict(float)
    for term in problem.response_terms:
        weights[term.chain] += term.weight
    return dict(weights)


@dataclass(frozen=True)
class _Outcome:
    status: str  # "solved", "infeasible", or what went wrong
    optimal: bool = False
    gap: float | None = None


def _solve(prob: pulp.LpProblem, solver: str, deadline: float) -> _Outcome:
    remaining = max(0.05, deadline - time.monotonic())
    if solver == "highs":
        return _solve_highs(prob, remaining)
    return _solve_cbc(prob, remaining)


def _solve_highs(prob: pulp.LpProblem, time_limit_s: float) -> _Outcome:
    engine = pulp.HiGHS(
        msg=False, timeLimit=time_limit_s, gapRel=RELATIVE_GAP, gapAbs=ABSOLUTE_GAP, threads=1, random_seed=SEED
    )
    prob.solve(engine)
    highs: Any = prob.solverModel
    status = highs.getModelStatus()
    kinds = highspy.HighsModelStatus
    if status == kinds.kOptimal:
        return _Outcome("solved", optimal=True, gap=0.0)
    if status == kinds.kInfeasible:
        return _Outcome("infeasible")
    if prob.sol_status == pulp.LpSolutionIntegerFeasible:
        return _Outcome("solved", optimal=False, gap=float(highs.getInfo().mip_gap))
    return _Outcome(str(status))


def _solve_cbc(prob: pulp.LpProblem, time_limit_s: float) -> _Outcome:
    with warnings.catch_warnings():
        # pulp 3.3 announces that its bundled CBC leaves in pulp 4.0 (pyproject pins pulp < 4).
        warnings.filterwarnings("ignore", message="PULP_CBC_CMD is deprecated", category=DeprecationWarning)
        engine = pulp.PULP_CBC_CMD(
            msg=False,
            timeLimit=time_limit_s,
            gapRel=RELATIVE_GAP,
            gapAbs=ABSOLUTE_GAP,
            threads=1,
            options=[f"randomCbcSeed {SEED}", f"randomSeed {SEED}"],
        )
    prob.solve(engine)
    if prob.status == pulp.LpStatusInfeasible:
        return _Outcome("infeasible")
    if prob.sol_status == pulp.LpSolutionOptimal:
        return _Outcome("solved", optimal=True, gap=0.0)
    if prob.sol_status == pulp.LpSolutionIntegerFeasible:
        return _Outcome("solved", optimal=False)  # CBC through pulp does not report its bound
    return _Outcome(pulp.LpStatus[prob.status])
