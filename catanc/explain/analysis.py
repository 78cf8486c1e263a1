"""The plan in plain words (``catanc explain``): what runs when, what binds, what to watch.

:func:`explain_plan` is pure data over a spec, its problem and a plan;
:func:`report_blocks` decides, once, what the report says, as neutral
blocks (headings, paragraphs, tables, a preformatted timeline bar, a list);
:func:`render` lays them out as rich renderables for the terminal and
:func:`render_markdown` as GitHub Markdown for a committed ``PLAN.md``
(deterministic, independent of any terminal width).  It reads the plan only through
``plan.subchains`` (cores, shared, fraction, ...), ``plan.shared_cores``
(each shared core's ``T`` and order) and ``plan.chains``, and recomputes
every derived number with :mod:`catanc.core.metrics`:

1. per core, one schedule period: switch, slice ``f * c(S)`` and idle slack
   of each subchain in order, and how often each completes a run (every
   ``n = 1/f`` periods); dedicated cores: subchain, threads, period, load;
2. per subchain and 3. per chain, the plan's numbers;
4. which constraints bind (within :data:`BINDING_TOLERANCE`, relative) and
   which objective terms dominate;
5. warnings: the plan's own, bounds with less than :data:`NEAR_SATURATION`
   headroom (and by how much compute may grow on their cores before they are
   missed, at this schedule), subchains starved at the minimum slice;
6. the spec's baseline under the same model (:mod:`catanc.planning.baseline`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, assert_never

from rich.console import Console, ConsoleOptions, RenderableType, RenderResult
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from catanc.core.metrics import Timing, evaluate_chain
from catanc.core.priorities import ENFORCER_FIFO, RUNNING_FIFO, UNSCHEDULED_FIFO, resting_fifo
from catanc.core.problem import Chain, Executor, Problem, Subchain
from catanc.errors import Diagnostic
from catanc.explain.enforceable import short_slots
from catanc.planning.baseline import BaselineEvaluation, BaselineGap, TermValue, evaluate_baseline, objective_terms
from catanc.planning.order import slot_starts
from catanc.planning.stage1.estimate import Allocation
from catanc.spec.language import Schedule, Spec
from catanc.text import plural

if TYPE_CHECKING:
    from catanc.planning.types import CorePlan, Plan, SubchainPlan
    from catanc.spec.machine import MachineUse

BINDING_TOLERANCE = 1e-6
"""Relative distance at which a constraint counts as binding."""

NEAR_SATURATION = 0.10
"""Headroom below which a bound is warned about."""

ROW_LIMIT = 12
"""Rows shown in the chain and term tables; the rest are summarised in one line."""

BAR_WIDTH = 64
"""Characters in a shared core's timeline bar."""

SLICE_MARKS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


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


@dataclass(frozen=True)
class Binding:
    kind: str  # "rate cap", "rate floor", "fixed rate", "chain bound", "minimum slice", "f <= 1"
    subject: str  # subchain name or chain label
    detail: str


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


# --------------------------------------------------------------------------- analysis


def explain_plan(spec: Spec, problem: Problem, plan: Plan, machine: MachineUse | None = None) -> Explanation:
    """Everything ``catanc explain`` shows about ``plan`` (planned from ``spec`` on ``plan.cores`` cores).

    ``machine``: the profile ``spec``'s schedule costs were raised with, if any.
    """
    by_name = {sub.name: sub for sub in problem.subchains}
    timings = plan_timings(plan)
    responses = [evaluate_chain(problem, chain, timings).response_ms for chain in problem.chains]
    terms = objective_terms(problem, responses, lambda term: timings[term.subchain].period_ms)
    headrooms = tuple(_headrooms(plan, problem, spec.schedule))
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
            *([] if machine is not None else [found.warning for found in short_slots(plan, spec.schedule)]),
        ),
        baseline=evaluate_baseline(spec, problem, plan.cores),
        allocation=allocation_note(plan),
        executors=tuple(executor_note(executor, plan, problem) for executor in problem.executors),
        machine=machine.sentence() if machine is not None else None,
        unscheduled=tuple(name for name, node in spec.nodes.items() if not node.scheduled),
    )


