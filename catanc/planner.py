"""The planner: Stage I, then Stage II, into a :class:`Plan` (the runtime table's ``plan``).

- Stage I (:mod:`catanc.stage1`) allocates cores.
- Dedicated subchains get Eq. 1's period and thread count, then their rate cap.
- Shared cores get one geometric program over all of them, with whole runs
  ``1/f`` for non-batch subchains (:mod:`catanc.stage2`).
- Bounds are soft: if no plan meets them, the smallest common scale an
  integer plan can meet is found (by the same branch and bound, minimising
  the scale), used, reported and warned about.

Every number in the plan is re-derived from the schedule itself (``T`` from
the fractions, ``p = max(T/f, p_min)``) and the objective re-evaluated by
:mod:`catanc.model`, so the plan reports what it would do.

Still to come (issue 4): evaluating Stage I's next-best allocations under
Stage II, ``Replanner``, ``catanc explain``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from catanc.errors import InfeasibleError
from catanc.model import Timing, bound_scale, capped_dedicated, evaluate_chain, objective
from catanc.problem import Problem, Subchain, build_problem
from catanc.spec import Schedule, Spec
from catanc.stage1 import Stage1Result, allocate
from catanc.stage2.integer import IntegerSolution, solve_integer
from catanc.stage2.relaxed import Layout, RelaxedStage2, SharedCore

SCALE_PRECISION = 1e-6
"""Slack on the smallest bound scale when the bounds cannot all hold (solver tolerance)."""


@dataclass(frozen=True)
class SubchainPlan:
    name: str
    nodes: tuple[str, ...]
    cores: tuple[int, ...]
    shared: bool
    threads: int  # Eq. 1's q (1 on a shared core)
    period_ms: float
    latency_ms: float
    fraction: float  # f: share of one run per schedule period (1.0 when dedicated)
    priority: int  # higher steals from lower


@dataclass(frozen=True)
class CorePlan:
    core: int
    period_ms: float  # T, the schedule's length
    order: tuple[str, ...]


@dataclass(frozen=True)
class ChainPlan:
    nodes: tuple[str, ...]
    subchains: tuple[str, ...]
    latency_ms: float
    period_ms: float
    response_ms: float


@dataclass(frozen=True)
class Plan:
    app: str
    cores: int
    objective: float
    constraint_scale: float
    subchains: dict[str, SubchainPlan]
    shared_cores: tuple[CorePlan, ...]
    chains: tuple[ChainPlan, ...]
    stage1: Stage1Result
    warnings: tuple[str, ...]


def plan(
    spec: Spec,
    cores: int,
    *,
    stage1_method: str = "auto",
    solver: str | None = None,
    time_limit_s: float | None = None,
) -> Plan:
    """Plan ``spec`` on ``cores`` identical cores."""
    problem = build_problem(spec)
    first = allocate(problem, cores, method=stage1_method, solver=solver, time_limit_s=time_limit_s)
    importance = problem.importance()
    layout = ordered_layout(Layout.from_allocation(first.allocation), spec.schedule, importance, problem)
    by_name = {sub.name: sub for sub in problem.subchains}
    timings: dict[str, Timing] = {}
    threads: dict[str, int] = {}
    for name, k in layout.dedicated:
        dedicated = capped_dedicated(by_name[name], k)
        timings[name] = dedicated.timing
        threads[name] = dedicated.threads
    fractions: dict[str, float] = {}
    lengths: dict[int, float] = {}
    if layout.shared:
        model = RelaxedStage2(problem, layout, spec.schedule)
        model.set_numbers(problem)
        _, solution = _smallest_scale(model, problem)
        fractions = dict(solution.solution.fraction)
        for name in solution.runs:
            fractions[name] = 1.0 / solution.runs[name]  # exactly whole runs, not the solver's float
        for core in layout.shared:
            lengths[core.core] = schedule_length(core, fractions, by_name, spec.schedule)
            for name in core.subchains:
                latency = lengths[core.core] / fractions[name]
                timings[name] = Timing(max(latency, by_name[name].min_period_ms), latency)
                threads[name] = 1
    scale = bound_scale(problem, timings)
    warnings = []
    if not first.optimal:  # Stage I's own bound scale is an estimate: the plan's below is what counts
        gap = "unknown" if first.gap is None else f"{first.gap:.2%}"
        warnings.append(f"Stage I stopped at its time limit with a proven optimality gap of {gap}")
    if scale > 1.0 + SCALE_PRECISION:
        warnings.append(
            f"the bounds cannot all be met: every chain bound and rate floor is scaled by {scale:.4g} "
            "(the plan meets the scaled bounds)"
        )
    return _assemble(
        spec=spec,
        problem=problem,
        cores=cores,
        layout=layout,
        timings=timings,
        threads=threads,
        fractions=fractions,
        lengths=lengths,
        scale=scale,
        first=first,
        importance=importance,
        warnings=warnings,
    )


def ordered_layout(layout: Layout, schedule: Schedule, importance: dict[str, float], problem: Problem) -> Layout:
    """Each shared core's subchains in schedule order: the spec's ``order``, then by weight."""
    position = {sub.name: index for index, sub in enumerate(problem.subchains)}
    given = {name: index for index, name in enumerate(schedule.order or [])}

    def key(name: str) -> tuple[int, float, int]:
        if name in given:
            return (0, given[name], 0)
        return (1, -importance[name], position[name])

    shared = tuple(SharedCore(core.core, tuple(sorted(core.subchains, key=key))) for core in layout.shared)
    return Layout(layout.dedicated, shared)


def priorities(problem: Problem, schedule: Schedule, importance: dict[str, float]) -> dict[str, int]:
    """Stealing priority: the spec's, else by weight (the heaviest highest); higher steals from lower."""
    if schedule.priorities:
        return {sub.name: schedule.priorities.get(sub.name, 0) for sub in problem.subchains}
    ranked = sorted(range(len(problem.subchains)), key=lambda i: (-importance[problem.subchains[i].name], i))
    count = len(ranked)
    return {problem.subchains[i].name: count - rank for rank, i in enumerate(ranked)}


