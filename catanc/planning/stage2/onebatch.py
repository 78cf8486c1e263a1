"""Stage II with every ``n_i`` fixed and one batch subchain sharing a core: one variable, solved exactly.

With the runs fixed, the only number left free is the batch subchain's
fraction ``x = f_b``.  Its core's schedule length is ``T = (A + c_b x) / u``
(``A``: the other members' slices ``c_i / n_i`` and the switches; ``u = 1 -
slack``), so a member's latency ``n_i T`` is affine in ``x`` and the batch
subchain's ``T / x = A / (u x) + c_b / u``.  Every period, chain response
and bound is then a sum of maxima of *pieces* ``a x + b / x + c`` with
``a, b, c >= 0`` (a period is ``max(latency, p_min)``, a chain's longest
period a maximum over its stages), hence convex in ``x``.  Between
consecutive *breakpoints* (where two pieces of one maximum cross) each of
them is a single piece, and there

- a bound ``piece <= limit`` holds on an interval: between the roots of a quadratic;
- the objective's piece is least at ``sqrt(b / a)``, clipped to what the bounds allow;
- the least scale is the maximum of the bounds' pieces (and 1), least where
  one piece is stationary, two cross, or at an end.

The best of the segments' candidates is the exact optimum,
which :class:`~catanc.planning.stage2.whole.WholeRuns` then scores with the model's own
functions.  Where the optimum is not one point (an objective flat in ``x``) or
not attained (at ``x = inf`` where nothing bounds the batch fraction, or at
``x = 0`` where no minimum slice does), the answer is :data:`OPEN` and the
caller asks the conic solver, as before this module.

nav2d plans this way on one core (GL is batch and shares the core): more than
half of the conic solves of a re-plan were such fixed-run evaluations.  The
sizes are tiny (nav2d: ~20 pieces, a handful of segments), so this is plain
Python: written with numpy, its per-call overhead made it slower than the
conic solve (~400 us against ~300); plain, it takes ~100 us.
"""

from __future__ import annotations

import itertools
import math
import weakref
from dataclasses import dataclass
from enum import Enum
from typing import Final

from catanc.core.problem import ChainForm, Problem
from catanc.planning.stage2.base import RelaxedSolution, Stage2Model, aligned_every, length_candidates
from catanc.planning.stage2.whole import FEASIBILITY, WholeRuns

Piece = tuple[float, float, float]
"""``(a, b, c)`` of ``a x + b / x + c``."""
Row = dict[int, float]
"""A piece as weights on the basis pieces (see :func:`_compile`)."""


class _OpenError(Exception):
    """Raised inside a search where the closed form has no unique attained optimum (then: OPEN)."""


class Open(Enum):
    """The closed form has no unique attained optimum here: solve the relaxation instead."""

    OPEN = "open"


OPEN: Final = Open.OPEN

MARGIN = FEASIBILITY / 2
"""The bounds' slack used to choose ``x``; the plan is then checked with :data:`FEASIBILITY`, so a
point on a bound's boundary passes despite rounding."""

FLAT = 1e-12
"""An objective piece whose terms in ``x`` are this small against its value counts as flat in ``x``."""


@dataclass(frozen=True)
class _Structure:
    """What depends only on the layout and the spec's terms and bounds, compiled once per model.

    The basis pieces, computed per call: subchain ``k``'s latency at ``2k``, its period before
    the rate cap at ``2k + 1`` (the latency when shared, a constant when dedicated), and the
    batch core's schedule length last.  A slot is one piece of a maximum, as weights on them
    plus a constant.
    """

    names: tuple[str, ...]  # every subchain, in problem order
    slots: tuple[tuple[tuple[tuple[int, float], ...], float], ...]  # (weights, constant)
    groups: tuple[tuple[int, tuple[int, ...]], ...]  # (expression, its slots): 0 the objective, j bound j
    limits: tuple[float, ...]  # bound j's limit as written (before the scale), at j - 1


