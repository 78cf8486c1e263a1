"""The plan in plain words (``catanc explain``, PLAN.md): the analysis, as data.

:func:`explain_plan` is pure data over a spec, its problem and a plan: an
:class:`Explanation`.  What the report says about it is decided once, as
neutral blocks, by :mod:`catanc.explain.blocks`; :mod:`catanc.explain.terminal`
lays them out for a terminal (rich) and :mod:`catanc.explain.markdown` as
GitHub Markdown for a committed ``PLAN.md`` (deterministic, independent of any
terminal width).  It reads the plan only through
``plan.subchains`` (cores, shared, fraction, ...), ``plan.shared_cores``
(each shared core's ``T`` and order) and ``plan.chains``, and recomputes
every derived number with :mod:`catanc.model.metrics`:

1. per core, one schedule period: switch, slice ``f * c(S)`` and idle slack
   of each subchain in order, and how often each completes a run (every
   ``n = 1/f`` periods); dedicated cores: subchain, threads, period, load;
2. per subchain and 3. per chain, the plan's numbers;
4. which constraints bind (within :data:`BINDING_TOLERANCE`, relative) and
   which objective terms dominate;
5. warnings: the plan's own, bounds with less than :data:`NEAR_SATURATION`
   headroom (and by how much compute may grow on their cores before they are
   missed, at this schedule: :mod:`catanc.explain.headroom`), subchains
   starved at the minimum slice, executor nodes predicted to lose triggers while
   another node holds their thread (:mod:`catanc.explain.executors`);
6. the spec's baseline under the same model (:mod:`catanc.planning.baseline`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from catanc.errors import Diagnostic
from catanc.explain.enforceable import short_slots
from catanc.explain.executor_caps import cap_offer
from catanc.explain.executors import objective_as_run, plan_turns, rate_warnings
from catanc.explain.headroom import NEAR_SATURATION, Headroom, plan_headrooms
from catanc.explain.processes import ProcessView, process_views
from catanc.model.metrics import Timing, evaluate_chain
from catanc.model.problem import Executor, Problem, Subchain
from catanc.planning.baseline import BaselineEvaluation, BaselineGap, TermValue, evaluate_baseline, objective_terms
from catanc.planning.order import slot_starts
from catanc.planning.stage1.estimate import Allocation
from catanc.planning.stage2.base import aligned_every
from catanc.spec.language import Schedule, Spec
from catanc.text import hz

if TYPE_CHECKING:
    from catanc.planning.types import CorePlan, OfferedChoice, Plan, SubchainPlan
    from catanc.spec.machine import MachineUse

BINDING_TOLERANCE = 1e-6
"""Relative distance at which a constraint counts as binding."""


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class Segment:
    """One piece of a shared core's schedule period."""

    kind: Literal["switch", "slice", "idle"]
    subchain: str | None
    offset_ms: float
    length_ms: float


@dataclass(frozen=True)
class SharedCoreView:
    core: int
    period_ms: float  # T
    order: tuple[str, ...]
    segments: tuple[Segment, ...]


@dataclass(frozen=True)
class DedicatedView:
    subchain: str
    cores: tuple[int, ...]


@dataclass(frozen=True)
class ChainView:
    nodes: tuple[str, ...]
    stages: tuple[str, ...]
    latency_ms: float
    period_ms: float
    response_ms: float
    weight: float  # total weight of the response terms on it (0 if none)
    bound_ms: float | None  # tightest bound as written (unscaled), if any


EXECUTOR_SPACING = "executor's thread"
"""A binding's kind where Stage II spaced a subchain's triggers out to free an executor's thread."""


@dataclass(frozen=True)
class Binding:
    kind: str  # "rate cap", "rate floor", "fixed rate", "chain bound", "minimum slice", "f <= 1", EXECUTOR_SPACING
    subject: str  # subchain name or chain label
    detail: str


