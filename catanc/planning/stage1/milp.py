"""Stage I as a mixed-integer linear program (pulp; HiGHS or CBC).

Formulation (cores are identical, so no core indices and no symmetry):

- ``x[i, o]`` binary: subchain ``i`` takes option ``o`` (dedicated on ``k``
  cores, or shared in a group of ``m``); exactly one per subchain.  Its period
  and latency are then the constants of :mod:`catanc.planning.stage1.estimate`, so
  ``p_i = sum_o P(i, o) x[i, o]`` is linear: the fair share ``c(S) * m`` needs
  no product of variables.
- ``g[m]`` integer: the number of groups of size ``m``;
  ``sum_i x[i, shared m] = m * g[m]``, and ``g[m] >= x[i, shared m]`` (implied
  for integer solutions; it makes the LP relaxation tight: benchmarks/RESULTS.md).
- cores: ``sum k x[i, dedicated k] + sum g[m] = K`` (``<= K`` with fewer
  subchains than cores).
- each chain's period ``P_t`` is a variable bounded below by each stage's
  period; its response ``R_t = L_t + P_t`` is linear.
- bounds ``R_t <= s B_t`` and ``p_i <= s p_max`` with ``s = 1``; when that is
  infeasible, a first solve minimises ``s`` and the second keeps it.
- subchains that must share one core (an executor's unit,
  :mod:`catanc.planning.stage1.together`) take no dedicated option, and all take the
  same group size, at least the unit's: ``x[a, shared m] = x[b, shared m]``.
  That leaves only whether the units of one size fit its groups (three pairs
  in two groups of three do not): an answer that does not is cut off and the
  MILP solved again.

The objective is section 2's, plus a tie-breaking term 1e-8 of the
objective's size (:func:`catanc.planning.stage1.estimate.tie_rank`).  The reported
objective is always re-evaluated from the allocation by the analytic model.
"""

from __future__ import annotations

import math
import time
import warnings
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import highspy
import pulp