def spec_warning(diagnostic: Diagnostic) -> str:
    """A spec's warning in the report: what stderr says after ``warning:``, and the spec's line (not its path)."""
    what = f"{diagnostic.field}: " if diagnostic.field else ""
    line = f" (spec line {diagnostic.location.line})" if diagnostic.location is not None else ""
    return f"{what}{diagnostic.message}{line}"


def executor_note(executor: Executor, plan: Plan, problem: Problem) -> str:
    """Where an executor's nodes run: one thread, so one core set and never at once.

    Across subchains on a shared core, a run can wait for the other nodes' runs to end: their
    compute, in wall time at about the executor's share of the core (its subchains' slices over
    ``T``; it may also take idle time of other slots).  The slot model's latencies do not count
    that wait, so the note says how long it can be.
    """
    nodes = ", ".join(executor.nodes)
    subs = executor.subchains
    cores = sorted({core for name in subs for core in plan.subchains[name].cores})
    where = _cores_text(cores)
    if len(subs) == 1:
        how = f"in subchain {subs[0]} on {where}: its period covers their compute added up"
        return f"Executor {executor.name} runs {nodes} in one thread (never at once): {how}."
    how = f"subchains {', '.join(subs)} share {where}, one slot after the other"
    period = next((core.period_ms for core in plan.shared_cores if core.core in cores), None)
    if period is None:
        return f"Executor {executor.name} runs {nodes} in one thread (never at once): {how}."
    share = math.fsum(plan.subchains[name].fraction * problem.subchain(name).compute_ms for name in subs) / period
    compute = {
        node: c
        for name in subs
        for node, c in zip(problem.subchain(name).nodes, problem.subchain(name).node_compute_ms, strict=True)
    }
    waits = {node: math.fsum(compute[other] for other in executor.nodes if other != node) for node in executor.nodes}
    node = max(executor.nodes, key=lambda n: (waits[n], -executor.nodes.index(n)))
    behind = ", ".join(other for other in executor.nodes if other != node)
    wall = waits[node] / min(share, 1.0)
    return (
        f"Executor {executor.name} runs {nodes} in one thread (never at once): {how}; a run may wait for "
        f"the others' to end, about {wall:.1f} ms for {node} behind {behind} ({waits[node]:.3g} ms of compute at "
        f"the executor's {share:.0%} of the core), which the plan's latencies do not count."
    )


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
    before = comparison.two_stage_objective
    if before is None:
        versus = "Stage I's allocation cannot meet the bounds as well"
    else:
        lower = (before - plan.objective) / before if before else 0.0
        versus = f"{plan.objective:.3f} ms against {before:.3f} ms, {lower:.1%} lower"
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


def _hz(period_ms: float) -> str:
    return f"{1000.0 / period_ms:.4g} Hz"


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
                found.append(Binding("fixed rate", sub.name, f"runs at exactly {_hz(sub.min_period_ms)}"))
        else:
            held = chosen.every is not None and chosen.every > (runs_per_period(chosen, sub.batch) or 1)
            if capped:
                found.append(Binding("rate cap", sub.name, f"period {period:.3f} ms = its cap of {_hz(period)}"))
            elif held:  # aligned with the slots: every k periods, the first multiple of T at or above the cap
                found.append(
                    Binding(
                        "rate cap",
                        sub.name,
                        f"period {period:.3f} ms = {chosen.every} periods, the fewest at or above its cap of "
                        f"{_hz(sub.min_period_ms)}",
                    )
                )
            if floored:
                scaled = "" if scale == 1.0 else f" (scaled by {scale:.4g})"
                found.append(
                    Binding("rate floor", sub.name, f"period {period:.3f} ms = its floor of {_hz(period)}{scaled}")
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


# --------------------------------------------------------------------------- headroom


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


def _headrooms(plan: Plan, problem: Problem, schedule: Schedule) -> list[Headroom]:
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
            f"{sub.name}'s fixed rate ({_hz(sub.max_period_ms)})"
            if fixed
            else f"{sub.name}'s rate floor (>= {_hz(limit)})"
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


def _cores_text(cores: Sequence[int]) -> str:
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
            else f"; compute times on {_cores_text(item.cores)} may grow {item.growth:.1%} before it is missed"
        )
        notes.append(
            f"core near saturation: {item.what} has {item.headroom:.1%} headroom on {_cores_text(item.cores)} "
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
            f"of its {sub.compute_ms:.3g} ms per period on {_cores_text(chosen.cores)}): {every}, "
            f"{1000.0 / chosen.period_ms:.4g} Hz"
        )
    return notes