@dataclass(frozen=True)
class Explanation:
    app: str
    cores: int
    objective: float  # of the plan, recomputed from its timings
    constraint_scale: float
    schedule: Schedule
    shared: tuple[SharedCoreView, ...]
    dedicated: tuple[DedicatedView, ...]
    idle_cores: tuple[int, ...]
    subchains: tuple[SubchainPlan, ...]
    compute_ms: dict[str, float]  # c(S) per subchain
    batch: frozenset[str]
    chains: tuple[ChainView, ...]  # most important first (see chain_views)
    bindings: tuple[Binding, ...]
    terms: tuple[TermValue, ...]  # the plan's terms, in the Problem's order
    headrooms: tuple[Headroom, ...]
    warnings: tuple[str, ...]
    baseline: BaselineEvaluation | BaselineGap
    allocation: str  # how the allocation was chosen, in a sentence
    executors: tuple[str, ...] = ()  # one sentence per executor: its nodes never overlap, and where they run
    machine: str | None = None  # which machine profile the plan's costs came from (compile/explain --machine)
    unscheduled: tuple[str, ...] = ()  # nodes on their own clock (SCHED_FIFO 3)
    offered: tuple[str, ...] = ()  # one sentence per node whose driver offers rates: the one picked, a free one
    processes: tuple[ProcessView, ...] = ()  # the deploy section's processes: cores, level, one executor or not


# --------------------------------------------------------------------------- analysis


def explain_plan(spec: Spec, problem: Problem, plan: Plan, machine: MachineUse | None = None) -> Explanation:
    """Everything ``catanc explain`` shows about ``plan`` (planned from ``spec`` on ``plan.cores`` cores).

    ``machine``: the profile ``spec``'s schedule costs were raised with, if any.
    """
    problem = problem.choosing(plan.offered_periods_ms)  # the offered rates picked are fixed rates
    by_name = {sub.name: sub for sub in problem.subchains}
    timings = plan_timings(plan)
    responses = [evaluate_chain(problem, chain, timings).response_ms for chain in problem.chains]
    terms = objective_terms(problem, responses, lambda term: timings[term.subchain].period_ms)
    headrooms = tuple(plan_headrooms(plan, problem, spec.schedule))
    shared = tuple(
        _shared_view(core, plan, by_name, spec.schedule) for core in sorted(plan.shared_cores, key=lambda c: c.core)
    )
    dedicated = tuple(
        DedicatedView(sub.name, sub.cores) for sub in plan.subchains.values() if not sub.shared and sub.cores
    )
    used = {core for sub in plan.subchains.values() for core in sub.cores}
    return Explanation(
        app=plan.app,
        cores=plan.cores,
        objective=math.fsum(term.contribution for term in terms),
        constraint_scale=plan.constraint_scale,
        schedule=spec.schedule,
        shared=shared,
        dedicated=dedicated,
        idle_cores=tuple(core for core in range(plan.cores) if core not in used),
        subchains=tuple(plan.subchains.values()),
        compute_ms={name: sub.compute_ms for name, sub in by_name.items()},
        batch=frozenset(name for name, sub in by_name.items() if sub.batch),
        chains=chain_views(plan, problem),
        bindings=tuple(bindings(plan, problem, spec.schedule)),
        terms=terms,
        headrooms=headrooms,
        warnings=(
            *(spec_warning(diagnostic) for diagnostic in problem.warnings),
            *plan.warnings,
            *_warnings(plan, problem, spec.schedule, headrooms),
            *rate_warnings(plan, problem, spec.schedule),
            *([] if machine is not None else [found.warning for found in short_slots(plan, spec.schedule)]),
        ),
        baseline=evaluate_baseline(spec, problem, plan.cores),
        allocation=allocation_note(plan),
        executors=tuple(executor_note(executor, spec, problem, plan) for executor in problem.executors),
        offered=tuple(offered_note(choice, plan) for choice in plan.offered),
        machine=machine.sentence() if machine is not None else None,
        unscheduled=tuple(name for name, node in spec.nodes.items() if not node.scheduled),
        processes=process_views(spec, problem, plan),
    )


def spec_warning(diagnostic: Diagnostic) -> str:
    """A spec's warning in the report: what stderr says after ``warning:``, and the spec's line (not its path)."""
    what = f"{diagnostic.field}: " if diagnostic.field else ""
    line = f" (spec line {diagnostic.location.line})" if diagnostic.location is not None else ""
    return f"{what}{diagnostic.message}{line}"


