"""Stage II for one allocation: dedicated timings, then the shared cores' integer schedule.

- Dedicated subchains: Eq. 1's period and threads, then their rate cap
  (:func:`catanc.model.metrics.capped_dedicated`); no solver.
- Shared cores: the exact integer optimum over whole runs ``n_i = 1/f_i``
  (:func:`catanc.planning.stage2.integer.solve_integer`) with soft bounds: at scale 1
  if any integer plan meets them, else at the smallest scale one can meet.

Where an executor's nodes head subchains on one shared core, the members' ``k`` are then
traded against the triggers its thread loses (:mod:`catanc.planning.stage2.turns`), and results
are ranked by the objective as run (:attr:`Stage2Result.as_run`).

Every number of the result is re-derived from the schedule itself (``T``
from the fractions, or the breakpoint ``p_min / k`` the search chose above
it; ``p = k T`` with ``k = max(n, ceil(p_min / T))`` for a non-batch shared
subchain, triggered at its slot every ``k`` periods; ``p = max(T/f, p_min)``
for a batch one) and the objective re-evaluated by :mod:`catanc.model.metrics`, so
a result reports what its schedule would do.

A fixed rate is a rate cap and a rate floor at once: when the bounds are
scaled by ``s``, its floor scales as every rate floor does and its cap
stays, so its period lies in ``[p_fix, s p_fix]`` (never faster than the
spec says).  Two fixed rates on one core that no common ``T`` serves
(``T = p_1 / k_1 = p_2 / k_2`` with both slots fitting) are therefore
planned at the least scale, with a warning naming them (:func:`fixed_rate_conflicts`).

:func:`lower_bound` bounds an allocation's result from below without a
solver, so the planner can skip allocations that cannot win.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

from catanc.errors import InfeasibleError
from catanc.model.metrics import Timing, bound_scale, capped_dedicated, objective
from catanc.model.problem import Problem
from catanc.planning.stage2.base import Layout, Stage2Model, aligned_every, schedule_length
from catanc.planning.stage2.convex import OPEN, Open
from catanc.planning.stage2.integer import Effort, IntegerSolution, closed_form, solve_integer
from catanc.planning.stage2.turns import LayoutTurns
from catanc.spec.language import Schedule

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
    as_run: float  # the objective with the periods executors' threads leave (ms): what plans are ranked by
    relaxations: int  # GP solves it took
    gap: float = 0.0  # proven relative distance to this layout's optimum (0 unless the search was capped)
    every: dict[str, int] = field(default_factory=dict)  # k per non-batch shared subchain: p = k T
    offered: dict[str, float] = field(default_factory=dict)  # the offered period picked per subchain offering some
    # Every subchain's period as run, where the executor trade scored them (None: not scored here)
    periods_as_run: dict[str, float] | None = None


def dedicated_timings(problem: Problem, layout: Layout) -> tuple[dict[str, Timing], dict[str, int]]:
    """Eq. 1 with the rate cap for every dedicated subchain: (timings, threads)."""
    timings: dict[str, Timing] = {}
    threads: dict[str, int] = {}
    for name, cores in layout.dedicated:
        dedicated = capped_dedicated(problem.subchain(name), cores, problem.slack)
        timings[name] = dedicated.timing
        threads[name] = dedicated.threads
    return timings, threads


def lower_bound(problem: Problem, layout: Layout, schedule: Schedule) -> tuple[float, float]:
    """(scale, objective) that no plan of this layout beats, in microseconds of arithmetic.

    A shared subchain's ``T / f_i`` is at least ``(c_i + sum of the others'
    least slices + switches) / (1 - slack)`` when ``f_i <= 1``, and at least
    ``c_i / (1 - slack)`` for a batch subchain (``f_i`` unbounded); the model's
    scale and objective only grow with periods and latencies.  The objective's
    bound is the larger of the objective at those least timings and
    :func:`load_bound`, which weighs each shared core's load as a whole.
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
    return bound_scale(problem, timings), max(
        objective(problem, timings), load_bound(problem, layout, schedule, timings)
    )