# --------------------------------------------------------------------------- report blocks

Align = Literal["left", "right"]


@dataclass(frozen=True)
class Heading:
    """A numbered section's title ("2. Subchains")."""

    text: str


@dataclass(frozen=True)
class Paragraph:
    """One paragraph of prose; ``strong`` for the report's opening line."""

    text: str
    strong: bool = False


@dataclass(frozen=True)
class Preformatted:
    """A line whose spacing carries meaning (a timeline bar): shown verbatim, in Markdown in a code block."""

    text: str


@dataclass(frozen=True)
class Bullets:
    """A list of notes (the warnings)."""

    items: tuple[str, ...]


@dataclass(frozen=True)
class Column:
    header: str
    align: Align = "left"


@dataclass(frozen=True)
class TableBlock:
    """A table: an optional title above it, one cell per column in every row, an optional note below it."""

    columns: tuple[Column, ...]
    rows: tuple[tuple[str, ...], ...]
    title: str | None = None
    footer: str | None = None

    def __post_init__(self) -> None:
        for row in self.rows:
            if len(row) != len(self.columns):
                raise ValueError(f"a row of {len(row)} cells in a table of {len(self.columns)} columns: {row}")


Block = Heading | Paragraph | Preformatted | Bullets | TableBlock
"""One piece of the report, as neutral data: :func:`render` and :func:`render_markdown` only lay it out."""


def _columns(headers: Sequence[str], left: Sequence[str] = ()) -> tuple[Column, ...]:
    """Columns right-aligned (numbers) except those named in ``left``."""
    return tuple(Column(header, "left" if header in left else "right") for header in headers)


# --------------------------------------------------------------------------- rendering


def _ms(value: float) -> str:
    return f"{value:.3f}"


def _rate(period_ms: float) -> str:
    return f"{1000.0 / period_ms:.2f}"


def _share(part: float, whole: float) -> str:
    return f"{part / whole:.1%}" if whole > 0 else "-"


def timeline_bar(view: SharedCoreView, width: int = BAR_WIDTH) -> str:
    """A proportional bar of one period: a letter per subchain's slice, ``|`` switches, ``.`` idle.

    Every slice and a non-empty idle gap get at least one character, so a
    1 ms slice in a 700 ms period still shows.
    """
    total = view.period_ms
    marks = {name: SLICE_MARKS[index % len(SLICE_MARKS)] for index, name in enumerate(view.order)}
    exact = [segment.length_ms / total * width if total > 0 else 0.0 for segment in view.segments]
    counts = [math.floor(x) for x in exact]
    for index in sorted(range(len(exact)), key=lambda i: (-(exact[i] - counts[i]), i)):
        if sum(counts) >= width:
            break
        counts[index] += 1
    for index, segment in enumerate(view.segments):
        if segment.kind != "switch" and segment.length_ms > 0 and counts[index] == 0:
            counts[index] = 1
    while sum(counts) > width:
        largest = max(range(len(counts)), key=lambda i: (counts[i], -i))
        counts[largest] -= 1
    chars = []
    for segment, count in zip(view.segments, counts, strict=True):
        if segment.kind == "switch":
            mark = "|"
        elif segment.kind == "idle":
            mark = "."
        else:
            assert segment.subchain is not None
            mark = marks[segment.subchain]
        chars.append(mark * count)
    return "".join(chars)


def _runs_text(sub: SubchainPlan, batch: bool, length: float) -> str:
    runs = runs_per_period(sub, batch)
    if runs == 1:
        text = "a whole run every period"
    elif runs is not None:
        text = f"one run every {runs} periods ({runs * length:.3f} ms)"
    elif sub.fraction >= 1:
        text = f"{sub.fraction:.3g} runs per period"
    else:
        text = f"one run every {1.0 / sub.fraction:.3g} periods on average"
    if sub.every is not None and sub.every > (runs or 1):
        text += f"; triggered at its slot every {sub.every} periods ({sub.period_ms:.3f} ms, rate cap)"
    elif sub.every is not None:
        text += "; triggered at its slot"
    elif sub.period_ms > sub.latency_ms * (1 + BINDING_TOLERANCE):
        text += f"; triggered every {sub.period_ms:.3f} ms on its own clock (rate cap)"
    return text