def executor_note(executor: Executor, spec: Spec, problem: Problem, plan: Plan) -> str:
    """Where an executor's nodes run: one thread, so one core set and never at once.

    Across subchains on a shared core, a run can wait for the other nodes' runs to end
    (:mod:`catanc.explain.executors`): the note says how long, at most, for the node that waits
    longest, what the objective becomes with the triggers lost meanwhile, and a rate cap on the
    long node that would run better, if one does (:mod:`catanc.explain.executor_caps`).
    """
    runs = _runs_in_one_thread(executor)
    subs = executor.subchains
    cores = sorted({core for name in subs for core in plan.subchains[name].cores})
    where = cores_text(cores)
    if len(subs) == 1:
        how = f"in subchain {subs[0]} on {where}: its period covers their compute added up"
        return f"{runs}: {how}."
    how = f"subchains {', '.join(subs)} share {where}, one slot after the other"
    turns = plan_turns(executor, plan, problem, spec.schedule)
    if turns is None:
        return f"{runs}: {how}."
    rate = max(turns.rates, key=lambda rate: rate.longest_wait_ms)
    note = (
        f"{runs}: {how}; a run may wait for "
        f"the others' to end, up to about {rate.longest_wait_ms:.1f} ms for {rate.node} behind {rate.blocked_by} "
        f"({turns.member(rate.blocked_by).compute_ms:.3g} ms of compute, at what the slack and the other subchains "
        "leave of the core), which the plan's latencies do not count."
    )
    # The objective as run counts every thread's losses: said once, after the first thread that takes turns.
    taking_turns = [e for e in problem.executors if plan_turns(e, plan, problem, spec.schedule) is not None]
    as_run = objective_as_run(plan, problem, spec.schedule)
    if executor == taking_turns[0] and as_run > plan.objective * (1 + 1e-9):
        whose = "it" if len(taking_turns) == 1 else "the threads of " + ", ".join(e.name for e in taking_turns)
        note += (
            f" With the triggers lost to {whose} counted, the objective as run is about {as_run:.3f} ms, "
            f"{as_run / plan.objective - 1:.1%} above the plan's."
        )
    offer = cap_offer(spec, problem, plan, executor)
    return note if offer is None else f"{note} {offer.sentence}"


def _runs_in_one_thread(executor: Executor) -> str:
    """``Executor mapper runs GL, GM in one thread (never at once)``, and the process that makes it one, if any."""
    nodes = ", ".join(executor.nodes)
    if executor.process is None:
        return f"Executor {executor.name} runs {nodes} in one thread (never at once)"
    what = f"Process {executor.process}" if executor.name == executor.process else f"Executor {executor.name}"
    also = "" if executor.name == executor.process else f", the nodes of process {executor.process}"
    return f"{what} runs {nodes}{also} in one thread (never at once; {executor.why})"


def allocation_text(allocation: Allocation) -> str:
    """``local alone | GL, GM share a core``: who runs where, without core indices."""
    parts = [f"{name} alone" if k == 1 else f"{name} on {k} cores" for name, k in allocation.dedicated]
    parts += [", ".join(group) + " share a core" for group in allocation.groups]
    return " | ".join(parts) or "nothing to run"


def allocation_note(plan: Plan) -> str:
    """Why this allocation: Stage I's estimate, or a runner-up that exact Stage II found better."""
    comparison = plan.comparison
    considered = comparison.allocations
    if considered <= 1:
        return f"Allocation: {allocation_text(plan.allocation)} (Stage I's; no other allocation was planned)."
    if comparison.complete:
        searched = (
            f"best of {considered} allocations planned exactly ({comparison.planned} solved, the rest bounded out)"
        )
    else:
        searched = (
            f"best of the {comparison.planned} most promising of {considered} allocations planned exactly "
            "(the search stops there)"
        )
    if plan.allocation == plan.stage1.allocation:
        return f"Allocation: {allocation_text(plan.allocation)}: Stage I's estimate, confirmed as the {searched}."
    before = comparison.two_stage_objective  # as run, as plans are ranked
    now = plan.objective if plan.objective_as_run is None else plan.objective_as_run
    if before is None:
        versus = "Stage I's allocation cannot meet the bounds as well"
    else:
        lower = (before - now) / before if before else 0.0
        what = "" if now == plan.objective else "objective as run "
        versus = f"{what}{now:.3f} ms against {before:.3f} ms, {lower:.1%} lower"
    return (
        f"Allocation: {allocation_text(plan.allocation)}, the {searched}; Stage I's estimate chose "
        f"{allocation_text(plan.stage1.allocation)} ({versus})."
    )


def plan_timings(plan: Plan) -> dict[str, Timing]:
    return {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in plan.subchains.items()}


def runs_per_period(sub: SubchainPlan, batch: bool) -> int | None:
    """``n = 1/f``, the periods per run of a non-batch shared subchain (None otherwise)."""
    if not sub.shared or batch:
        return None
    return max(1, round(1.0 / sub.fraction))