@dataclass(frozen=True, slots=True)
class _Member:
    """One shared subchain in :func:`load_bound`: the objective charges ``a l + b max(l, p_min)`` on its
    latency ``l >= least``, and its core's load ``load / l``."""

    load: float
    least: float
    p_min: float
    a: float
    b: float

    def best_latency(self, price: float) -> float:
        """The ``l >= least`` minimising ``a l + b max(l, p_min) + price load / l`` (convex in ``l``)."""
        if self.p_min <= self.least:
            return _toward(self.a + self.b, price * self.load, self.least, math.inf)
        below = _toward(self.a, price * self.load, self.least, self.p_min)
        return below if below < self.p_min else _toward(self.a + self.b, price * self.load, self.p_min, math.inf)


def _toward(slope: float, pull: float, low: float, high: float) -> float:
    """The minimiser of ``slope l + pull / l`` on ``[low, high]``."""
    if slope <= 0.0:
        return high
    return min(max(math.sqrt(pull / slope), low), high)


def load_bound(problem: Problem, layout: Layout, schedule: Schedule, least: dict[str, Timing]) -> float:
    """A Lagrangian lower bound on the objective: each shared core's load ``sum c_i / l_i <= 1 - slack``
    priced by a multiplier instead of each subchain's cheapest latency alone (``least``).

    Relaxed: a chain's longest period counts one stage's (the longest in ``least``) or its floor;
    the switches (``n s / T``) are charged to one non-batch member (``T <= l`` when ``f <= 1``);
    minimum slices are dropped.  The objective is then separable: every subchain's best latency
    for a price has a closed form, and every price gives a bound (the price is sought by a few
    fixed-point steps; the bound holds whether or not they converge).
    """
    shared = {name for core in layout.shared for name in core.subchains}
    latency_weight = dict.fromkeys(shared, 0.0)
    period_weight = dict.fromkeys(shared, 0.0)
    constant = 0.0
    for term in problem.response_terms:
        form, weight = problem.chain_forms[term.chain], term.weight
        constant += weight * form.constant
        for name in form.latency_of:
            if name in shared:
                latency_weight[name] += weight
            else:
                constant += weight * least[name].latency_ms
        longest = max(form.longest_of, key=lambda name: least[name].period_ms, default=None)
        periods = list(form.period_of)
        if longest is None or form.floor >= least[longest].period_ms:
            constant += weight * form.floor
        else:
            periods.append(longest)
        for name in periods:
            if name in shared:
                period_weight[name] += weight
            else:
                constant += weight * least[name].period_ms
    for period_term in problem.period_terms:
        if period_term.subchain in shared:
            period_weight[period_term.subchain] += period_term.weight
        else:
            constant += period_term.weight * least[period_term.subchain].period_ms
    usable = 1.0 - schedule.slack
    total = constant
    for core in layout.shared:
        subs = [problem.subchain(name) for name in core.subchains]
        load = {sub.name: sub.compute_ms for sub in subs}
        unbatched = [sub.name for sub in subs if not sub.batch]
        if unbatched:  # the member the switches are charged to: the one a price shortens most
            charged = max(unbatched, key=lambda name: (latency_weight[name] + period_weight[name]) / load[name])
            load[charged] += len(subs) * schedule.switch_ms
        members = [
            _Member(load[sub.name], least[sub.name].latency_ms, sub.min_period_ms,
                    latency_weight[sub.name], period_weight[sub.name])
            for sub in subs
        ]  # fmt: skip
        total += _priced_core(members, usable)
    return total