class _Builder:
    """Collects maxima of pieces for the objective (expression 0) and each bound."""

    def __init__(self, problem: Problem, shared: set[str]) -> None:
        self.index = {sub.name: k for k, sub in enumerate(problem.subchains)}
        self.min_period = {sub.name: sub.min_period_ms for sub in problem.subchains}
        self.shared = shared
        self.groups: list[tuple[int, list[tuple[Row, float]]]] = []
        self.sums: dict[int, tuple[Row, float]] = {}  # each expression's single-piece part

    def add_sum(self, expression: int, row: Row, constant: float) -> None:
        total, base = self.sums.get(expression, ({}, 0.0))
        merged = dict(total)
        for index, weight in row.items():
            merged[index] = merged.get(index, 0.0) + weight
        self.sums[expression] = (merged, base + constant)

    def period_pieces(self, name: str, weight: float) -> list[tuple[Row, float]]:
        """``weight * max(period, p_min)``: a shared subchain's period; a dedicated one's is capped already."""
        pieces: list[tuple[Row, float]] = [({2 * self.index[name] + 1: weight}, 0.0)]
        if name in self.shared and self.min_period[name] > 0:
            pieces.append(({}, weight * self.min_period[name]))
        return pieces

    def add_group(self, expression: int, pieces: list[tuple[Row, float]]) -> None:
        if len(pieces) == 1:
            self.add_sum(expression, *pieces[0])
        else:
            self.groups.append((expression, pieces))

    def add_response(self, expression: int, form: ChainForm, weight: float) -> None:
        """``weight * R`` of a chain: ``L`` as a sum, each waiting period and the longest period as maxima."""
        self.add_sum(expression, {2 * self.index[name]: weight for name in form.latency_of}, weight * form.constant)
        for name in form.period_of:
            self.add_group(expression, self.period_pieces(name, weight))
        longest = [piece for name in form.longest_of for piece in self.period_pieces(name, weight)]
        if form.floor > 0:
            longest.append(({}, weight * form.floor))
        if longest:
            self.add_group(expression, longest)

    def build(self, names: tuple[str, ...], limits: list[float]) -> _Structure:
        singles = [(e, [self.sums.get(e, ({}, 0.0))]) for e in range(len(limits) + 1)]
        slots: list[tuple[tuple[tuple[int, float], ...], float]] = []
        groups: list[tuple[int, tuple[int, ...]]] = []
        for expression, pieces in singles + self.groups:
            first = len(slots)
            slots += [(tuple(sorted(row.items())), constant) for row, constant in pieces]
            groups.append((expression, tuple(range(first, len(slots)))))
        return _Structure(names, tuple(slots), tuple(groups), tuple(limits))


def _compile(problem: Problem, shared: set[str]) -> _Structure:
    builder = _Builder(problem, shared)
    names = tuple(sub.name for sub in problem.subchains)
    if problem.weighted:
        for term in problem.response_terms:
            if term.weight > 0:
                builder.add_response(0, problem.chain_forms[term.chain], term.weight)
        for period_term in problem.period_terms:
            if period_term.weight > 0:
                builder.add_group(0, builder.period_pieces(period_term.subchain, period_term.weight))
    else:  # the sum of the schedule lengths: the batch core's T, the other cores' are constants
        builder.add_sum(0, {2 * len(names): 1.0}, 0.0)
    limits: list[float] = []
    for bound in problem.response_bounds:
        limits.append(bound.max_response_ms)
        builder.add_response(len(limits), problem.chain_forms[bound.chain], 1.0)
    for sub in problem.subchains:
        if sub.max_period_ms < math.inf:
            limits.append(sub.max_period_ms)
            builder.add_group(len(limits), builder.period_pieces(sub.name, 1.0))
    return builder.build(names, limits)


_STRUCTURES: weakref.WeakKeyDictionary[Stage2Model, _Structure] = weakref.WeakKeyDictionary()


