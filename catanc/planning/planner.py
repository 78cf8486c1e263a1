"""The planner: Stage I, then Stage II, into a :class:`Plan` (the runtime table's ``plan``).

- Stage I (:mod:`catanc.planning.stage1`) allocates cores with crude period estimates.
- Stage II (:mod:`catanc.planning.stage2.solve`) plans an allocation exactly:
  dedicated subchains by Eq. 1, shared cores by one geometric program with
  whole runs ``1/f``, bounds soft (the smallest common scale, warned about).
- Beyond the paper: Stage I's estimate misjudges which subchains pair well,
  so the planner also plans Stage I's runners-up exactly and keeps the best
  (:func:`candidate_allocations`): every allocation when there are at most
  :data:`ALL_ALLOCATIONS_UP_TO`, else the MILP's next best by no-good cuts.
  Allocations whose solver-free lower bound cannot beat the best so far are
  skipped, and at most :data:`PLAN_AT_MOST` are solved, the most promising
  first.  The plain two-stage result is kept for comparison.

Every number in the plan is re-derived from the schedule itself and the
objective re-evaluated by :mod:`catanc.model.metrics`, so the plan reports what it
would do.  :class:`catanc.planning.replan.Replanner` re-plans with new compute times.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import replace
from typing import Literal

from catanc.errors import InfeasibleError, UsageError
from catanc.model.build import build_problem
from catanc.model.metrics import chain_metrics_of
from catanc.model.problem import Problem
from catanc.planning.order import data_flow_order, flow_weights, priorities
from catanc.planning.stage1 import Allocation, Stage1Result, allocate, next_best
from catanc.planning.stage1.exhaustive import every_allocation
from catanc.planning.stage2.base import Layout, SharedCore, Stage2Model
from catanc.planning.stage2.convex import Open
from catanc.planning.stage2.integer import Effort
from catanc.planning.stage2.solve import (
    SCALE_PRECISION,
    Stage2Result,
    better,
    closed_fixed_plan,
    fixed_rate_conflicts,
    lower_bound,
    solve_layout,
)
from catanc.planning.stage2.turns import LayoutTurns
from catanc.planning.types import ChainPlan, CorePlan, OfferedChoice, Plan, SubchainPlan, TwoStageComparison
from catanc.spec.language import Schedule, Spec

ALL_ALLOCATIONS_UP_TO = 2500
"""Plan every allocation exactly when there are at most this many (8 subchains on 4 cores: 2,213)."""

PLAN_AT_MOST = 150
"""Of those, at most this many (the most promising by their lower bound) get a Stage II solve: a
count, not a clock, so that the same spec always gives the same plan (~2 ms each; 8 subchains on
4 cores can have 2,000 allocations that the bound cannot rule out)."""

STAGE2_RELAXATIONS = 500
"""Stage II's integer search on the allocation planned first stops after this many relaxations
(~0.3-2 ms each) once it has a plan, and the plan says its proven gap: a group of 20 subchains on
one core took 4,117 (9 s). A count, not a clock: deterministic."""

RUNNER_UP_RELAXATIONS = 20
RUNNERS_UP_RELAXATIONS = 500
"""Each runner-up's search, and all of them together, stop after this many relaxations (once it has a plan).

A runner-up's search only counts if it beats the best plan so far, and where the relaxation is loose
(rate caps: whole trigger counts) its depth-first dives rarely do: on Autoware at K=2 eight runners-up
each dived ~180 relaxations and found their plan at the first box the search then rounds best first.
So a runner-up turns best first after 20 (the same plans on every example spec at K=1-4 and on
Autoware at K=1, 2, 4, 8; Autoware K=2 planned in 0.78 s CPU instead of 1.74)."""

NEXT_BEST = 4
"""Beyond ALL_ALLOCATIONS_UP_TO, how many of the MILP's runners-up to plan exactly."""

NEXT_BEST_TIME_S = 0.5
"""Each runner-up's MILP must be proven within this, else the search for runners-up stops."""

Backend = Literal["cvxpy", "conic"]
BACKENDS: tuple[Backend, ...] = ("cvxpy", "conic")


def plan(
    spec: Spec,
    cores: int,
    *,
    stage1_method: str = "auto",
    solver: str | None = None,
    time_limit_s: float | None = None,
    runners_up: bool = True,
    backend: Backend = "cvxpy",
) -> Plan:
    """Plan ``spec`` on ``cores`` identical cores.

    ``runners_up=False`` gives the paper's plain two-stage plan.  ``backend``
    picks the model the plan's Stage II is solved with: cvxpy (the model of
    record) or the direct conic model (the same optimum, faster); runners-up
    are always ranked with the conic one.
    """
    return plan_problem(
        build_problem(spec),
        spec.schedule,
        cores,
        stage1_method=stage1_method,
        solver=solver,
        time_limit_s=time_limit_s,
        runners_up=runners_up,
        backend=backend,
    )


