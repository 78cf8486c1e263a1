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

import math
import weakref
from dataclasses import dataclass

from catanc.model.problem import ChainForm, Problem
from catanc.planning.stage2.base import RelaxedSolution, Stage2Model, aligned_every, length_candidates
from catanc.planning.stage2.convex import OPEN, Convex, Open, Piece, least_scale_point, optimum_point
from catanc.planning.stage2.whole import FEASIBILITY, WholeRuns

Row = dict[int, float]
"""A piece as weights on the basis pieces (see :func:`_compile`)."""


class _OpenError(Exception):
    """Raised inside a search where the closed form has no unique attained optimum (then: OPEN)."""


MARGIN = FEASIBILITY / 2
"""The bounds' slack used to choose ``x``; the plan is then checked with :data:`FEASIBILITY`, so a
point on a bound's boundary passes despite rounding."""


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
        self.capped = self.whole.capped(self.core)  # the batch core's members whose k can exceed n
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

    def fixed_runs(
        self, runs: dict[str, int], scale: float, *, least_scale: bool, cutoff: float = math.inf
    ) -> RelaxedSolution | Open | None:
        """The exact optimum with these runs (None: they miss the scaled bounds, or no plan beats
        ``cutoff`` where lengths are searched; OPEN: ask the solver).

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
                cutoff=cutoff,
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
            for low, high, length in order:
                bound_x = self._choose(relaxed, scale, least_scale=least_scale, window=(low, high))
                if bound_x is None:
                    break  # the relaxation's feasible x form one interval around ``centre``
                if isinstance(bound_x, Open):
                    raise _OpenError
                if best is not None and self._value(relaxed, bound_x, least_scale=least_scale) >= best.objective:
                    break
                exact = self._convex(runs, lengths, self._every(runs, length))
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

    def _windows(self, runs: dict[str, int]) -> list[tuple[float, float, float]]:
        """The batch core's ``x`` intervals on which every ``k`` there is constant: (low, high, the ``T`` at
        low, whose :meth:`_every` they are; the search visits a few of them, so ``k`` waits for it)."""
        load, slope = self._load_slope(runs)
        least = load + slope * self.least_fraction
        members = [(runs[name], self.whole.by_name[name].min_period_ms) for name in self.capped]
        points = length_candidates(least, members)
        lows = [self.least_fraction] + [(length - load) / slope for length in points[1:]]
        highs = [*lows[1:], math.inf]
        return list(zip(lows, highs, points, strict=True))

    def _every(self, runs: dict[str, int], length: float) -> dict[str, int]:
        """Each capped member's ``k`` on the batch core at schedule length ``length``."""
        by_name = self.whole.by_name
        return {
            name: aligned_every(runs[name], length, by_name[name].min_period_ms)
            for name in self.whole.capped(self.core)
        }

    def _load_slope(self, runs: dict[str, int]) -> tuple[float, float]:
        """The batch core's ``T = load + slope x``."""
        fractions = {name: 1.0 / runs[name] for name in self.core.subchains if name != self.batch}
        fractions[self.batch] = 0.0
        load = self.whole.length(self.core, fractions)
        return load, self.whole.by_name[self.batch].compute_ms / self.usable

    def _convex(
        self, runs: dict[str, int], lengths: dict[int, float] | None, every: dict[str, int] | None
    ) -> list[Convex] | None:
        """The objective and each bound in ``x`` (None: ``T / x`` is constant).

        ``every`` None: the relaxation (``p = max(n T, p_min)``); else the batch core's ``k``
        (the other cores' follow from their ``T``).
        """
        pieces = self._pieces(runs, lengths, every)
        return None if pieces is None else self._expressions(pieces)

    def _choose(
        self, expressions: list[Convex], scale: float, *, least_scale: bool, window: tuple[float, float]
    ) -> float | Open | None:
        objective, *bounds = expressions
        limits = self.structure.limits
        if least_scale:
            scaled = [bound.scaled(1.0 / limit) for bound, limit in zip(bounds, limits, strict=True)]
            return least_scale_point(scaled, *window)
        allowed = [limit * scale * (1 + MARGIN) for limit in limits]
        return optimum_point(objective, bounds, allowed, *window)

    def _value(self, expressions: list[Convex], x: float, *, least_scale: bool) -> float:
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

    def _expressions(self, pieces: list[Piece]) -> list[Convex]:
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
        return [Convex(tuple(m), (b[0], b[1], b[2])) for m, b in zip(maxima, bases, strict=True)]