class OneBatchRuns:
    """The exact Stage II optimum with fixed runs where one shared subchain is batch."""

    def __init__(self, model: Stage2Model, problem: Problem) -> None:
        self.whole = WholeRuns(model, problem)
        (self.batch,) = [name for name in model.shared_names if problem.subchain(name).batch]
        (self.core,) = [core for core in model.layout.shared if self.batch in core.subchains]
        self.core_of = {name: core.core for core in model.layout.shared for name in core.subchains}
        self.usable = 1.0 - model.schedule.slack
        self.switch_ms = model.schedule.switch_ms
        self.least_fraction = 0.0
        if model.schedule.min_slice_ms > 0:  # f c >= min(slice, c)
            compute = problem.subchain(self.batch).compute_ms
            self.least_fraction = min(model.schedule.min_slice_ms, compute) / compute
        structure = _STRUCTURES.get(model)
        if structure is None:
            structure = _compile(model.problem, set(model.shared_names))
            _STRUCTURES[model] = structure
        self.structure = structure

    @property
    def aligned_matters(self) -> bool:
        return self.whole.aligned_matters

    @staticmethod
    def applies(model: Stage2Model, problem: Problem) -> bool:
        """Exactly one shared subchain is batch (more would leave several variables free)."""
        return sum(problem.subchain(name).batch for name in model.shared_names) == 1

    def solve(self, runs: dict[str, int], scale: float, *, least_scale: bool) -> RelaxedSolution | Open | None:
        """The relaxation's optimum with these runs (None: they miss the scaled bounds; OPEN: ask the solver)."""
        expressions = self._convex(runs, None, None)
        if expressions is None:
            return OPEN
        x = self._choose(expressions, scale, least_scale=least_scale, window=(self.least_fraction, math.inf))
        if x is None or isinstance(x, Open):
            return x
        return self.whole.solve(runs, scale, least_scale=least_scale, batch={self.batch: x}, aligned=False)

    def fixed_runs(self, runs: dict[str, int], scale: float, *, least_scale: bool) -> RelaxedSolution | Open | None:
        """The exact optimum with these runs (None: they miss the scaled bounds; OPEN: ask the solver).

        Where a shared subchain's ``k`` can exceed its ``n`` (a rate cap or a fixed rate), the
        relaxation is only a bound: the lengths of the other cores are searched as
        :meth:`WholeRuns.exact` does, and the batch core's ``T`` (so ``x``) interval by interval,
        where every ``k`` on it is constant (between ``T = p_min / j`` breakpoints), outward from
        the relaxed optimum until the relaxation over an interval reaches the best found (the
        relaxation is convex in ``x``, so these bounds only grow outward).
        """
        if not self.whole.aligned_matters:
            return self.solve(runs, scale, least_scale=least_scale)
        try:
            return self.whole.exact(
                runs,
                scale,
                least_scale=least_scale,
                fixed_cores=frozenset({self.core.core}),
                leaf=lambda lengths: self._batch_core(runs, scale, lengths, least_scale=least_scale),
                relaxed_leaf=lambda lengths: self._relaxed(runs, scale, lengths, least_scale=least_scale),
            )
        except _OpenError:
            return OPEN

    def _relaxed(
        self, runs: dict[str, int], scale: float, lengths: dict[int, float], *, least_scale: bool
    ) -> float | None:
        """The relaxation's optimum over ``x`` with the other cores at ``lengths`` (a lower bound)."""
        expressions = self._convex(runs, lengths, None)
        if expressions is None:
            raise _OpenError
        x = self._choose(expressions, scale, least_scale=least_scale, window=(self.least_fraction, math.inf))
        if isinstance(x, Open):
            raise _OpenError
        return None if x is None else self._value(expressions, x, least_scale=least_scale)

    def _batch_core(
        self, runs: dict[str, int], scale: float, lengths: dict[int, float], *, least_scale: bool
    ) -> RelaxedSolution | None:
        """The best ``x`` with the other cores at ``lengths``, interval by interval of the batch core's ``T``."""
        relaxed = self._convex(runs, lengths, None)
        if relaxed is None:
            raise _OpenError
        centre = self._choose(relaxed, scale, least_scale=least_scale, window=(self.least_fraction, math.inf))
        if centre is None:
            return None
        if isinstance(centre, Open):
            raise _OpenError
        windows = self._windows(runs)
        first = max(index for index, (low, _, _) in enumerate(windows) if low <= centre)
        best: RelaxedSolution | None = None
        for order in (windows[first:], windows[:first][::-1]):  # outward from the relaxed optimum
            for low, high, every in order:
                bound_x = self._choose(relaxed, scale, least_scale=least_scale, window=(low, high))
                if bound_x is None:
                    break  # the relaxation's feasible x form one interval around ``centre``
                if isinstance(bound_x, Open):
                    raise _OpenError
                if best is not None and self._value(relaxed, bound_x, least_scale=least_scale) >= best.objective:
                    break
                exact = self._convex(runs, lengths, every)
                if exact is None:
                    raise _OpenError
                x = self._choose(exact, scale, least_scale=least_scale, window=(low, high))
                if isinstance(x, Open):
                    raise _OpenError
                if x is None:
                    continue
                found = self.whole.solve(runs, scale, least_scale=least_scale, batch={self.batch: x}, lengths=lengths)
                if found is not None and (best is None or found.objective < best.objective):
                    best = found
        return best

    def _windows(self, runs: dict[str, int]) -> list[tuple[float, float, dict[str, int]]]:
        """The batch core's ``x`` intervals on which every ``k`` there is constant: (low, high, k by subchain)."""
        load, slope = self._load_slope(runs)
        capped = self.whole.capped(self.core)
        least = load + slope * self.least_fraction
        members = [(runs[name], self.whole.by_name[name].min_period_ms) for name in capped]
        points = length_candidates(least, members)
        lows = [self.least_fraction] + [(length - load) / slope for length in points[1:]]
        highs = [*lows[1:], math.inf]
        return [
            (low, high, {name: aligned_every(runs[name], length, self.whole.by_name[name].min_period_ms)
                         for name in capped})
            for low, high, length in zip(lows, highs, points, strict=True)
        ]  # fmt: skip

    def _load_slope(self, runs: dict[str, int]) -> tuple[float, float]:
        """The batch core's ``T = load + slope x``."""
        fractions = {name: 1.0 / runs[name] for name in self.core.subchains if name != self.batch}
        fractions[self.batch] = 0.0
        load = self.whole.length(self.core, fractions)
        return load, self.whole.by_name[self.batch].compute_ms / self.usable

    def _convex(
        self, runs: dict[str, int], lengths: dict[int, float] | None, every: dict[str, int] | None
    ) -> list[_Convex] | None:
        """The objective and each bound in ``x`` (None: ``T / x`` is constant).

        ``every`` None: the relaxation (``p = max(n T, p_min)``); else the batch core's ``k``
        (the other cores' follow from their ``T``).
        """
        pieces = self._pieces(runs, lengths, every)
        return None if pieces is None else self._expressions(pieces)

    def _choose(
        self, expressions: list[_Convex], scale: float, *, least_scale: bool, window: tuple[float, float]
    ) -> float | Open | None:
        objective, *bounds = expressions
        limits = self.structure.limits
        if least_scale:
            scaled = [bound.scaled(1.0 / limit) for bound, limit in zip(bounds, limits, strict=True)]
            return _least_scale_point(scaled, *window)
        allowed = [limit * scale * (1 + MARGIN) for limit in limits]
        return _optimum_point(objective, bounds, allowed, *window)

    def _value(self, expressions: list[_Convex], x: float, *, least_scale: bool) -> float:
        objective, *bounds = expressions
        if least_scale:
            limits = self.structure.limits
            return max([1.0, *(bound.value(x) / limit for bound, limit in zip(bounds, limits, strict=True))])
        return objective.value(x)

    def _pieces(
        self, runs: dict[str, int], lengths: dict[int, float] | None = None, every: dict[str, int] | None = None
    ) -> list[Piece] | None:
        """Every slot's piece for these runs and the problem's compute times (None: T / x is constant)."""
        by_name = self.whole.by_name
        fractions = {name: 1.0 / runs[name] for name in self.whole.shared if name != self.batch}
        fractions[self.batch] = 0.0
        chosen = {
            core.core: max(self.whole.length(core, fractions), (lengths or {}).get(core.core, 0.0))
            for core in self.whole.layout.shared
        }
        load = chosen[self.core.core]  # A / u: T without the batch subchain's slice
        slope = by_name[self.batch].compute_ms / self.usable  # c_b / u
        if load <= 0:
            return None
        basis: list[Piece] = []
        for name in self.structure.names:
            core = self.core_of.get(name)
            if core is None:
                timing = self.whole.dedicated[name]
                basis += [(0.0, 0.0, timing.latency_ms), (0.0, 0.0, timing.period_ms)]
                continue
            if name == self.batch:
                latency = (0.0, load, slope)
                basis += [latency, latency]
                continue
            n = runs[name]
            if core == self.core.core:
                k = n if every is None else every.get(name, n)
                basis += [(n * slope, 0.0, n * load), (k * slope, 0.0, k * load)]
            else:
                k = n if every is None else aligned_every(n, chosen[core], by_name[name].min_period_ms)
                basis += [(0.0, 0.0, n * chosen[core]), (0.0, 0.0, k * chosen[core])]
        basis.append((slope, 0.0, load))
        pieces: list[Piece] = []
        for weights, constant in self.structure.slots:
            a = b = 0.0
            c = constant
            for index, weight in weights:
                pa, pb, pc = basis[index]
                a += weight * pa
                b += weight * pb
                c += weight * pc
            pieces.append((a, b, c))
        return pieces

    def _expressions(self, pieces: list[Piece]) -> list[_Convex]:
        """The objective and each bound as sums of maxima, with what cannot decide a maximum dropped.

        Equal pieces are kept once and constants only at their largest (several subchains on
        one core with the same runs have the same latency): the pairs to cross stay few.
        """
        expressions = len(self.structure.limits) + 1
        maxima: list[list[tuple[Piece, ...]]] = [[] for _ in range(expressions)]
        bases = [[0.0, 0.0, 0.0] for _ in range(expressions)]
        for expression, slots in self.structure.groups:
            distinct: set[Piece] = set()
            highest = -math.inf
            for slot in slots:
                piece = pieces[slot]
                if piece[0] == 0 and piece[1] == 0:
                    highest = max(highest, piece[2])
                else:
                    distinct.add(piece)
            if highest > -math.inf:
                distinct.add((0.0, 0.0, highest))
            if len(distinct) == 1:
                (a, b, c), base = next(iter(distinct)), bases[expression]
                base[0] += a
                base[1] += b
                base[2] += c
            else:
                maxima[expression].append(tuple(sorted(distinct)))
        return [_Convex(tuple(m), (b[0], b[1], b[2])) for m, b in zip(maxima, bases, strict=True)]