def _shared_blocks(view: SharedCoreView, explanation: Explanation) -> list[Block]:
    subs = {sub.name: sub for sub in explanation.subchains}
    title = (
        f"core {view.core}: shared by {plural(len(view.order), 'subchain')}, "
        f"schedule period T = {view.period_ms:.3f} ms ({_rate(view.period_ms)} Hz)"
    )
    marks = "  ".join(f"{SLICE_MARKS[i % len(SLICE_MARKS)]} {name}" for i, name in enumerate(view.order))
    rows = []
    for segment in view.segments:
        if segment.kind == "switch":
            if segment.length_ms <= 0:
                continue
            what, often = f"switch to {segment.subchain}", ""
        elif segment.kind == "idle":
            what, often = f"idle (slack {explanation.schedule.slack:.0%} of T)", ""
        else:
            assert segment.subchain is not None
            sub = subs[segment.subchain]
            what = f"{segment.subchain}: slice f*c = {sub.fraction:.4g} x {explanation.compute_ms[sub.name]:.3f} ms"
            often = _runs_text(sub, sub.name in explanation.batch, view.period_ms)
        rows.append(
            (_ms(segment.offset_ms), _ms(segment.length_ms), _share(segment.length_ms, view.period_ms), what, often)
        )
    columns = _columns(("offset ms", "length ms", "share of T", "what", "how often"), left=("what", "how often"))
    blocks: list[Block] = [
        TableBlock(columns, tuple(rows), title=title),
        Preformatted(f"{timeline_bar(view)}\n{marks}; | switch, . idle"),
    ]
    if len(view.order) > 1:
        ranked = sorted(view.order, key=lambda name: (-subs[name].priority, name))
        blocks.append(
            Paragraph(
                f"Stealing order: {' > '.join(ranked)} (a subchain that is late takes the slice of one after it)."
            )
        )
    return blocks


def _dedicated_line(view: DedicatedView, explanation: Explanation) -> Paragraph:
    sub = next(s for s in explanation.subchains if s.name == view.subchain)
    cores = len(view.cores)
    load = sub.latency_ms / sub.period_ms
    spread = f", {load * sub.threads / cores:.0%} of its {cores} cores" if cores > 1 else ""
    return Paragraph(
        f"{_cores_text(view.cores)}: dedicated to {sub.name}, {plural(sub.threads, 'thread')}, "
        f"period {sub.period_ms:.3f} ms ({_rate(sub.period_ms)} Hz), latency {sub.latency_ms:.3f} ms: "
        f"busy {load:.0%} (latency/period){spread}, {explanation.schedule.slack:.0%} slack kept idle"
    )


def _subchain_table(explanation: Explanation) -> TableBlock:
    columns = (
        "subchain", "nodes", "cores", "how", "rate Hz", "period ms", "fraction", "every k", "slice ms",
        "latency ms",
    )  # fmt: skip
    rows = []
    for sub in explanation.subchains:
        runs = runs_per_period(sub, sub.name in explanation.batch)
        fraction = f"1/{runs}" if runs is not None and runs > 1 else f"{sub.fraction:.4g}"
        slice_ms = _ms(sub.fraction * explanation.compute_ms[sub.name]) if sub.shared else "-"
        rows.append(
            (
                sub.name,
                " -> ".join(sub.nodes),
                ",".join(str(c) for c in sub.cores) or "-",
                f"{'shared' if sub.shared else 'dedicated'}, FIFO {fifo_levels(sub.shared)}",
                _rate(sub.period_ms),
                _ms(sub.period_ms),
                fraction,
                "-" if sub.every is None else str(sub.every),
                slice_ms,
                _ms(sub.latency_ms),
            )
        )
    unscheduled = explanation.unscheduled
    own_clock = f" Unscheduled nodes ({', '.join(unscheduled)}): {UNSCHEDULED_FIFO}." if unscheduled else ""
    footer = (
        "FIFO: the SCHED_FIFO level of a subchain's threads as deployed: at rest (launch.sh sets it) -> in its "
        f"slice (catanc run raises it).{own_clock} catanc run's own threads: {ENFORCER_FIFO}."
    )
    return TableBlock(_columns(columns, left=("subchain", "nodes", "how")), tuple(rows), footer=footer)


