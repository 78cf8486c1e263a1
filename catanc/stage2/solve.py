"""Stage II for one allocation: dedicated timings, then the shared cores' integer schedule.

- Dedicated subchains: Eq. 1's period and threads, then their rate cap
  (:func:`catanc.model.capped_dedicated`); no solver.
- Shared cores: the exact integer optimum over whole runs ``n_i = 1/f_i``
  (:func:`catanc.stage2.integer.solve_integer`) with soft bounds: at scale 1
  if any integer plan meets them, else at the smallest scale one can meet.

Every number of the result is re-derived from the schedule itself (``T``
from the fractions, ``p = max(T/f, p_min)``) and the objective re-evaluated
by :mod:`catanc.model`, so a result reports what its schedule would do.

:func:`lower_bound` bounds an allocation's result from below without a
solver, so the planner can skip allocations that cannot win.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from catanc.errors import InfeasibleError
from catanc.model import Timing, bound_scale, capped_dedicated, objective
from catanc.problem import Problem
from catanc.spec import Schedule
from catanc.stage2.base import Layout, Stage2Model, schedule_length
from catanc.stage2.integer import Effort, IntegerSolution, solve_integer

SCALE_PRECISION = 1e-6
"""Slack on the smallest bound scale when the bounds cannot all hold (solver tolerance)."""


@dataclass(frozen=True)
class Stage2Result:
    layout: Layout
    timings: dict[str, Timing]  # every subchain's period and processing latency
    threads: dict[str, int]  # Eq. 1's q (1 on a shared core)
    fractions: dict[str, float]  # f per shared subchain (exactly 1/n when not batch)
    runs: dict[str, int]  # n = 1/f per non-batch shared subchain
    lengths: dict[int, float]  # T per shared core
    scale: float  # the factor on the bounds this plan meets (1.0: as written)
    objective: float  # re-evaluated by the analytic model (ms)
    relaxations: int  # GP solves it took
    gap: float = 0.0  # proven relative distance to this layout's optimum (0 unless the search was capped)


def dedicated_timings(problem: Problem, layout: Layout) -> tuple[dict[str, Timing], dict[str, int]]:
    """Eq. 1 with the rate cap for every dedicated subchain: (timings, threads)."""
    timings: dict[str, Timing] = {}
    threads: dict[str, int] = {}
    for name, cores in layout.dedicated:
        dedicated = capped_dedicated(problem.subchain(name), cores)
        timings[name] = dedicated.timing
        threads[name] = dedicated.threads
    return timings, threads


def lower_bound(problem: Problem, layout: Layout, schedule: Schedule) -> tuple[float, float]:
    """(scale, objective) that no plan of this layout beats, in microseconds of arithmetic.

    A shared subchain's ``T / f_i`` is at least ``(c_i + sum of the others'
    least slices + switches) / (1 - slack)`` when ``f_i <= 1``, and at least
    ``c_i / (1 - slack)`` for a batch subchain (``f_i`` unbounded); the model's
    scale and objective only grow with periods and latencies.
    """
    timings, _ = dedicated_timings(problem, layout)
    usable = 1.0 - schedule.slack
    for core in layout.shared:
        members = [problem.subchain(name) for name in core.subchains]
        least = {sub.name: min(schedule.min_slice_ms, sub.compute_ms) for sub in members}
        switches = len(members) * schedule.switch_ms
        for sub in members:
            if sub.batch:
                latency = sub.compute_ms / usable
            else:
                others = math.fsum(least[other.name] for other in members if other.name != sub.name)
                latency = (sub.compute_ms + others + switches) / usable
            timings[sub.name] = Timing(max(latency, sub.min_period_ms), latency)
    return bound_scale(problem, timings), objective(problem, timings)


def solve_layout(
    problem: Problem,
    layout: Layout,
    schedule: Schedule,
    model: Stage2Model | None,
    *,
    beat: tuple[float, float] | None = None,
    start: dict[str, int] | None = None,
    gap: float = 0.0,
    node_limit: int | None = None,
    fixed: tuple[dict[str, int], float] | None = None,
    effort: Effort | None = None,
) -> Stage2Result | None:
    """The best integer plan for ``layout``, or None if it cannot beat ``beat`` = (scale, objective).

    ``model`` is the layout's relaxation, built beforehand (None when no core
    is shared) and loaded with ``problem``'s compute times here.  Raises
    :class:`InfeasibleError` when no schedule exists whatever the bounds.
    ``gap`` accepts an integer plan proven within that relative distance of
    the optimum (:func:`~catanc.stage2.integer.solve_integer`; 0: exact);
    ``node_limit`` caps its relaxations (the result then says its ``gap``);
    ``effort`` counts them, whatever the outcome.
    ``fixed`` = (runs, scale) skips the search: the plan with those runs
    (None if they miss the bounds so scaled); the planner's model of record
    re-solves the winner so.
    """
    timings, threads = dedicated_timings(problem, layout)
    fractions: dict[str, float] = {}
    runs: dict[str, int] = {}
    lengths: dict[int, float] = {}
    relaxations = 0
    search_gap = 0.0
    if layout.shared:
        if model is None:
            raise ValueError("a layout with shared cores needs its Stage II model")
        model.set_numbers(problem)
        if fixed is not None:
            found = _fixed_plan(model, *fixed)
        else:
            found = _integer_plan(model, problem, beat=beat, start=start, gap=gap, node_limit=node_limit, effort=effort)
        if found is None:
            return None
        solution = found
        relaxations = solution.nodes
        search_gap = solution.gap
        fractions = dict(solution.solution.fraction)
        runs = dict(solution.runs)
        for name, n in runs.items():
            fractions[name] = 1.0 / n  # exactly whole runs, not the solver's float
        by_name = {sub.name: sub for sub in problem.subchains}
        for core in layout.shared:
            lengths[core.core] = schedule_length(core, fractions, by_name, schedule)
            for name in core.subchains:
                latency = lengths[core.core] / fractions[name]
                timings[name] = Timing(max(latency, by_name[name].min_period_ms), latency)
                threads[name] = 1
    result = Stage2Result(
        layout=layout,
        timings=timings,
        threads=threads,
        fractions=fractions,
        runs=runs,
        lengths=lengths,
        scale=max(1.0, bound_scale(problem, timings)),
        objective=objective(problem, timings),
        relaxations=relaxations,
        gap=search_gap,
    )
    if beat is not None and not better(result, beat):
        return None
    return result


def better(result: Stage2Result, than: tuple[float, float]) -> bool:
    """Lexicographic: a smaller bound scale first, then a smaller objective (both beyond noise)."""
    scale, value = than
    if result.scale < scale * (1 - SCALE_PRECISION):
        return True
    if result.scale > scale * (1 + SCALE_PRECISION):
        return False
    return result.objective < value - 1e-9 * max(1.0, abs(value))


def _integer_plan(
    model: Stage2Model,
    problem: Problem,
    *,
    beat: tuple[float, float] | None,
    start: dict[str, int] | None,
    gap: float,
    node_limit: int | None,
    effort: Effort | None,
) -> IntegerSolution | None:
    """The integer optimum at scale 1, else at the smallest scale an integer plan can meet."""
    if beat is None or beat[0] <= 1.0 + SCALE_PRECISION:
        cutoff = beat[1] if beat is not None and problem.weighted else None
        found = solve_integer(
            model, problem, 1.0, cutoff=cutoff, start=start, gap=gap, node_limit=node_limit, effort=effort
        )
        if found is not None or beat is not None:
            return found  # None with ``beat``: worse, or infeasible where ``beat`` is feasible
    least = solve_integer(
        model,
        problem,
        least_scale=True,
        cutoff=None if beat is None else beat[0] * (1 + SCALE_PRECISION),
        node_limit=node_limit,
        effort=effort,
    )
    if least is None:
        if beat is not None:
            return None
        raise InfeasibleError(f"{problem.app}: no schedule exists for the shared cores, whatever the bounds")
    scale = least.objective * (1 + SCALE_PRECISION)
    return solve_integer(model, problem, scale, start=least.runs, gap=gap, node_limit=node_limit, effort=effort)


def _fixed_plan(model: Stage2Model, runs: dict[str, int], scale: float) -> IntegerSolution | None:
    model.set_box({name: (n, n) for name, n in runs.items()})
    solution = model.solve(scale)
    if solution is None:
        return None
    return IntegerSolution(dict(runs), solution, solution.objective, root_bound=solution.objective, nodes=1)