def _shared_view(core: CorePlan, plan: Plan, by_name: dict[str, Subchain], schedule: Schedule) -> SharedCoreView:
    """One period of a shared core: before each slice the switch to it, after the last the idle slack."""
    slices = {name: plan.subchains[name].fraction * by_name[name].compute_ms for name in core.order}
    starts = slot_starts(core.order, slices, schedule.switch_ms)
    segments = []
    end = 0.0  # of the previous slot: where the switch to the next begins
    for name in core.order:
        segments.append(Segment("switch", name, end, schedule.switch_ms))
        segments.append(Segment("slice", name, starts[name], slices[name]))
        end = starts[name] + slices[name]
    segments.append(Segment("idle", None, end, max(0.0, core.period_ms - end)))
    return SharedCoreView(core.core, core.period_ms, core.order, tuple(segments))


def chain_views(plan: Plan, problem: Problem) -> tuple[ChainView, ...]:
    """Every chain of the plan: weighted or bounded first, by weighted response (largest first)."""
    weights: dict[tuple[str, ...], float] = {}
    for term in problem.response_terms:
        nodes = problem.chains[term.chain].nodes
        weights[nodes] = weights.get(nodes, 0.0) + term.weight
    bounds: dict[tuple[str, ...], float] = {}
    for bound in problem.response_bounds:
        nodes = problem.chains[bound.chain].nodes
        bounds[nodes] = min(bounds.get(nodes, math.inf), bound.max_response_ms)
    views = [
        ChainView(
            nodes=chain.nodes,
            stages=chain.subchains,
            latency_ms=chain.latency_ms,
            period_ms=chain.period_ms,
            response_ms=chain.response_ms,
            weight=weights.get(chain.nodes, 0.0),
            bound_ms=bounds.get(chain.nodes),
        )
        for chain in plan.chains
    ]
    position = {view.nodes: index for index, view in enumerate(views)}

    def key(view: ChainView) -> tuple[int, float, float, int]:
        ranked = view.weight > 0 or view.bound_ms is not None
        tightness = view.response_ms / view.bound_ms if view.bound_ms is not None else 0.0
        return (0 if ranked else 1, -view.weight * view.response_ms, -tightness, position[view.nodes])

    return tuple(sorted(views, key=key))


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= BINDING_TOLERANCE * max(abs(a), abs(b))


def bindings(plan: Plan, problem: Problem, schedule: Schedule) -> list[Binding]:
    """Constraints the plan sits on (within :data:`BINDING_TOLERANCE`, relative)."""
    scale = plan.constraint_scale
    found: list[Binding] = []
    for sub in problem.subchains:
        chosen = plan.subchains[sub.name]
        period = chosen.period_ms
        capped = sub.min_period_ms > 0 and _close(period, sub.min_period_ms)
        floored = sub.max_period_ms < math.inf and _close(period, sub.max_period_ms * scale)
        if sub.min_period_ms > 0 and sub.min_period_ms == sub.max_period_ms:
            if capped or floored:
                found.append(Binding("fixed rate", sub.name, f"runs at exactly {hz(sub.min_period_ms)}"))
        else:
            whole = runs_per_period(chosen, sub.batch) or 1
            every = chosen.every or 0
            held = every > whole
            # Beyond the least k its cap asks for: spaced out by Stage II's trade of an executor's thread.
            spaced = held and every > aligned_every(whole, period / every, sub.min_period_ms)
            if capped:
                found.append(Binding("rate cap", sub.name, f"period {period:.3f} ms = its cap of {hz(period)}"))
            elif spaced:
                found.append(
                    Binding(
                        EXECUTOR_SPACING,
                        sub.name,
                        f"period {period:.3f} ms = {chosen.every} periods, more than its run needs: triggered "
                        "less often, its runs hold the thread it shares with other nodes less of the time",
                    )
                )
            elif held:  # aligned with the slots: every k periods, the first multiple of T at or above the cap
                found.append(
                    Binding(
                        "rate cap",
                        sub.name,
                        f"period {period:.3f} ms = {chosen.every} periods, the fewest at or above its cap of "
                        f"{hz(sub.min_period_ms)}",
                    )
                )
            if floored:
                scaled = "" if scale == 1.0 else f" (scaled by {scale:.4g})"
                found.append(
                    Binding("rate floor", sub.name, f"period {period:.3f} ms = its floor of {hz(period)}{scaled}")
                )
        if not chosen.shared:
            continue
        slice_ms = chosen.fraction * sub.compute_ms
        runs = runs_per_period(chosen, sub.batch)
        if _at_minimum_slice(chosen, sub, schedule):
            if runs is not None:
                detail = f"one run every {runs} periods, the most its {sub.compute_ms:.3g} ms allow"
            else:
                detail = f"{chosen.fraction:.3g} runs per period"
            found.append(
                Binding(
                    "minimum slice",
                    sub.name,
                    f"slice {slice_ms:.3f} ms at the {schedule.min_slice_ms:g} ms floor: {detail}",
                )
            )
        if runs == 1:
            found.append(Binding("f <= 1", sub.name, "a whole run in every period (it would take more if it could)"))
    for bound in problem.response_bounds:
        chain = problem.chains[bound.chain]
        response = evaluate_chain(problem, chain, plan_timings(plan)).response_ms
        limit = bound.max_response_ms * scale
        if _close(response, limit):
            found.append(Binding("chain bound", chain.label, f"response {response:.3f} ms = its bound {limit:.3f} ms"))
    return found