def fifo_levels(shared: bool) -> str:
    """The SCHED_FIFO levels of a subchain's threads as the deployment applies them (catan-model.md section 6)."""
    rest = resting_fifo(shared)
    return f"{rest}->{RUNNING_FIFO}" if rest != RUNNING_FIFO else str(rest)


def _chain_table(explanation: Explanation) -> TableBlock:
    chains = explanation.chains
    columns = ("chain", "subchains", "weight", "bound ms", "latency ms", "period ms", "response ms")
    rows = tuple(
        (
            " -> ".join(view.nodes),
            " -> ".join(view.stages) or "-",
            f"{view.weight:g}" if view.weight > 0 else "-",
            f"{view.bound_ms:g}" if view.bound_ms is not None else "-",
            _ms(view.latency_ms),
            _ms(view.period_ms),
            _ms(view.response_ms),
        )
        for view in chains[:ROW_LIMIT]
    )
    footer = None
    if len(chains) > ROW_LIMIT:
        rest = chains[ROW_LIMIT:]
        weighted = math.fsum(view.weight * view.response_ms for view in rest)
        share = _share(weighted, explanation.objective)
        footer = f"... {plural(len(rest), 'more chain')} (together {share} of the objective)"
    return TableBlock(_columns(columns, left=("chain", "subchains")), rows, footer=footer)


def _binding_table(explanation: Explanation) -> Block:
    if not explanation.bindings:
        return Paragraph("Binding constraints: none (every rate and chain bound has room, no slice is at a limit)")
    return TableBlock(
        (Column("constraint"), Column("on"), Column("detail")),
        tuple((item.kind, item.subject, item.detail) for item in explanation.bindings),
        title="Binding constraints",
    )


def _term_table(explanation: Explanation) -> TableBlock:
    terms = sorted(explanation.terms, key=lambda t: -t.contribution)
    total = explanation.objective
    columns = ("term", "spec", "weight", "value ms", "weight x value", "share")
    rows = tuple(
        (
            term.label,
            term.origin,
            f"{term.weight:g}",
            _ms(term.value_ms),
            _ms(term.contribution),
            _share(term.contribution, total),
        )
        for term in terms[:ROW_LIMIT]
    )
    footer = None
    if len(terms) > ROW_LIMIT:
        rest = math.fsum(t.contribution for t in terms[ROW_LIMIT:])
        footer = f"... {plural(len(terms) - ROW_LIMIT, 'more term')} ({_share(rest, total)} of the objective)"
    return TableBlock(
        _columns(columns, left=("term", "spec")), rows, title=f"Objective terms: {total:.3f} ms in all", footer=footer
    )


def _baseline_section(explanation: Explanation) -> list[Block]:
    baseline = explanation.baseline
    if isinstance(baseline, BaselineGap):
        return [Paragraph(f"Baseline: {baseline.reason}; nothing to compare with.")]
    listed = ", ".join(f"{row.node} {row.rate_hz:g} Hz" for row in baseline.nodes.values() if row.rate_hz is not None)
    inherited = ", ".join(f"{row.node} on {row.trigger}" for row in baseline.nodes.values() if row.trigger is not None)
    cores = plural(baseline.cores, "core")
    blocks: list[Block] = [
        Paragraph(
            f"Baseline: the spec's hand-tuned timers ({listed})"
            + (f", the rest on their inputs ({inherited})" if inherited else "")
            + f", CPU shared fairly by Linux over {cores}: utilisation {baseline.utilisation:.1%}, "
            f"latency = compute / (1 - utilisation)."
        ),
    ]
    if baseline.overloaded:
        blocks.append(
            Paragraph(
                f"The baseline is overloaded: its rates ask for {baseline.utilisation:.1%} of {cores}, which Linux "
                f"cannot sustain; every period is stretched x{baseline.stretch:.3f} and latencies are taken "
                f"at 95% utilisation."
            )
        )
    pairs = sorted(
        zip(baseline.terms, explanation.terms, strict=True),
        key=lambda pair: -max(pair[0].contribution, pair[1].contribution),
    )
    rows = [
        (base.label, f"{base.weight:g}", _ms(base.value_ms), _ms(mine.value_ms), _ratio(base.value_ms, mine.value_ms))
        for base, mine in pairs[:ROW_LIMIT]
    ]
    if len(pairs) > ROW_LIMIT:
        rows.append((f"... {plural(len(pairs) - ROW_LIMIT, 'more term')}", "", "", "", ""))
    rows.append(
        (
            "objective (weighted sum)",
            "",
            _ms(baseline.objective),
            _ms(explanation.objective),
            _ratio(baseline.objective, explanation.objective),
        )
    )
    columns = _columns(("term", "weight", "baseline ms", "plan ms", "baseline / plan"), left=("term",))
    blocks.append(TableBlock(columns, tuple(rows), title="Baseline versus plan (same model)"))
    return blocks