def _priced_core(members: list[_Member], usable: float) -> float:
    """``max over price >= 0`` of ``sum_i min_l [a l + b max(l, p_min) + price c / l] - price * usable``, nearly."""

    def at(price: float) -> tuple[float, float, float]:
        """At the members' best latencies for ``price``: the dual's value, the load of the members held
        at an edge (``least``, ``p_min``, or no pull), and ``sum sqrt(c slope)`` over the others."""
        values = []
        fixed = interior = 0.0
        for member in members:
            latency = member.best_latency(price)
            if math.isinf(latency):  # only where a + b = 0: nothing charged, no load
                values.append(0.0)
                continue
            p_min, load = member.p_min, member.load
            values.append(member.a * latency + member.b * max(latency, p_min) + price * load / latency)
            slope = member.a if latency < p_min else member.a + member.b
            if latency in (member.least, p_min) or slope <= 0.0:
                fixed += load / latency
            else:
                interior += math.sqrt(load * slope)
        return math.fsum(values) - price * usable, fixed, interior

    best = at(0.0)[0]
    price = (math.fsum(math.sqrt(m.load * (m.a + m.b)) for m in members) / usable) ** 2
    for _ in range(8):  # where the load at the best latencies meets the core: sqrt(price) = S / (usable - C)
        if price <= 0.0:
            break
        value, fixed, interior = at(price)
        best = max(best, value)
        if interior <= 0.0 or fixed >= usable:
            break
        following = (interior / (usable - fixed)) ** 2
        if abs(following - price) <= 1e-12 * price:
            break
        price = following
    return best


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
    spacing: dict[str, int] | None = None,
) -> Stage2Result | None:
    """The best integer plan for ``layout``, or None if it cannot beat ``beat`` = (scale, objective).

    ``model`` is the layout's relaxation, built beforehand (None when no core
    is shared) and loaded with ``problem``'s compute times here.  Raises
    :class:`InfeasibleError` when no schedule exists whatever the bounds.
    ``gap`` accepts an integer plan proven within that relative distance of
    the optimum (:func:`~catanc.planning.stage2.integer.solve_integer`; 0: exact);
    ``node_limit`` caps its relaxations (the result then says its ``gap``);
    ``effort`` counts them, whatever the outcome.
    ``fixed`` = (runs, scale) skips the search: the plan with those runs
    (None if they miss the bounds so scaled); the planner's model of record
    re-solves the winner so.  ``spacing``: a re-solve's last trigger spacing,
    where the executor trade starts its search (the same answer, sooner).
    Subchains whose driver offers rates get each of them in turn (:func:`_best_offered`).
    """
    if problem.offered():
        options = {"start": start, "gap": gap, "node_limit": node_limit, "fixed": fixed, "spacing": spacing}
        return _best_offered(problem, layout, schedule, model, beat=beat, effort=effort, **options)
    timings, threads = dedicated_timings(problem, layout)
    fractions: dict[str, float] = {}
    runs: dict[str, int] = {}
    every: dict[str, int] = {}
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
            length = schedule_length(core, fractions, by_name, schedule)
            if any(name in runs and by_name[name].min_period_ms > 0 for name in core.subchains):
                length = max(length, solution.solution.core_period_ms[core.core])  # a breakpoint p_min / k
            lengths[core.core] = length
            for name in core.subchains:
                sub = by_name[name]
                threads[name] = 1
                if name not in runs:  # batch: an average period, on its own clock
                    latency = length / fractions[name]
                    timings[name] = Timing(max(latency, sub.min_period_ms), latency)
                    continue
                every[name] = aligned_every(runs[name], length, sub.min_period_ms)
                timings[name] = Timing(every[name] * length, runs[name] * length)
    turns = LayoutTurns.of(problem, layout, schedule) if layout.shared and problem.weighted else None
    as_run = periods_as_run = None
    if turns is not None:
        scale = max(1.0, bound_scale(problem, timings)) * (1 + SCALE_PRECISION)
        lengths_of = {name: lengths[core.core] for core in layout.shared for name in core.subchains}
        traded = turns.best_spacing(problem, timings, lengths_of, every, scale, hint=spacing)
        if traded is not None:
            as_run, every, periods_as_run = traded
            for name in turns.members:
                timings[name] = Timing(every[name] * lengths_of[name], timings[name].latency_ms)
    planned = objective(problem, timings)
    result = Stage2Result(
        layout=layout,
        timings=timings,
        threads=threads,
        fractions=fractions,
        runs=runs,
        lengths=lengths,
        scale=max(1.0, bound_scale(problem, timings)),
        objective=planned,
        as_run=planned if as_run is None else as_run,
        relaxations=relaxations,
        gap=search_gap,
        every=every,
        periods_as_run=periods_as_run,
    )
    if beat is not None and not better(result, beat):
        return None
    return result