def _at_minimum_slice(chosen: SubchainPlan, sub: Subchain, schedule: Schedule) -> bool:
    """Held at the minimum slice: ``n`` as large as it may be (a batch subchain: ``f*c`` at the floor).

    A subchain that runs whole every period (``n = 1``) is not held there,
    even if a second period per run would break the floor: that is
    ``f <= 1`` binding instead.
    """
    floor = schedule.min_slice_ms
    if not chosen.shared or floor <= 0 or sub.compute_ms <= floor:
        return False
    if sub.batch:
        return _close(chosen.fraction * sub.compute_ms, floor)
    runs = runs_per_period(chosen, batch=False)
    assert runs is not None
    most = math.floor(sub.compute_ms / floor * (1 + BINDING_TOLERANCE))
    return runs > 1 and runs >= most


def cores_text(cores: Sequence[int]) -> str:
    if not cores:
        return "no core"
    return ("core " if len(cores) == 1 else "cores ") + ", ".join(str(c) for c in cores)


def _warnings(plan: Plan, problem: Problem, schedule: Schedule, headrooms: Sequence[Headroom]) -> list[str]:
    notes = []
    for item in headrooms:
        if item.headroom >= NEAR_SATURATION:
            continue
        grow = (
            ""
            if item.growth is None
            else f"; compute times on {cores_text(item.cores)} may grow {item.growth:.1%} before it is missed"
        )
        notes.append(
            f"core near saturation: {item.what} has {item.headroom:.1%} headroom on {cores_text(item.cores)} "
            f"({item.value:.3f} ms against {item.limit:.3f} ms){grow}"
        )
    for sub in problem.subchains:
        chosen = plan.subchains[sub.name]
        if not _at_minimum_slice(chosen, sub, schedule):
            continue
        runs = runs_per_period(chosen, sub.batch)
        every = f"one run every {runs} periods" if runs is not None else f"{chosen.fraction:.3g} runs per period"
        notes.append(
            f"subchain starved: {sub.name} gets only the minimum slice ({chosen.fraction * sub.compute_ms:.3f} ms "
            f"of its {sub.compute_ms:.3g} ms per period on {cores_text(chosen.cores)}): {every}, "
            f"{1000.0 / chosen.period_ms:.4g} Hz"
        )
    return notes


def offered_note(choice: OfferedChoice, plan: Plan) -> str:
    """Which offered rate the plan picked, and what a free rate would have given."""
    offered = ", ".join(f"{rate:g}" for rate in choice.offered_hz)
    picked = f"picked {choice.picked_hz:g} Hz"
    if choice.planned_hz < choice.picked_hz * (1 - 1e-6):
        scaled = f"the bounds scaled by {plan.constraint_scale:.4g}"
        picked += f" (none fits: planned at {choice.planned_hz:.4g} Hz, {scaled})"
    free = f"a free rate would plan {choice.free_hz:.4g} Hz, objective {choice.free_objective:.3f} ms"
    if choice.free_scale > 1.0:
        free += f" with the bounds scaled by {choice.free_scale:.4g}"
    elif plan.constraint_scale <= 1.0 and plan.objective > 0:
        free += f" ({(plan.objective - choice.free_objective) / plan.objective:.1%} lower)"
    return (
        f"{choice.node}'s driver offers {offered} Hz: the plan {picked} for subchain {choice.subchain}, "
        f"objective {plan.objective:.3f} ms; {free}."
    )