def _ratio(base: float, mine: float) -> str:
    return f"{base / mine:.2f}x" if mine > 0 else "-"


def report_blocks(explanation: Explanation) -> list[Block]:
    """The whole report, in reading order, as blocks: the one place that decides what it says."""
    scale = (
        "every bound as written"
        if explanation.constraint_scale == 1.0
        else f"every bound scaled by {explanation.constraint_scale:.4g}"
    )
    cores = plural(explanation.cores, "core")
    blocks: list[Block] = [
        Paragraph(f"{explanation.app} on {cores}: objective {explanation.objective:.3f} ms, {scale}.", strong=True),
        Paragraph(explanation.allocation),
        *(Paragraph(note) for note in explanation.executors),
        *([Paragraph(explanation.machine)] if explanation.machine else []),
        Heading("1. Cores: one schedule period each"),
    ]
    for view in explanation.shared:
        blocks += _shared_blocks(view, explanation)
    blocks += [_dedicated_line(view, explanation) for view in explanation.dedicated]
    blocks += [Paragraph(f"core {core}: idle (no subchain runs here)") for core in explanation.idle_cores]
    blocks += [Heading("2. Subchains"), _subchain_table(explanation)]
    count = len(explanation.chains)
    chains = f"3. Chains ({count}, the most weighted first)" if count > 1 else f"3. Chains ({count})"
    blocks += [Heading(chains), _chain_table(explanation)]
    blocks += [Heading("4. What binds and what dominates"), _binding_table(explanation), _term_table(explanation)]
    blocks.append(Heading("5. Warnings"))
    blocks.append(Bullets(explanation.warnings) if explanation.warnings else Paragraph("none"))
    blocks.append(Heading("6. Baseline"))
    blocks += _baseline_section(explanation)
    return blocks


# --------------------------------------------------------------------------- renderers


def _rich_parts(block: Block) -> list[RenderableType]:
    """One block for a terminal: a blank line before each section, tables boxed, notes indented."""
    if isinstance(block, Heading):
        return [Text(""), Text(block.text, style="bold")]
    if isinstance(block, Paragraph):
        return [Text(block.text, style="bold" if block.strong else "")]
    if isinstance(block, Preformatted):
        return [Text("\n".join(f"  {line}" for line in block.text.splitlines()))]
    if isinstance(block, Bullets):
        return [Text(f"- {item}") for item in block.items]
    if isinstance(block, TableBlock):
        table = FittedTable(block)
        return [table] if block.footer is None else [table, Text(f"  {block.footer}")]
    assert_never(block)


UNBOUNDED_WIDTH = 10_000
"""Room enough to measure the narrowest a table can be without cutting a word."""