@dataclass(frozen=True)
class _Convex:
    """A sum of maxima of pieces: the maxima of two or more pieces, and the single pieces summed."""

    maxima: tuple[tuple[Piece, ...], ...]
    base: Piece

    def at(self, x: float) -> Piece:
        """The one piece this equals around ``x``, for ``x`` strictly between breakpoints."""
        a, b, c = self.base
        for pieces in self.maxima:
            top = pieces[0]
            highest = top[0] * x + top[1] / x + top[2]
            for piece in pieces[1:]:
                value = piece[0] * x + piece[1] / x + piece[2]
                if value > highest:
                    top, highest = piece, value
            a, b, c = a + top[0], b + top[1], c + top[2]
        return a, b, c

    def value(self, x: float) -> float:
        a, b, c = self.at(x)
        return a * x + b / x + c

    def edges(self, least: float) -> list[float]:
        """``least``, the breakpoints above it (where two pieces of a maximum cross), then infinity."""
        crossings: set[float] = set()
        for pieces in self.maxima:
            for i, first in enumerate(pieces):
                for second in pieces[i + 1 :]:
                    crossings.update(_crossings(first, second))
        return [least, *sorted(x for x in crossings if x > least), math.inf]

    def scaled(self, factor: float) -> _Convex:
        def times(piece: Piece) -> Piece:
            return piece[0] * factor, piece[1] * factor, piece[2] * factor

        return _Convex(tuple(tuple(times(piece) for piece in pieces) for pieces in self.maxima), times(self.base))