def _best_offered(
    problem: Problem,
    layout: Layout,
    schedule: Schedule,
    model: Stage2Model | None,
    *,
    beat: tuple[float, float] | None,
    effort: Effort | None,
    **options: Any,
) -> Stage2Result | None:
    """The best plan over every combination of offered rates, each planned as fixed rates.

    Exact by enumeration: the offered rates are few (a camera's modes), and each combination is the
    fixed-rate problem the search solves exactly.  Ties go to the first combination, the faster
    rates first.  A shared layout gets a model per combination: its rate bounds are built in.
    """
    offered = problem.offered()  # their combinations are few: the spec's check caps them
    best: Stage2Result | None = None
    infeasible = 0
    for periods in itertools.product(*(sub.offered_periods_ms for sub in offered)):
        chosen = {sub.name: period for sub, period in zip(offered, periods, strict=True)}
        fixed_problem = problem.choosing(chosen)
        fixed_model = None if model is None else type(model)(fixed_problem, layout, schedule)  # type: ignore[call-arg]
        target = beat if best is None else (best.scale, best.as_run)
        try:
            found = solve_layout(fixed_problem, layout, schedule, fixed_model, beat=target, effort=effort, **options)
        except InfeasibleError:
            infeasible += 1
            continue
        if found is not None:
            best = dataclasses.replace(found, offered=chosen)
    if infeasible == math.prod(len(sub.offered_hz) for sub in offered):
        raise InfeasibleError(f"{problem.app}: no schedule exists for the shared cores, whatever the bounds")
    return best


def fixed_rate_conflicts(problem: Problem, result: Stage2Result) -> list[str]:
    """A warning per shared core where a fixed rate is not met: the core's fixed rates, as planned.

    A shared core's triggers are aligned with its schedule period, so fixed rates on one core need
    a common ``T = p_1 / k_1 = p_2 / k_2`` that the slots fit in; where there is none, the plan
    meets them only with the bounds scaled (a fixed rate's floor scales, its cap does not).
    """
    notes = []
    for core in result.layout.shared:
        fixed = [
            problem.subchain(name)
            for name in core.subchains
            if name in result.runs and problem.subchain(name).min_period_ms == problem.subchain(name).max_period_ms
        ]
        missed = [sub for sub in fixed if result.timings[sub.name].period_ms > sub.min_period_ms * (1 + 1e-6)]
        if not missed:
            continue
        planned = {sub.name: 1000.0 / result.timings[sub.name].period_ms for sub in fixed}
        rates = ", ".join(
            f"{sub.name} {1000.0 / sub.min_period_ms:.4g} Hz (planned {planned[sub.name]:.4g})" for sub in fixed
        )
        what = "cannot share one schedule period" if len(fixed) > 1 else "cannot be met"
        notes.append(
            f"fixed rates on core {core.core} {what} (T = period / k for each, with every slot fitting): {rates}"
        )
    return notes


def better(result: Stage2Result, than: tuple[float, float]) -> bool:
    """Lexicographic: a smaller bound scale first, then a smaller objective as run (both beyond noise)."""
    scale, value = than
    if result.scale < scale * (1 - SCALE_PRECISION):
        return True
    if result.scale > scale * (1 + SCALE_PRECISION):
        return False
    return result.as_run < value - 1e-9 * max(1.0, abs(value))


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

        def floor() -> float:
            return lower_bound(problem, model.layout, model.schedule)[1]

        found = solve_integer(
            model,
            problem,
            1.0,
            cutoff=cutoff,
            start=start,
            gap=gap,
            node_limit=node_limit,
            effort=effort,
            floor=floor if problem.weighted else None,
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


def closed_fixed_plan(model: Stage2Model, runs: dict[str, int], scale: float) -> IntegerSolution | Open | None:
    """The plan with these runs by the exact closed form, where some ``k`` can exceed ``n`` (None: they miss
    the bounds so scaled); OPEN where the model's relaxation gives it. The closed form reads only the
    model's layout and schedule: with it, which model (cvxpy's or the conic one) makes no difference."""
    closed = closed_form(model, model.problem)
    if closed is None or not closed.aligned_matters:
        return OPEN
    found = closed.fixed_runs(runs, scale, least_scale=False)
    if found is None or isinstance(found, Open):
        return found
    return IntegerSolution(dict(runs), found, found.objective, root_bound=found.objective, nodes=0)


def _fixed_plan(model: Stage2Model, runs: dict[str, int], scale: float) -> IntegerSolution | None:
    """The plan with these runs: the model's relaxation, or the exact closed form where some ``k`` can exceed
    ``n`` (the relaxation then leaves ``k`` continuous: a bound, not a plan)."""
    closed = closed_fixed_plan(model, runs, scale)
    if not isinstance(closed, Open):
        return closed
    model.set_box({name: (n, n) for name, n in runs.items()})
    solution = model.solve(scale)
    if solution is None:
        return None
    return IntegerSolution(dict(runs), solution, solution.objective, root_bound=solution.objective, nodes=1)