@dataclass(frozen=True)
class FittedTable:
    """A table that fits the width it is given: one-line headers, or each header word on its own line if
    one-line headers would cut words short or if stacking them takes fewer lines (the text wraps less).

    Number columns are never wrapped or cut; text columns (names, chains, notes) wrap to fit.
    """

    block: TableBlock

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        flat, stacked = self._table(stacked=False), self._table(stacked=True)
        narrowest = Measurement.get(console, options.update_width(UNBOUNDED_WIDTH), flat).minimum
        if narrowest > options.max_width:  # one-line headers would cut words short
            yield stacked
        elif len(console.render_lines(stacked, options)) < len(console.render_lines(flat, options)):
            yield stacked  # taller headers, but the text wraps less: fewer lines in all
        else:
            yield flat

    def _table(self, *, stacked: bool) -> Table:
        block = self.block
        table = Table(title=block.title, title_justify="left")
        for index, column in enumerate(block.columns):
            if column.align == "right":
                header = column.header.replace(" ", "\n") if stacked else column.header
                widest = max((len(row[index]) for row in block.rows), default=0)
                table.add_column(header, justify="right", no_wrap=True, min_width=widest)
            else:
                table.add_column(column.header, justify="left")
        for row in block.rows:
            table.add_row(*row)
        return table


def render(explanation: Explanation) -> list[RenderableType]:
    """The explanation as rich renderables, in reading order."""
    return [part for block in report_blocks(explanation) for part in _rich_parts(block)]


_MARKDOWN_INLINE = re.compile(
    r"[\\`*]"  # escapes, code spans, emphasis
    r"|(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])"  # emphasis (an underscore inside a word is not)
    r"|\](?=[(\[:])"  # links: inline, reference, definition
    r"|<(?=[A-Za-z/!?])|&(?=#?\w+;)"  # HTML tags, entities
)
_MARKDOWN_BLOCK_START = re.compile(r"^(?:[#>+-]|\d+[.)])")


def _markdown_inline(text: str) -> str:
    """``text`` as literal Markdown on one line, for a heading or a table cell.

    Backslash-escapes only what could start markup, so that the file reads
    well raw: ``face_tracking``, ``objective[2]`` and ``f <= 1`` stay as
    they are.
    """
    return _MARKDOWN_INLINE.sub(lambda match: "\\" + match.group(0), " ".join(text.splitlines()).strip())


def _markdown_text(text: str) -> str:
    """``text`` as a literal paragraph or list item: also not a heading, quote, list or rule."""
    return _MARKDOWN_BLOCK_START.sub(
        lambda match: match.group(0)[:-1] + "\\" + match.group(0)[-1], _markdown_inline(text)
    )


def _markdown_cell(text: str) -> str:
    return _markdown_inline(text).replace("|", "\\|")


def _markdown_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _markdown_lines(block: Block) -> list[str]:
    """One block as GitHub Markdown lines (no blank line before or after it)."""
    if isinstance(block, Heading):
        return [f"## {_markdown_inline(block.text)}"]
    if isinstance(block, Paragraph):
        text = _markdown_text(block.text)
        return [f"**{text}**" if block.strong and text else text]
    if isinstance(block, Preformatted):
        lines = [line.rstrip() for line in block.text.splitlines()]
        ticks = max((len(run) for run in re.findall(r"`+", block.text)), default=0)
        fence = "`" * max(3, ticks + 1)
        return [fence, *lines, fence]
    if isinstance(block, Bullets):
        return [f"- {_markdown_text(item)}" for item in block.items]
    if isinstance(block, TableBlock):
        lines = [] if block.title is None else [f"**{_markdown_inline(block.title)}**", ""]
        lines.append(_markdown_row([_markdown_cell(column.header) for column in block.columns]))
        lines.append(_markdown_row(["---:" if column.align == "right" else "---" for column in block.columns]))
        lines += [_markdown_row([_markdown_cell(cell) for cell in row]) for row in block.rows]
        if block.footer is not None:
            lines += ["", _markdown_text(block.footer)]
        return lines
    assert_never(block)


def blocks_markdown(blocks: Sequence[Block]) -> str:
    """Blocks as one Markdown document: a blank line between blocks, ``\\n`` endings, one final newline."""
    chunks = ["\n".join(lines) for lines in map(_markdown_lines, blocks) if any(lines)]
    return "\n\n".join(chunks) + "\n"


def render_markdown(explanation: Explanation) -> str:
    """The same report as :func:`render`, as GitHub Markdown (for a committed ``PLAN.md``); no file header."""
    return blocks_markdown(report_blocks(explanation))