def _inside(low: float, high: float) -> float:
    """A point strictly inside ``(low, high)``, ``0 <= low < high <= inf``."""
    if math.isfinite(high):
        return math.sqrt(low * high) if low > 0 else high / 2
    return 2 * low if low > 0 else 1.0


def _minimisers(objective: _Convex, least: float) -> tuple[float, float]:
    """Where ``objective`` is least on ``[least, inf)``: one point, or a segment where it is flat.

    Convexity orders the segments: a binary search for the one whose piece is stationary
    inside it, or the breakpoint between one that falls and one that rises.  An end at 0 or
    infinity means the least value is approached, not attained.
    """
    edges = objective.edges(least)
    first, last = 0, len(edges) - 2
    while first <= last:
        k = (first + last) // 2
        low, high = edges[k], edges[k + 1]
        a, b, _ = objective.at(_inside(low, high))
        if a == 0 and b == 0:
            return low, high
        stationary = math.sqrt(b / a) if a > 0 and b > 0 else (0.0 if a > 0 else math.inf)
        if stationary < low:
            last = k - 1
        elif stationary > high:
            first = k + 1
        else:
            return stationary, stationary
    return edges[first], edges[first]


def _sublevel(bound: _Convex, limit: float, least: float) -> tuple[float, float] | None:
    """Where ``bound <= limit`` on ``[least, inf)``: an interval, by convexity (None: nowhere)."""
    edges = bound.edges(least)
    low, high = math.inf, -math.inf
    for start, end in itertools.pairwise(edges):
        allowed = _at_most(bound.at(_inside(start, end)), limit)
        if allowed is not None and max(start, allowed[0]) <= min(end, allowed[1]):
            low, high = min(low, max(start, allowed[0])), max(high, min(end, allowed[1]))
    return (low, high) if low <= high else None


