"""Stage II with whole runs: the exact optimum over integer ``n_i = 1/f_i`` (docs/explanation/model.md section 4).

A non-batch subchain on a shared core completes one run every ``n_i``
schedule periods, ``n_i`` a whole number.  The relaxed GP
(:class:`~catanc.planning.stage2.relaxed.RelaxedStage2`) is convex in log space, so
its optimum over a box ``low_i <= n_i <= high_i`` bounds every integer point
in the box: branch and bound on the ``n_i`` with it is exact.  Boxes are
finite because the minimum slice caps ``n_i <= c_i / min_slice``; the search
explores the child holding the relaxed value's nearest integer first and
prunes by the incumbent, which starts as the rounded root relaxation.

Depth first finds a plan within a few dives where the leaves' exact values
are near their relaxations.  Where the rate caps put them far above (whole
trigger counts: Autoware on 2 cores, 1.5%), dives can end in leaves no
better than the cutoff for thousands of relaxations.  Past the node limit
without a plan, the search therefore turns best first: the open box with
the least bound next, its relaxation's rounded point evaluated exactly (a
plan below the cutoff within ~10 boxes there, not ~1,700).  Both orders
are exact; the node limit then stops at the first plan, its gap proven.

(A throwaway prototype of the model rounded floor/ceil and searched
neighbourhoods; that missed the integer optimum by up to 0.95%.)
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

from catanc.model.problem import Problem
from catanc.planning.stage2.base import RelaxedSolution, Stage2Model
from catanc.planning.stage2.convex import OPEN, Open
from catanc.planning.stage2.onebatch import OneBatchRuns
from catanc.planning.stage2.whole import ENUMERATE_UP_TO, WholeRuns
from catanc.spec.language import Schedule

INTEGRAL_TOLERANCE = 1e-6
"""``n`` this close (relatively) to a whole number counts as whole."""

PRUNE_TOLERANCE = 5e-7
"""A box whose bound is within this (relatively) of the incumbent is not explored. It must exceed
the relaxation's own accuracy (Clarabel: ~1e-8): where the objective does not depend on some n_i,
whole boxes tie with the incumbent and a tighter tolerance would explore every one of them (a
subchain in no weighted term took 11,055 relaxations, 50 s). The optimum is exact to this."""

SCREEN_MARGIN = 1e-6
"""Relative: a box whose bound without a solver is this far above the pruning threshold is pruned
unsolved (beyond the relaxation's own accuracy, ~1e-9, so that the solver would have pruned it)."""

UNBOUNDED_RUNS = 10_000
"""The cap on ``n`` when no minimum slice bounds it (``min_slice_ms: 0``)."""

Box = dict[str, tuple[int, int]]


@dataclass
class Effort:
    """Relaxations solved, counted across searches (the planner's budget for runners-up)."""

    relaxations: int = 0


@dataclass(frozen=True)
class IntegerSolution:
    runs: dict[str, int]  # n_i: schedule periods per run, for each non-batch shared subchain
    solution: RelaxedSolution  # the GP's optimum with every n_i fixed
    objective: float
    root_bound: float  # a lower bound: the relaxation's value (the optimum itself when enumerated)
    nodes: int  # relaxations solved
    gap: float = 0.0  # proven (objective - optimum) / objective: 0 unless stopped by node_limit


def most_runs(compute_ms: float, schedule: Schedule) -> int:
    """The largest ``n`` the minimum slice allows: ``f c >= min(slice, c)``."""
    if schedule.min_slice_ms <= 0:
        return UNBOUNDED_RUNS
    return max(1, math.floor(compute_ms / min(schedule.min_slice_ms, compute_ms) + 1e-9))


def closed_form(model: Stage2Model, problem: Problem) -> WholeRuns | OneBatchRuns | None:
    """Fixed runs in closed form: with no batch subchain, or one (its fraction then solved for exactly)."""
    if WholeRuns.applies(model, problem):
        return WholeRuns(model, problem)
    if OneBatchRuns.applies(model, problem):
        return OneBatchRuns(model, problem)
    return None


def solve_integer(
    model: Stage2Model,
    problem: Problem,
    scale: float = 1.0,
    *,
    least_scale: bool = False,
    cutoff: float | None = None,
    start: dict[str, int] | None = None,
    gap: float = 0.0,
    enumerate_up_to: int = ENUMERATE_UP_TO,
    node_limit: int | None = None,
    effort: Effort | None = None,
    floor: Callable[[], float] | None = None,
) -> IntegerSolution | None:
    """The best plan with whole ``n_i``, or None when no integer plan meets the (scaled) bounds.

    With ``least_scale`` the search minimises the scale the bounds need instead
    (its ``objective`` is then that scale).  Only plans better than ``cutoff``
    are of interest (None when there is none): another allocation's plan,
    say.  ``start`` is a guess at the answer, evaluated first so that it
    prunes from the outset (the previous plan, when re-planning).  ``gap``
    accepts a plan proven within that relative distance of the optimum,
    measured against the plan as MILP solvers do: ``(plan - optimum) / plan
    <= gap`` (default: exact, to the solver's accuracy :data:`PRUNE_TOLERANCE`).

    Without batch subchains the answer for fixed runs has a closed form
    (:mod:`catanc.planning.stage2.whole`): small boxes are then enumerated outright,
    and the search's leaves need no solver (``enumerate_up_to=0`` forces the
    search, as the tests do).  With one batch subchain the leaves are solved
    exactly in its one free fraction (:mod:`catanc.planning.stage2.onebatch`).

    ``node_limit`` stops the search after that many relaxations once it has a
    plan; the result then carries its proven ``gap`` (a large group of
    subchains on one core can need thousands: 26 integer runs took 4,117).

    ``floor`` gives a lower bound on the objective of every point of the root box without a solver (weighted
    problems; the planner's :func:`~catanc.planning.stage2.solve.lower_bound`). Where ``start`` is within the
    gap of it, the search stops there, as the root relaxation (no lower: the floor bounds it too) would have
    stopped it: the same plan, without a solver (nav2d on 2 cores: the floor is the relaxation's value within
    1e-8, so a re-solve usually needs no conic solve).
    """
    compute = {sub.name: sub.compute_ms for sub in problem.subchains}
    # Branch first where it matters: subchains weighted in the objective, then those a bound
    # depends on, then the rest. The relaxation leaves a subchain that influences nothing at an
    # arbitrary fraction, and branching on it first multiplies boxes that all tie.
    weight, bounded = problem.importance(), problem.bounded()
    rank = {name: (2 if weight[name] > 0 else 1 if name in bounded else 0) for name in model.integral}
    root: Box = {name: (1, most_runs(compute[name], model.schedule)) for name in model.integral}
    nodes = 0
    tolerance = max(PRUNE_TOLERANCE, gap)
    fixed = closed_form(model, problem)
    whole = fixed if isinstance(fixed, WholeRuns) else None
    if whole is not None and WholeRuns.size(root) <= enumerate_up_to:
        found = whole.best(root, scale, least_scale=least_scale)
        if found is None or (cutoff is not None and found.solution.objective >= cutoff):
            return None
        value = found.solution.objective
        return IntegerSolution(found.runs, found.solution, value, root_bound=value, nodes=0)

    # A child box whose bound without a solver already reaches the pruning threshold is not solved:
    # the relaxation (at least that bound) would prune it too. It still counts as a relaxation, so
    # that node limits stop where they did (the same plans; Autoware at K=2: ~9% of solves saved).
    screen = whole.box_bound if whole is not None and problem.weighted and not least_scale else None

    def relax(box: Box, prune_at: float = math.inf) -> RelaxedSolution | None:
        nonlocal nodes
        nodes += 1
        if effort is not None:
            effort.relaxations += 1
        if screen is not None and prune_at < math.inf and screen(box) >= prune_at * (1 + SCREEN_MARGIN):
            return None
        model.set_box(box)
        return model.solve_least_scale() if least_scale else model.solve(scale)

    best: tuple[float, Box, RelaxedSolution] | None = None
    threshold = math.inf if cutoff is None else cutoff  # prune boxes whose bound is not below this

    def offer(box: Box) -> float:
        """Evaluate the box's point exactly (every n fixed); its value (inf: infeasible)."""
        nonlocal best, threshold
        exact: RelaxedSolution | Open | None = OPEN
        if fixed is not None:  # every n fixed and at most one batch subchain: no solver needed
            # A point no better than the incumbent changes nothing: not even the split below, as
            # its value then exceeds the box's bound anyway (that is below the incumbent).
            runs = {name: low for name, (low, _) in box.items()}
            exact = fixed.fixed_runs(runs, scale, least_scale=least_scale, cutoff=threshold)
        if isinstance(exact, Open):
            exact = relax(box)
        if exact is None:
            return math.inf
        if exact.objective < min(threshold, best[0] if best else math.inf):
            best = (exact.objective, box, exact)
            threshold = exact.objective
        return exact.objective

    if start is not None and set(start) == set(model.integral):
        offer({name: (min(max(n, 1), root[name][1]),) * 2 for name, n in start.items()})
        # Beyond the solver's accuracy above the threshold, as the screen below: the relaxation would stop here.
        if (
            best is not None
            and floor is not None
            and not least_scale
            and floor() >= threshold * (1 - tolerance) * (1 + SCREEN_MARGIN)
        ):
            return _result(best, None, nodes)
    first = relax(root)
    if first is None or first.objective >= threshold * (1 - tolerance):
        return _result(best, first, nodes)
    rounded = {name: (r, r) for name, r in _nearest(first, model.integral, root).items()}
    if best is None or best[1] != rounded:
        offer(rounded)

    # Open boxes with their bounds and the order they were found in: a stack (depth first) until
    # the node limit passes without a plan, then a heap by bound (best first, ties: found first).
    created = itertools.count()
    boxes: list[tuple[float, int, Box, RelaxedSolution]] = [(first.objective, next(created), root, first)]
    best_first = False
    while boxes:
        if node_limit is not None and nodes >= node_limit:
            if best is not None:
                open_bound = min(bound for bound, _, _, _ in boxes)
                return _result(best, first, nodes, gap=max(0.0, (best[0] - open_bound) / best[0]) if best[0] else 0.0)
            if not best_first:
                best_first = True
                heapq.heapify(boxes)
        bound, _, box, solution = heapq.heappop(boxes) if best_first else boxes.pop()
        if bound >= threshold * (1 - tolerance):
            if best_first:
                break  # and every box still open: none has a lower bound
            continue
        if best_first and fixed is not None:  # its rounded point: a plan sooner than the leaves give one
            offer({name: (r, r) for name, r in _nearest(solution, model.integral, box).items()})
            if best is not None:  # past the node limit: stop with it (this box's bound is the least open)
                return _result(best, first, nodes, gap=max(0.0, (best[0] - bound) / best[0]) if best[0] else 0.0)
        branch = _most_fractional(solution, model.integral, box, rank)
        if branch is None:  # whole already: evaluate exactly with n fixed
            point = _nearest(solution, model.integral, box)
            value = offer({name: (r, r) for name, r in point.items()})
            # Where a rate cap makes some k exceed n the relaxation (k continuous) may be below the
            # point's value; other points of the box may then do better: split around the point.
            wide = [name for name in model.integral if box[name][0] < box[name][1]]
            if value <= solution.objective * (1 + tolerance) or not wide:
                continue
            name = max(wide, key=lambda name: (rank[name], box[name][1] - box[name][0]))
            low, high = box[name]
            at = point[name]
            parts = [(low, at - 1), (at, at), (at + 1, high)]
            children = [{**box, name: part} for part in parts if part[0] <= part[1]]
        else:
            name, runs = branch
            low, high = box[name]
            below = {**box, name: (low, math.floor(runs))}
            above = {**box, name: (math.ceil(runs), high)}
            children = [below, above] if runs - math.floor(runs) < 0.5 else [above, below]
        for child in reversed(children):  # the nearer child is explored first (depth first)
            relaxed = relax(child, prune_at=threshold * (1 - tolerance))
            if relaxed is not None and relaxed.objective < threshold * (1 - tolerance):
                entry = (relaxed.objective, next(created), child, relaxed)
                if best_first:
                    heapq.heappush(boxes, entry)
                else:
                    boxes.append(entry)
    return _result(best, first, nodes)


def _result(
    best: tuple[float, Box, RelaxedSolution] | None, root: RelaxedSolution | None, nodes: int, gap: float = 0.0
) -> IntegerSolution | None:
    if best is None:
        return None
    objective, box, solution = best
    return IntegerSolution(
        runs={name: low for name, (low, _) in box.items()},
        solution=solution,
        objective=objective,
        root_bound=objective if root is None else min(root.objective, objective),
        nodes=nodes,
        gap=gap,
    )


def _runs(solution: RelaxedSolution, name: str) -> float:
    return 1.0 / solution.fraction[name]


def _nearest(solution: RelaxedSolution, names: list[str], box: Box) -> dict[str, int]:
    return {name: min(max(round(_runs(solution, name)), box[name][0]), box[name][1]) for name in names}


def _most_fractional(
    solution: RelaxedSolution, names: list[str], box: Box, rank: dict[str, int]
) -> tuple[str, float] | None:
    """The non-whole ``n`` to branch on: highest rank, then farthest from a whole number, then first."""
    choice: tuple[tuple[int, float], str, float] | None = None
    for name in names:
        runs = min(max(_runs(solution, name), box[name][0]), box[name][1])
        distance = min(runs - math.floor(runs), math.ceil(runs) - runs)
        if distance <= INTEGRAL_TOLERANCE * max(1.0, runs):
            continue
        key = (rank[name], distance)
        if choice is None or key > choice[0]:
            choice = (key, name, runs)
    return None if choice is None else (choice[1], choice[2])