def schedule_length(
    core: SharedCore, fractions: dict[str, float], by_name: dict[str, Subchain], schedule: Schedule
) -> float:
    """The shortest ``T`` that fits every slice, the switches and the slack."""
    load = math.fsum(fractions[name] * by_name[name].compute_ms for name in core.subchains)
    return (load + len(core.subchains) * schedule.switch_ms) / (1.0 - schedule.slack)


def _smallest_scale(model: RelaxedStage2, problem: Problem) -> tuple[float, IntegerSolution]:
    """The integer optimum at scale 1, or else at the smallest scale an integer plan can meet."""
    found = solve_integer(model, problem, 1.0)
    if found is not None:
        return 1.0, found
    least = solve_integer(model, problem, least_scale=True)
    if least is None:
        raise InfeasibleError(f"{problem.app}: no schedule exists for the shared cores, whatever the bounds")
    scale = least.objective * (1 + SCALE_PRECISION)
    found = solve_integer(model, problem, scale)
    if found is None:  # pragma: no cover - the least-scale plan itself meets this scale
        raise InfeasibleError(f"{problem.app}: no schedule meets the bounds scaled by {scale:.6g}")
    return scale, found


def _assemble(
    *,
    spec: Spec,
    problem: Problem,
    cores: int,
    layout: Layout,
    timings: dict[str, Timing],
    threads: dict[str, int],
    fractions: dict[str, float],
    lengths: dict[int, float],
    scale: float,
    first: Stage1Result,
    importance: dict[str, float],
    warnings: list[str],
) -> Plan:
    indices = first.allocation.core_indices()
    ranks = priorities(problem, spec.schedule, importance)
    shared = {name for core in layout.shared for name in core.subchains}
    subchains = {
        sub.name: SubchainPlan(
            name=sub.name,
            nodes=sub.nodes,
            cores=indices[sub.name],
            shared=sub.name in shared,
            threads=threads[sub.name],
            period_ms=timings[sub.name].period_ms,
            latency_ms=timings[sub.name].latency_ms,
            fraction=fractions.get(sub.name, 1.0),
            priority=ranks[sub.name],
        )
        for sub in problem.subchains
    }
    chains = []
    for chain in problem.chains:
        metrics = evaluate_chain(problem, chain, timings)
        chains.append(
            ChainPlan(
                chain.nodes,
                tuple(stage.name for stage in chain.stages),
                metrics.latency_ms,
                metrics.period_ms,
                metrics.response_ms,
            )
        )
    return Plan(
        app=problem.app,
        cores=cores,
        objective=objective(problem, timings),
        constraint_scale=scale,
        subchains=subchains,
        shared_cores=tuple(CorePlan(core.core, lengths[core.core], core.subchains) for core in layout.shared),
        chains=tuple(chains),
        stage1=first,
        warnings=tuple(warnings),
    )