def _optimum_point(
    objective: _Convex, bounds: list[_Convex], limits: list[float], least: float, most: float = math.inf
) -> float | Open | None:
    """The objective's least ``x`` in ``[least, most]`` where every bound holds (None: nowhere; OPEN: not
    one attained point).

    On an interval a convex function is least at its unconstrained minimiser clipped to it.
    """
    low, high = least, most
    for bound, limit in zip(bounds, limits, strict=True):
        allowed = _sublevel(bound, limit, least)
        if allowed is None:
            return None
        low, high = max(low, allowed[0]), min(high, allowed[1])
        if low > high:
            return None
    first, last = _minimisers(objective, least)
    x = min(max(first, low), high)
    if min(max(last, low), high) != x or not 0 < x < math.inf:
        return OPEN
    return x


def _least_scale_point(bounds: list[_Convex], least: float, most: float = math.inf) -> float | Open:
    """The ``x`` in ``[least, most]`` needing the least scale: ``max(1, max_j bound_j)``, least (bounds
    divided by their limits).

    On each segment every bound is one piece, and the maximum of convex pieces is least where
    one is stationary, two cross (the constant 1 among them), or at an end.  A least value
    approached at ``x = 0`` or ``x = inf`` is not attained: OPEN.
    """
    crossings = {x for bound in bounds for x in bound.edges(least)[1:-1] if x < most}
    edges = [least, *sorted(crossings), most]
    best: tuple[float, float] | None = None
    limits: list[float] = []  # the least scale approached at x = 0 (where no slice bounds x), then at inf
    last: list[Piece] = []
    for low, high in itertools.pairwise(edges):
        sample = _inside(low, high)
        last = [bound.at(sample) for bound in bounds] + [(0.0, 0.0, 1.0)]
        if low == 0:
            limits.append(math.inf if any(b > 0 for _, b, _ in last) else max(c for _, _, c in last))
        candidates = [low, high, sample]
        for i, (a, b, _) in enumerate(last):
            if a > 0 and b > 0:
                candidates.append(math.sqrt(b / a))
            for other in last[i + 1 :]:
                candidates += _crossings(last[i], other)
        for x in candidates:
            if low <= x <= high and 0 < x < math.inf:
                needed = max(a * x + b / x + c for a, b, c in last)
                if best is None or needed < best[0]:
                    best = (needed, x)
    assert best is not None  # the last segment's sample is a candidate
    if math.isinf(most):  # where no bound grows with x on the last segment, the least scale may lie at x = inf
        limits.append(math.inf if any(a > 0 for a, _, _ in last) else max(c for _, _, c in last))
    needed, x = best
    return OPEN if limits and needed > min(limits) * (1 + FLAT) else x


def _crossings(first: Piece, second: Piece) -> list[float]:
    """Where two pieces are equal, for ``x > 0``: the positive roots of ``da x^2 + dc x + db``."""
    da, db, dc = first[0] - second[0], first[1] - second[1], first[2] - second[2]
    if da == 0:
        return [-db / dc] if dc != 0 and -db / dc > 0 else []
    discriminant = dc * dc - 4 * da * db
    if discriminant < 0:
        return []
    q = -0.5 * (dc + math.copysign(math.sqrt(discriminant), dc))  # the stable pair of roots
    roots = [q / da] + ([db / q] if q != 0 else [])
    return [x for x in roots if x > 0]


def _at_most(piece: Piece, limit: float) -> tuple[float, float] | None:
    """Where ``a x + b / x + c <= limit`` for ``x > 0`` (an interval; None: nowhere)."""
    a, b, c = piece
    room = limit - c  # a x^2 - room x + b <= 0
    if room < 0 or (room == 0 and b > 0):
        return None
    discriminant = room * room - 4 * a * b
    if discriminant < 0:
        return None
    root = math.sqrt(discriminant)
    least = 2 * b / (room + root) if b > 0 else 0.0
    most = (room + root) / (2 * a) if a > 0 else math.inf
    return least, most