from catanc.errors import UsageError
from catanc.model.metrics import chain_form
from catanc.model.problem import Problem
from catanc.planning.stage1 import SOLVERS
from catanc.planning.stage1.estimate import (
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
from catanc.planning.stage1.result import Stage1Result
from catanc.planning.stage1.search import local_search
from catanc.planning.stage1.together import check_cores, options_allowed

DEFAULT_SOLVER = "highs"
DEFAULT_TIME_LIMIT_S = 2.5
"""Stage I's whole budget (model, LP, search, MILP): keeps ``catanc compile`` of a 60-subchain app
on 16 cores within 5 s (benchmarks/RESULTS.md)."""

MIN_SOLVE_S = 0.05
"""Below this much time left, the MILP is not started: the search's allocation stands."""

SEARCH_BUDGET = 60_000
SEARCH_BUDGET_MIN = 300
"""The local search polishes the rounded LP with SEARCH_BUDGET / N evaluations (at least the minimum):
an evaluation costs about N microseconds, so this is about 60 ms."""

LP_START_FROM = 20
"""From this many subchains the LP relaxation is solved first (bound and start); below, the MILP
alone is quicker than LP + MILP (benchmarks/RESULTS.md)."""

LP_TIME_LIMIT_S = 30.0
"""A safety net only: the relaxation takes 0.5 s at 60 subchains, 2 s at 100."""

RELATIVE_GAP = 1e-9
ABSOLUTE_GAP = 1e-10  # below the tie-breaking term, so ties are decided by it
SEED = 1


@dataclass
class _Model:
    prob: pulp.LpProblem
    choice: dict[tuple[str, Option], pulp.LpVariable]
    groups: dict[int, pulp.LpVariable]
    chain_periods: dict[int, pulp.LpVariable]
    scale: pulp.LpVariable | None
    objective: pulp.LpAffineExpression
    tie_coefficient: dict[tuple[str, Option], float]

    def start_values(
        self, problem: Problem, table: OptionTable, options: Mapping[str, Option]
    ) -> dict[str, float] | None:
        """Every variable's value for one allocation (a MIP start), if it meets the bounds as scaled now."""
        scale = evaluate(problem, table, options).scale
        if self.scale is not None and self.scale.upBound is not None and scale > self.scale.upBound:
            return None
        values = {var.name: float(options[name] == option) for (name, option), var in self.choice.items()}
        for size, var in self.groups.items():
            values[var.name] = sum(1 for o in options.values() if o == Option(True, size)) / size
        timings = {name: table[name][option] for name, option in options.items()}
        for index, var in self.chain_periods.items():
            form = chain_form(problem, problem.chains[index])
            values[var.name] = max([form.floor, *(timings[name].period_ms for name in form.longest_of)])
        if self.scale is not None:
            values[self.scale.name] = max(1.0, scale)
        return values


def solve_milp(
    problem: Problem,
    cores: int,
    *,
    solver: str = DEFAULT_SOLVER,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    exclude: Sequence[Allocation] = (),
    exclude_options: Sequence[Mapping[str, Option]] = (),
) -> Stage1Result:
    """The best allocation by the MILP; within ``time_limit_s``, else the best found with its gap.

    Steps: build the model; from :data:`LP_START_FROM` subchains, solve its LP
    relaxation to the end (a proven bound, and nearly integral); round it and
    polish it by local search (:mod:`catanc.planning.stage1.search`); give that to the
    MILP as its first incumbent, and let the MILP prove or improve it in what
    is left of ``time_limit_s`` (counted from the start).

    ``exclude`` lists allocations already found: a no-good cut per allocation
    (its options may not all be chosen again) makes the MILP return the next best.
    ``exclude_options`` cuts off options no grouping can form (executor units that do not fit).
    """
    if solver not in SOLVERS:
        raise UsageError(f"unknown Stage I solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    method = f"milp/{solver}"
    if not problem.subchains:
        return Stage1Result(Allocation((), ()), 0.0, 1.0, True, 0.0, method)
    check_cores(problem, cores)
    started = time.monotonic()
    deadline = started + time_limit_s
    table = option_table(problem, cores)
    model = _build(problem, cores, table)
    excluded = [allocation.options() for allocation in exclude] + [dict(options) for options in exclude_options]
    for n, options in enumerate(excluded):
        chosen = pulp.lpSum(model.choice[name, option] for name, option in options.items())
        model.prob += chosen <= len(options) - 1, f"no_good_{n}"
    relaxed = _relaxation(model, solver) if len(problem.subchains) >= LP_START_FROM else None
    budget = max(SEARCH_BUDGET_MIN, SEARCH_BUDGET // max(1, len(problem.subchains)))
    start = local_search(problem, table, cores, relaxed.weights if relaxed else None, budget=budget)
    lp_bound = relaxed.bound if relaxed else None

    def start_values() -> dict[str, float] | None:
        # An excluded allocation is no start (it violates its cut): the MILP then finds its own.
        if start in excluded or not options_allowed(problem, start):
            return None
        return model.start_values(problem, table, start)

    outcome = _solve(model.prob, solver, deadline, start_values())
    if outcome.status == "infeasible" and model.scale is not None:
        # Soft bounds: find the smallest common scale, then optimise under it.
        model.scale.upBound = None
        model.prob.setObjective(model.scale + 0)
        outcome = _solve(model.prob, solver, deadline, start_values())
        if outcome.status == "solved":
            model.scale.upBound = float(model.scale.varValue) * (1 + SCALE_SLACK)
        model.prob.setObjective(model.objective)
        outcome = _solve(model.prob, solver, deadline, start_values())
    options = dict(start)
    model_objective = None
    if outcome.status == "solved":
        found = {name: option for (name, option), var in model.choice.items() if var.varValue > 0.5}
        mine, theirs = evaluate(problem, table, start), evaluate(problem, table, found)
        if outcome.optimal or start in excluded or (theirs.scale, theirs.objective) <= (mine.scale, mine.objective):
            options = found
            model_objective = float(pulp.value(model.objective)) - sum(
                model.tie_coefficient[key] * var.varValue for key, var in model.choice.items()
            )
    elif outcome.status != "time limit":
        raise RuntimeError(f"Stage I MILP ({solver}) failed: {outcome.status}")
    if not options_allowed(problem, options):
        if options in excluded:
            raise RuntimeError("Stage I found no allocation that keeps each executor's subchains on one core")
        return solve_milp(
            problem,
            cores,
            solver=solver,
            time_limit_s=max(0.0, time_limit_s - (time.monotonic() - started)),
            exclude=exclude,
            exclude_options=[*exclude_options, options],
        )
    evaluation = evaluate(problem, table, options)
    bounds = [b for b in (outcome.bound, lp_bound) if b is not None and math.isfinite(b)]
    if evaluation.scale > 1.0:
        bounds = [b for b in bounds if b is outcome.bound]  # the LP bounded the unscaled problem
    return Stage1Result(
        allocation=allocation_from_options(problem, options),
        objective=evaluation.objective,
        constraint_scale=evaluation.scale,
        optimal=outcome.optimal,
        gap=0.0 if outcome.optimal else _gap(evaluation.objective, max(bounds, default=None)),
        method=method,
        model_objective=model_objective,
    )


@dataclass(frozen=True)
class _Relaxation:
    weights: dict[str, dict[Option, float]]  # each subchain's options, as the LP weighs them
    bound: float  # the LP's value: a proven lower bound (to the tie term's 1e-8)


def _relaxation(model: _Model, solver: str) -> _Relaxation | None:
    """The LP relaxation: a proven bound and, rounded, a near-optimal start (HiGHS only).

    It is solved to the end whatever the time limit (an LP is quick: 0.5 s at
    60 subchains); through CBC's subprocess it costs more than it gives, so
    CBC starts from the local search alone.
    """
    if solver != "highs":
        return None
    model.prob.solve(_DeadlineHiGHS(None, time.monotonic() + LP_TIME_LIMIT_S, mip=False, threads=1))
    if model.prob.status != pulp.LpStatusOptimal:
        return None  # bounds that cannot all hold: the search starts from scratch
    weights: dict[str, dict[Option, float]] = {}
    for (name, option), var in model.choice.items():
        weights.setdefault(name, {})[option] = float(var.varValue or 0.0)
    return _Relaxation(weights, float(pulp.value(model.prob.objective)))


def _gap(value: float, bound: float | None) -> float | None:
    if bound is None:
        return None
    return max(0.0, value - bound) / max(abs(value), 1e-12)


def _build(problem: Problem, cores: int, table: OptionTable, *, strengthen: bool = True) -> _Model:
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
        # Implied for integer solutions, and what makes the LP tight: a subchain sharing at size m
        # needs a whole group of size m. Without it the relaxation lets every subchain pick its own
        # size at a fraction of a core (60 subchains: LP bound 94% of the optimum instead of 99.7%).
        for i, sub in enumerate(subchains):
            if strengthen:  # off only to measure what it buys (benchmarks/solvers.py)
                prob += groups[m] >= choice[sub.name, Option(True, m)], f"group_exists_{m}_{i}"
    used = pulp.lpSum(option.size * var for (_, option), var in choice.items() if not option.shared) + pulp.lpSum(
        groups.values()
    )
    prob += (used == cores) if count >= cores else (used <= cores), "cores"
    for number, unit in enumerate(problem.together):
        for option in table[unit[0]]:
            if not option.shared or option.size < len(unit):
                for name in unit:
                    prob += choice[name, option] == 0, f"together_{number}_{name}_{option.shared:d}_{option.size}"
            else:
                for name in unit[1:]:
                    prob += choice[name, option] == choice[unit[0], option], f"together_{number}_{name}_{option.size}"

    response: dict[int, pulp.LpAffineExpression] = {}
    chain_periods: dict[int, pulp.LpVariable] = {}
    for index, chain in enumerate(problem.chains):
        form = chain_form(problem, chain)
        chain_period = prob.add_variable(f"P_{index}", lowBound=form.floor)
        for position, name in enumerate(form.longest_of):
            prob += chain_period >= period[name], f"P_{index}_{position}"
        chain_latency = (
            pulp.lpSum(latency[name] for name in form.latency_of)
            + pulp.lpSum(period[name] for name in form.period_of)
            + form.constant
        )
        chain_periods[index] = chain_period
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
    return _Model(prob, choice, groups, chain_periods, scale, objective, tie_coefficient)


def _chain_weights(problem: Problem) -> dict[int, float]:
    weights: dict[int, float] = defaultdict(float)
    for term in problem.response_terms:
        weights[term.chain] += term.weight
    return dict(weights)


@dataclass(frozen=True)
class _Outcome:
    status: str  # "solved", "infeasible", "time limit" (no solution found), or what went wrong
    optimal: bool = False
    bound: float | None = None  # the solver's proven lower bound, when it stopped early


def _solve(prob: pulp.LpProblem, solver: str, deadline: float, start: dict[str, float] | None) -> _Outcome:
    if deadline - time.monotonic() < MIN_SOLVE_S:
        return _Outcome("time limit")
    if solver == "highs":
        return _solve_highs(prob, deadline, start)
    return _solve_cbc(prob, deadline, start)


class _SilentHighs(highspy.Highs):
    """highspy's solver with its output off from its first call on.

    highspy 1.16's constructor calls ``enableCallbacks``, and HiGHS prints its
    banner to stdout at the first call made while ``output_flag`` is on: pulp
    sets the flag only after construction, so the banner went into
    ``catanc allocate --json``.  Setting options prints nothing.
    """

    def __init__(self) -> None:
        super().__init__()  # type: ignore[no-untyped-call]  # highspy's constructor has no annotations

    def enableCallbacks(self) -> Any:
        self.silent()
        return super().enableCallbacks()  # type: ignore[no-untyped-call]


class _DeadlineHiGHS(pulp.HiGHS):  # type: ignore[misc]
    """pulp's HiGHS, silent, handed a starting solution and the time left once the model is built."""

    def __init__(self, start: dict[str, float] | None, deadline: float, **options: Any) -> None:
        super().__init__(msg=False, **options)
        self.start = start
        self.deadline = deadline

    def createAndConfigureSolver(self, lp: pulp.LpProblem) -> None:
        # pulp's own makes a highspy.Highs, which prints before the options can silence it
        highs = _SilentHighs()
        settings = {"mip_rel_gap": self.gapRel, "mip_abs_gap": self.gapAbs, "threads": self.threads}  # time: callSolver
        for key, value in {**settings, **self.optionsDict}.items():
            if value is not None:
                highs.setOptionValue(key, value)
        lp.solverModel = highs

    def callSolver(self, lp: pulp.LpProblem) -> None:
        highs: Any = lp.solverModel
        # pulp builds the model before this call: the clock HiGHS sees starts now.
        highs.setOptionValue("time_limit", max(MIN_SOLVE_S, self.deadline - time.monotonic()))
        if self.start is not None:
            values = [0.0] * highs.getNumCol()
            for var in lp.variables():
                values[var.index] = self.start.get(var.name, 0.0)
            solution = highspy.HighsSolution()
            solution.col_value = values
            highs.setSolution(solution)
        highs.run()


OBJECTIVE_AGREEMENT = 1e-7
"""How closely (relative) HiGHS's reported objective must match the one of the solution it returns."""


def _solve_highs(prob: pulp.LpProblem, deadline: float, start: dict[str, float] | None) -> _Outcome:
    outcome = _run_highs(prob, deadline, start)
    if start is not None and outcome.status == "solved" and not _objective_agrees(prob.solverModel):
        # highspy 1.16.0 (presolve on, a start given) can misread the start's objective, dropping
        # presolve's offset: a start costing 45.6 read as 9.6, below the optimum, so the search
        # stopped at once and returned the start as "optimal" (45.2 exists).  Its own search is right.
        outcome = _run_highs(prob, deadline, None)
    return outcome


def _objective_agrees(highs: Any) -> bool:
    """Whether the objective HiGHS reports is that of the solution it returns, as its own model prices it."""
    model = highs.getLp()
    costs: list[float] = [float(cost) for cost in model.col_cost_]
    values: list[float] = [float(value) for value in highs.getSolution().col_value]
    priced = math.fsum([float(model.offset_), *(cost * value for cost, value in zip(costs, values, strict=True))])
    reported = float(highs.getInfo().objective_function_value)
    return abs(priced - reported) <= OBJECTIVE_AGREEMENT * max(1.0, abs(priced))


def _run_highs(prob: pulp.LpProblem, deadline: float, start: dict[str, float] | None) -> _Outcome:
    prob.solve(_DeadlineHiGHS(start, deadline, gapRel=RELATIVE_GAP, gapAbs=ABSOLUTE_GAP, threads=1, random_seed=SEED))
    highs: Any = prob.solverModel
    status = highs.getModelStatus()
    kinds = highspy.HighsModelStatus
    if status == kinds.kOptimal:
        return _Outcome("solved", optimal=True)
    if status == kinds.kInfeasible:
        return _Outcome("infeasible")
    bound = float(highs.getInfo().mip_dual_bound)
    if prob.sol_status == pulp.LpSolutionIntegerFeasible:
        return _Outcome("solved", bound=bound)
    if status == kinds.kTimeLimit:
        return _Outcome("time limit", bound=bound)
    return _Outcome(str(status))


def _solve_cbc(prob: pulp.LpProblem, deadline: float, start: dict[str, float] | None) -> _Outcome:
    if start is not None:
        for var in prob.variables():
            var.setInitialValue(start.get(var.name, 0.0), check=False)
    with warnings.catch_warnings():
        # pulp 3.3 announces that its bundled CBC leaves in pulp 4.0 (pyproject pins pulp < 4).
        warnings.filterwarnings("ignore", message="PULP_CBC_CMD is deprecated", category=DeprecationWarning)
        engine = pulp.PULP_CBC_CMD(
            msg=False,
            timeLimit=max(MIN_SOLVE_S, deadline - time.monotonic()),
            gapRel=RELATIVE_GAP,
            gapAbs=ABSOLUTE_GAP,
            threads=1,
            warmStart=start is not None,
            options=[f"randomCbcSeed {SEED}", f"randomSeed {SEED}"],
        )
    prob.solve(engine)
    if prob.status == pulp.LpStatusInfeasible:
        return _Outcome("infeasible")
    if prob.sol_status == pulp.LpSolutionOptimal:
        return _Outcome("solved", optimal=True)
    if prob.sol_status == pulp.LpSolutionIntegerFeasible:
        return _Outcome("solved")  # CBC through pulp does not report its bound
    if prob.status == pulp.LpStatusNotSolved:
        return _Outcome("time limit")
    return _Outcome(pulp.LpStatus[prob.status])


def relaxation_bound(problem: Problem, cores: int, *, strengthen: bool = True) -> float | None:
    """The LP relaxation's value, with or without the strengthening rows (for the benchmark)."""
    table = option_table(problem, cores)
    relaxed = _relaxation(_build(problem, cores, table, strengthen=strengthen), "highs")
    return relaxed.bound if relaxed else None