def offered_rate_misses(problem: Problem, result: Stage2Result) -> list[str]:
    """A warning per subchain whose driver offers rates where none is met: the one picked, as planned.

    On a shared core the rate picked is a fixed rate there, which :func:`fixed_rate_conflicts` names.
    """
    notes = []
    for sub in problem.subchains:
        picked = result.offered.get(sub.name)
        if picked is None or sub.name in result.runs or result.timings[sub.name].period_ms <= picked * (1 + 1e-6):
            continue
        offered = ", ".join(f"{rate:g}" for rate in sub.offered_hz)
        notes.append(
            f"subchain {sub.name}: none of the rates its driver offers ({offered} Hz) can be met: planned at "
            f"{1000.0 / result.timings[sub.name].period_ms:.4g} Hz, slower than the {1000.0 / picked:.4g} Hz "
            "picked: the subchain cannot keep up with its driver (give it more cores, or offer a slower rate)"
        )
    return notes


def plan_problem(
    problem: Problem,
    schedule: Schedule,
    cores: int,
    *,
    stage1_method: str = "auto",
    solver: str | None = None,
    time_limit_s: float | None = None,
    runners_up: bool = True,
    backend: Backend = "cvxpy",
    models: dict[Layout, Stage2Model] | None = None,
    gap: float = 0.0,
    start: tuple[Layout, dict[str, int]] | None = None,
    compare_offered: bool = True,
) -> Plan:
    """:func:`plan` for a built problem; ``models`` caches Stage II models by layout (re-planning).

    Re-planning may also accept each allocation's integer plan within ``gap`` of its optimum (see
    :func:`~catanc.planning.stage2.solve.solve_layout`; 0: exact) and start the search of ``start``'s layout
    from its runs (the current plan's).  Where drivers offer rates, ``compare_offered`` also plans their
    rates free, for explain (:attr:`Plan.offered`; re-planning at run time has no use for it).
    """
    if backend not in BACKENDS:
        raise UsageError(f"unknown Stage II backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    first = allocate(problem, cores, method=stage1_method, solver=solver, time_limit_s=time_limit_s)
    importance = problem.importance()
    cache: dict[Layout, Stage2Model] = {} if models is None else models

    candidates = candidate_allocations(problem, cores, first, solver=solver) if runners_up else [first.allocation]
    layouts = {
        allocation: ordered_layout(Layout.from_allocation(allocation), schedule, importance, problem)
        for allocation in candidates
    }
    best: Stage2Result | None = None
    chosen = first.allocation
    two_stage: Stage2Result | None = None
    planned = 0
    complete = True
    budget = RUNNERS_UP_RELAXATIONS
    bounds = {allocation: lower_bound(problem, layouts[allocation], schedule) for allocation in candidates[1:]}
    ranked = candidates[:1] + sorted(candidates[1:], key=lambda allocation: bounds[allocation])
    for allocation in ranked:
        if best is not None and not _could_beat(bounds[allocation], best):
            continue
        if planned >= PLAN_AT_MOST or budget <= 0:
            complete = False
            break
        layout = layouts[allocation]
        beat = None if best is None else (best.scale, best.as_run)
        limit = STAGE2_RELAXATIONS if best is None else min(RUNNER_UP_RELAXATIONS, budget)
        effort = Effort()
        try:
            result = solve_layout(
                problem,
                layout,
                schedule,
                conic_model(cache, problem, layout, schedule),
                beat=beat,
                start=start[1] if start is not None and start[0] == layout else None,
                gap=gap,
                node_limit=limit,
                effort=effort,
            )
        except InfeasibleError:
            if len(candidates) == 1:
                raise
            result = None
        planned += 1
        if best is not None:
            budget -= effort.relaxations
        if allocation == first.allocation:
            two_stage = result
        if result is not None and (best is None or better(result, (best.scale, best.as_run))):
            best, chosen = result, allocation
    if best is None:
        raise InfeasibleError(f"{problem.app}: no schedule exists for the shared cores, whatever the bounds")
    if best.offered:  # from here on, the offered rates picked are fixed rates
        problem = problem.choosing(best.offered)
    if backend == "cvxpy" and best.layout.shared:
        # The winner's numbers come from the model of record, at the runs the search chose.
        scale = 1.0 if best.scale <= 1.0 + SCALE_PRECISION else best.scale * (1 + SCALE_PRECISION)
        fixed = (best.runs, scale)
        # Where the closed form gives the plan (rate caps on shared subchains), no solver runs: the model
        # of record is then not built, nor cvxpy imported (~1 s of a whole process, Autoware).
        model = conic_model(cache, problem, best.layout, schedule)
        if model is None or isinstance(closed_fixed_plan(model, *fixed), Open):
            model = new_model(problem, best.layout, schedule, "cvxpy")
        record = solve_layout(problem, best.layout, schedule, model, fixed=fixed)
        if record is not None:
            best = replace(record, gap=best.gap, relaxations=best.relaxations, offered=best.offered)
    comparison = TwoStageComparison(
        allocations=len(candidates),
        planned=planned,
        complete=complete,
        two_stage_objective=None if two_stage is None else two_stage.as_run,
        two_stage_scale=None if two_stage is None else two_stage.scale,
    )
    found = assemble(
        problem=problem,
        schedule=schedule,
        cores=cores,
        result=best,
        allocation=chosen,
        first=first,
        comparison=comparison,
        importance=importance,
    )
    if not (compare_offered and best.offered):
        return found
    free = plan_problem(
        problem.freed(),
        schedule,
        cores,
        stage1_method=stage1_method,
        solver=solver,
        time_limit_s=time_limit_s,
        runners_up=runners_up,
        backend=backend,
        compare_offered=False,
    )
    return replace(found, offered=offered_choices(problem, found, free))


def offered_choices(problem: Problem, found: Plan, free: Plan) -> tuple[OfferedChoice, ...]:
    """Per subchain whose driver offers rates: the one ``found`` picked, and the rate a ``free`` plan took."""
    return tuple(
        OfferedChoice(
            subchain=sub.name,
            node=sub.offered_by,
            offered_hz=sub.offered_hz,
            picked_hz=next(rate for rate in sub.offered_hz if 1000.0 / rate == found.offered_periods_ms[sub.name]),
            planned_hz=1000.0 / found.subchains[sub.name].period_ms,
            free_hz=1000.0 / free.subchains[sub.name].period_ms,
            free_objective=free.objective,
            free_scale=free.constraint_scale,
        )
        for sub in problem.subchains
        if sub.name in found.offered_periods_ms
    )


def conic_model(
    cache: dict[Layout, Stage2Model], problem: Problem, layout: Layout, schedule: Schedule
) -> Stage2Model | None:
    """The conic model of ``layout`` from ``cache``, built on first use (None when no core is shared).

    A cached model is reused whatever compute times ``problem`` now has: they are loaded per solve.
    """
    if not layout.shared:
        return None
    if layout not in cache:
        cache[layout] = new_model(problem, layout, schedule, "conic")
    return cache[layout]


def new_model(problem: Problem, layout: Layout, schedule: Schedule, backend: Backend) -> Stage2Model:
    """Stage II's relaxation of ``layout`` for ``backend`` (built once, re-solved with new numbers).

    The solvers load on first use: cvxpy only for the model of record.
    """
    if backend == "conic":
        from catanc.planning.stage2.conic import ConicStage2  # noqa: PLC0415

        return ConicStage2(problem, layout, schedule)
    from catanc.planning.stage2.relaxed import RelaxedStage2  # noqa: PLC0415

    return RelaxedStage2(problem, layout, schedule)


def candidate_allocations(
    problem: Problem, cores: int, first: Stage1Result, *, solver: str | None = None
) -> list[Allocation]:
    """Stage I's allocation, then the runners-up to plan exactly (see the module's docstring)."""
    every = list(itertools.islice(every_allocation(problem, cores), ALL_ALLOCATIONS_UP_TO + 1))
    if len(every) <= ALL_ALLOCATIONS_UP_TO:
        return [first.allocation, *(allocation for allocation in every if allocation != first.allocation)]
    if not first.optimal:  # Stage I used its whole budget already
        return [first.allocation]
    found = [first.allocation]
    while len(found) <= NEXT_BEST:
        runner_up = next_best(problem, cores, found, solver=solver, time_limit_s=NEXT_BEST_TIME_S)
        if not runner_up.optimal or runner_up.allocation in found:
            break  # a runner-up found by the clock could differ from run to run
        found.append(runner_up.allocation)
    return found


def _could_beat(bound: tuple[float, float], best: Stage2Result) -> bool:
    scale, value = bound
    if scale > best.scale * (1 + SCALE_PRECISION):
        return False
    if scale < best.scale * (1 - SCALE_PRECISION):
        return True
    return value < best.as_run - 1e-9 * max(1.0, abs(best.as_run))


def ordered_layout(layout: Layout, schedule: Schedule, importance: dict[str, float], problem: Problem) -> Layout:
    """Each shared core's subchains in the spec's ``order``, then by weight (the data flow's order, chosen
    once the slices are known, starts from this one: :func:`slot_order`)."""
    position = {sub.name: index for index, sub in enumerate(problem.subchains)}
    given = {name: index for index, name in enumerate(schedule.order or [])}

    def key(name: str) -> tuple[int, float, int]:
        if name in given:
            return (0, given[name], 0)
        return (1, -importance[name], position[name])

    shared = tuple(SharedCore(core.core, tuple(sorted(core.subchains, key=key))) for core in layout.shared)
    return Layout(layout.dedicated, shared)


def slot_order(core: SharedCore, result: Stage2Result, problem: Problem, schedule: Schedule) -> tuple[str, ...]:
    """The order of the core's slots: the spec's where it names them, else the data flow's with these slices."""
    given = set(schedule.order or [])
    if given & set(core.subchains):
        return core.subchains
    slices = {name: result.fractions[name] * problem.subchain(name).compute_ms for name in core.subchains}
    weights = flow_weights(problem, core.subchains)
    return data_flow_order(core.subchains, slices, weights, schedule.switch_ms, result.lengths[core.core])


def periods_as_run(problem: Problem, schedule: Schedule, result: Stage2Result) -> dict[str, float]:
    """The periods an executor's thread changes (:meth:`LayoutTurns.periods`), by subchain; the rest run as planned.

    Where Stage II's executor trade scored them at the plan's timings, they are its.
    """
    periods = result.periods_as_run
    if periods is None:
        turns = LayoutTurns.of(problem, result.layout, schedule) if result.layout.shared else None
        if turns is None:
            return {}
        periods = turns.periods(problem, result.timings)
    planned = result.timings
    return {name: period for name, period in periods.items() if period > planned[name].period_ms * (1 + 1e-9)}


def assemble(
    *,
    problem: Problem,
    schedule: Schedule,
    cores: int,
    result: Stage2Result,
    allocation: Allocation,
    first: Stage1Result,
    comparison: TwoStageComparison,
    importance: dict[str, float],
    orders: Mapping[int, tuple[str, ...]] | None = None,
) -> Plan:
    """The plan of one Stage II result: per subchain, per shared core, per chain, and warnings.

    ``orders`` keeps each core's slot order where it holds the same subchains (a re-solve keeps
    the order its plan was made with: :func:`slot_order` enumerates orders).
    """
    problem = problem.choosing(result.offered)  # the offered rates picked are fixed rates (re-plans too)
    kept = dict(orders or {})
    warnings = []
    if not first.optimal:  # Stage I's own bound scale is an estimate: the plan's below is what counts
        gap = "unknown" if first.gap is None else f"{first.gap:.2%}"
        warnings.append(f"Stage I stopped at its time limit with a proven optimality gap of {gap}")
    if result.gap > 0:
        warnings.append(
            f"Stage II's integer search stopped after {result.relaxations} relaxations: the plan is within "
            f"{result.gap:.3%} of the best for its allocation"
        )
    warnings += fixed_rate_conflicts(problem, result)
    warnings += offered_rate_misses(problem, result)
    if result.scale > 1.0 + SCALE_PRECISION:
        warnings.append(
            f"the bounds cannot all be met: every chain bound and rate floor is scaled by {result.scale:.4g} "
            "(the plan meets the scaled bounds)"
        )
    indices = allocation.core_indices()
    ranks = priorities(problem, schedule, importance)
    as_run = periods_as_run(problem, schedule, result)
    subchains = {
        sub.name: SubchainPlan(
            name=sub.name,
            nodes=sub.nodes,
            cores=indices[sub.name],
            shared=sub.name in result.fractions,
            threads=result.threads[sub.name],
            period_ms=result.timings[sub.name].period_ms,
            latency_ms=result.timings[sub.name].latency_ms,
            fraction=result.fractions.get(sub.name, 1.0),
            priority=ranks[sub.name],
            every=result.every.get(sub.name),
            period_as_run_ms=as_run.get(sub.name),
        )
        for sub in problem.subchains
    }
    chains = []
    for index, chain in enumerate(problem.chains):
        metrics = chain_metrics_of(problem, index, result.timings)
        names = tuple(stage.name for stage in chain.stages)
        chains.append(ChainPlan(chain.nodes, names, metrics.latency_ms, metrics.period_ms, metrics.response_ms))
    return Plan(
        app=problem.app,
        cores=cores,
        objective=result.objective,
        constraint_scale=result.scale,
        subchains=subchains,
        shared_cores=tuple(
            CorePlan(
                core.core,
                result.lengths[core.core],
                kept[core.core]
                if sorted(kept.get(core.core, ())) == sorted(core.subchains)
                else slot_order(core, result, problem, schedule),
            )
            for core in result.layout.shared
        ),
        chains=tuple(chains),
        stage1=first,
        warnings=tuple(warnings),
        allocation=allocation,
        comparison=comparison,
        runs=dict(result.runs),
        every=dict(result.every),
        objective_as_run=result.as_run,
        offered_periods_ms=dict(result.offered),
    )
