"""Stage II with every ``n_i = 1/f_i`` fixed, in closed form (no batch subchain on a shared core).

A shared non-batch subchain's head is triggered at its slot every ``k_i``
periods (docs/explanation/model.md section 4): latency ``n_i T``, period ``k_i T`` with
``k_i = max(n_i, ceil(p_min / T))`` (:func:`~catanc.planning.stage2.base.aligned_every`:
a longer ``k`` only lengthens periods).  With every ``n`` fixed, each term
and bound grows with each core's ``T`` except where some ``k_i`` drops, at
``T = p_min_i / j``; so the optimum takes, per core, the shortest ``T`` that
fits the slices, switches and slack, or one of those breakpoints above it
(:func:`~catanc.planning.stage2.base.length_candidates`).  The relaxation (the GP's
``p >= max(T n, p_min)``, ``k`` continuous) is a lower bound that only grows
with ``T`` too, so the candidates are tried in ascending order and the
search stops where the relaxed value reaches the best found.  That gives

- :class:`WholeRuns.solve`: one integer vector, evaluated without a solver
  (the leaves of the branch and bound);
- :class:`WholeRuns.best`: every integer vector of a small box at once, as
  numpy arrays: the exact integer optimum with no solver at all, used when
  the box holds at most :data:`ENUMERATE_UP_TO` vectors (VR on one core: 33).
  Those arrays are the relaxation; with rate caps on shared subchains the
  vectors are then evaluated exactly in order of their relaxed value until
  that reaches the best exact value.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from catanc.model.metrics import QUICK_MARGIN, Timing, WeightedSums, bound_scale, capped_dedicated, objective
from catanc.model.problem import Problem
from catanc.planning.stage2.base import (
    EVERY_TOLERANCE,
    RelaxedSolution,
    SharedCore,
    Stage2Model,
    aligned_every,
    length_candidates,
    schedule_length,
)

ENUMERATE_UP_TO = 4096
"""Evaluate every integer vector at once when a box holds at most this many (a few hundred µs)."""

FEASIBILITY = 1e-9
"""Relative slack on the bounds when fixed runs are checked (rounding only)."""

ALIGNED_AT_ONCE = 65536
"""Score vectors times candidate lengths at once as arrays up to this many (a few ms at most)."""

NEAR_TIE = 1e-9
"""Relative: a vector whose exact value as arrays is this close to the best is searched one by one (rounding)."""

Floats = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Enumerated:
    runs: dict[str, int]
    solution: RelaxedSolution
    candidates: int  # integer vectors evaluated


class WholeRuns:
    """Closed forms of one layout's Stage II with fixed runs; None-free only without batch subchains."""

    def __init__(self, model: Stage2Model, problem: Problem) -> None:
        self.problem = problem
        self.layout = model.layout
        self.schedule = model.schedule
        self.shared = model.layout.shared_names
        self.dedicated = {
            name: capped_dedicated(problem.subchain(name), k, problem.slack).timing
            for name, k in model.layout.dedicated
        }
        self.by_name = {sub.name: sub for sub in problem.subchains}
        self.quick = WeightedSums.of(problem)

    @staticmethod
    def applies(model: Stage2Model, problem: Problem) -> bool:
        """Closed forms hold when no shared subchain is batch (a batch ``f`` stays free)."""
        return not any(problem.subchain(name).batch for core in model.layout.shared for name in core.subchains)

    def length(self, core: SharedCore, fractions: Mapping[str, float]) -> float:
        """One shared core's schedule length ``T`` with these fractions."""
        return schedule_length(core, fractions, self.by_name, self.schedule)

    def solve(
        self,
        runs: dict[str, int],
        scale: float,
        *,
        least_scale: bool,
        batch: Mapping[str, float] | None = None,
        lengths: Mapping[int, float] | None = None,
        aligned: bool = True,
        above: float = math.inf,
    ) -> RelaxedSolution | None:
        """The plan with these runs at these schedule lengths (None: it misses the scaled bounds).

        Its objective is :func:`~catanc.model.metrics.objective`'s, or where :class:`WeightedSums` puts it
        clearly above ``above`` that estimate (within rounding of it): the caller only rejects it then.

        ``batch`` gives each batch subchain's fraction, chosen by the caller
        (:mod:`catanc.planning.stage2.onebatch`); without batch subchains it is empty.
        ``lengths`` gives some cores' ``T`` (at least what fits; the rest: what fits).
        ``aligned=False`` scores the relaxation instead (``p = max(n T, p_min)``).
        """
        batch = batch or {}
        timings = dict(self.dedicated)
        chosen: dict[int, float] = {}
        fractions = {name: batch[name] if name in batch else 1.0 / runs[name] for name in self.shared}
        for core in self.layout.shared:
            fit = self.length(core, fractions)
            length = max(fit, lengths[core.core]) if lengths is not None and core.core in lengths else fit
            chosen[core.core] = length
            for name in core.subchains:
                sub = self.by_name[name]
                if name in batch:
                    latency = length / batch[name]
                    timings[name] = Timing(max(latency, sub.min_period_ms), latency)
                    continue
                latency = length * runs[name]
                if aligned:
                    period = aligned_every(runs[name], length, sub.min_period_ms) * length
                else:
                    period = max(latency, sub.min_period_ms)
                timings[name] = Timing(period, latency)
        needed = bound_scale(self.problem, timings)
        if least_scale:
            value = max(1.0, needed)
        elif needed > scale * (1 + FEASIBILITY):
            return None
        elif not self.problem.weighted:
            value = math.fsum(chosen.values())
        elif above == math.inf:  # every value is of interest: no estimate first
            value = objective(self.problem, timings)
        else:
            value = self.quick.value(timings)
            if value <= above * (1 + QUICK_MARGIN):
                value = objective(self.problem, timings)
        return RelaxedSolution(
            core_period_ms=chosen,
            fraction=fractions,
            period_ms={name: timings[name].period_ms for name in self.shared},
            objective=value,
        )

    def box_bound(self, box: Mapping[str, tuple[int, int]]) -> float:
        """A lower bound on the relaxation's objective over ``box`` (weighted problems), without a solver.

        Each core's ``T`` is at least what fits the slices at the box's largest runs (and the minimum
        slice); each latency ``T / f`` at least ``low T``, each period at least that and ``p_min``;
        the objective grows with each of them.  The estimate is lowered past its rounding.
        """
        timings = dict(self.dedicated)
        usable = 1.0 - self.schedule.slack
        for core in self.layout.shared:
            load = 0.0
            for name in core.subchains:
                compute = self.by_name[name].compute_ms
                load += max(compute / box[name][1], min(self.schedule.min_slice_ms, compute))
            length = (load + len(core.subchains) * self.schedule.switch_ms) / usable
            for name in core.subchains:
                latency = box[name][0] * length
                timings[name] = Timing(max(latency, self.by_name[name].min_period_ms), latency)
        return self.quick.value(timings) * (1 - QUICK_MARGIN)

    def fixed_runs(
        self, runs: dict[str, int], scale: float, *, least_scale: bool, cutoff: float = math.inf
    ) -> RelaxedSolution | None:
        """The exact optimum with these runs: over the lengths where some ``k`` can exceed ``n``.

        Only a plan better than ``cutoff`` is of interest: where the lengths are searched, None
        then also means that none is (a caller holding a plan of that value loses nothing).
        """
        if self.aligned_matters:
            return self.exact(runs, scale, least_scale=least_scale, cutoff=cutoff)
        return self.solve(runs, scale, least_scale=least_scale, above=cutoff)

    def capped(self, core: SharedCore) -> list[str]:
        """The core's non-batch subchains with a rate cap or a fixed rate (their ``k`` may exceed ``n``)."""
        subs = [self.by_name[name] for name in core.subchains]
        return [sub.name for sub in subs if not sub.batch and sub.min_period_ms > 0]

    @property
    def aligned_matters(self) -> bool:
        """Whether some shared ``k`` can exceed its ``n``: only then does the relaxation differ."""
        return any(self.capped(core) for core in self.layout.shared)

    def exact(
        self,
        runs: dict[str, int],
        scale: float,
        *,
        least_scale: bool,
        batch: Mapping[str, float] | None = None,
        lengths: Mapping[int, float] | None = None,
        fixed_cores: frozenset[int] = frozenset(),
        leaf: Callable[[dict[int, float]], RelaxedSolution | None] | None = None,
        relaxed_leaf: Callable[[dict[int, float]], float | None] | None = None,
        cutoff: float = math.inf,
    ) -> RelaxedSolution | None:
        """The best plan with these runs over every core's ``T`` (the module's search); None: infeasible,
        or no plan better than ``cutoff`` (lengths whose bound reaches it are not scored).

        Cores in ``fixed_cores`` keep the ``T`` that fits (a batch core's, chosen by the caller);
        ``leaf`` and ``relaxed_leaf`` score a choice of lengths exactly and relaxed (default: this
        module's :meth:`solve`; the relaxed one a lower bound that grows with every ``T``).
        """
        best: RelaxedSolution | None = None

        def threshold() -> float:
            return cutoff if best is None else best.objective

        if leaf is None:

            def leaf(chosen: dict[int, float]) -> RelaxedSolution | None:
                return self.solve(runs, scale, least_scale=least_scale, batch=batch, lengths=chosen, above=threshold())

        if relaxed_leaf is None:

            def relaxed_leaf(chosen: dict[int, float]) -> float | None:
                # A bound only: the estimate, lowered past its rounding (never prunes more than the exact one).
                found = self.solve(
                    runs, scale, least_scale=least_scale, batch=batch, lengths=chosen, aligned=False, above=-math.inf
                )
                return None if found is None else found.objective * (1 - QUICK_MARGIN)

        fractions = {name: 1.0 / runs[name] for name in self.shared if name in runs}  # a searched core's
        searched = [core for core in self.layout.shared if core.core not in fixed_cores and self.capped(core)]
        options = [
            length_candidates(
                self.length(core, fractions),
                [(runs[name], self.by_name[name].min_period_ms) for name in self.capped(core)],
            )
            for core in searched
        ]

        def visit(level: int, chosen: dict[int, float], known: float | None) -> None:
            """Search the cores from ``level`` on; ``known`` is ``chosen``'s bound (NaN: not computed)."""
            nonlocal best
            if level == len(searched):
                found = leaf(chosen)
                if found is not None and found.objective < threshold():
                    best = found
                return
            for index, length in enumerate(options[level]):
                trial = {**chosen, searched[level].core: length}
                # The cores not chosen yet at the least T: a lower bound. The first option is that
                # least T, so its bound is the one ``chosen`` already has.
                bound = known if index == 0 and not _unknown(known) else relaxed_leaf(trial)
                if bound is None or bound >= threshold():
                    break  # and every longer T of this core: the relaxation only grows with it
                visit(level + 1, trial, bound)

        visit(0, dict(lengths or {}), math.nan)
        return best

    def best(self, box: dict[str, tuple[int, int]], scale: float, *, least_scale: bool) -> Enumerated | None:
        """The best integer vector in ``box`` by evaluating them all at once; None if none is feasible.

        Ties go to the first vector in lexicographic order of ``self.shared``.
        """
        ranges = [range(box[name][0], box[name][1] + 1) for name in self.shared]
        grid = np.array(list(itertools.product(*ranges)), dtype=np.float64).reshape(-1, len(self.shared))
        column = {name: grid[:, index] for index, name in enumerate(self.shared)}
        fits = {core.core: self._fit(core, column) for core in self.layout.shared}
        value = self._values(column, fits, scale, least_scale=least_scale, aligned=False)
        if self.aligned_matters:  # ``value`` is the relaxation: evaluate exactly, the most promising first
            return self._best_aligned(grid, column, fits, value, scale, least_scale=least_scale)
        chosen = int(np.argmin(value))
        if not math.isfinite(float(value[chosen])):
            return None
        runs = {name: int(grid[chosen, index]) for index, name in enumerate(self.shared)}
        solution = self.solve(runs, scale, least_scale=least_scale)
        if solution is None:  # pragma: no cover - the vector was feasible above
            return None
        return Enumerated(runs, solution, len(grid))

    def _fit(self, core: SharedCore, column: Mapping[str, Floats]) -> Floats:
        """Per vector, the shortest ``T`` that fits one core (:meth:`length` over arrays of runs)."""
        members = [self.by_name[name] for name in core.subchains]
        load = sum((sub.compute_ms / column[sub.name] for sub in members), np.zeros(len(column[members[0].name])))
        return (load + len(members) * self.schedule.switch_ms) / (1.0 - self.schedule.slack)

    def _values(
        self,
        column: Mapping[str, Floats],
        lengths: Mapping[int, Floats],
        scale: float,
        *,
        least_scale: bool,
        aligned: bool,
        feasibility: float = FEASIBILITY,
    ) -> Floats:
        """:meth:`solve`'s value of each vector at each core's ``T`` in ``lengths``, as arrays (+inf where
        it misses the bounds scaled by ``scale``, within ``feasibility``); ``aligned=False`` the relaxation's."""
        count = len(next(iter(lengths.values())))
        latency: dict[str, Floats] = {name: np.full(count, t.latency_ms) for name, t in self.dedicated.items()}
        period: dict[str, Floats] = {name: np.full(count, t.period_ms) for name, t in self.dedicated.items()}
        for core in self.layout.shared:
            length = lengths[core.core]
            for name in core.subchains:
                sub = self.by_name[name]
                latency[name] = length * column[name]
                if aligned and sub.min_period_ms > 0:  # k = max(n, ceil(p_min / T)): aligned_every's
                    every = np.ceil(sub.min_period_ms / length * (1 - EVERY_TOLERANCE))
                    period[name] = np.maximum(column[name], every) * length
                else:
                    period[name] = np.maximum(latency[name], sub.min_period_ms)  # = the latency without a cap
        responses = {}
        needed: Floats = np.ones(count)
        for index in {term.chain for term in self.problem.response_terms} | {
            bound.chain for bound in self.problem.response_bounds
        }:
            form = self.problem.chain_forms[index]
            total = sum((latency[name] for name in form.latency_of), np.full(count, form.constant))
            total = sum((period[name] for name in form.period_of), total)
            longest = np.full(count, form.floor)
            for name in form.longest_of:
                longest = np.maximum(longest, period[name])
            responses[index] = total + longest
        for bound in self.problem.response_bounds:
            needed = np.maximum(needed, responses[bound.chain] / bound.max_response_ms)
        for sub in self.problem.subchains:
            if sub.max_period_ms < math.inf:
                needed = np.maximum(needed, period[sub.name] / sub.max_period_ms)
        if least_scale:
            return needed
        if self.problem.weighted:
            value = sum((term.weight * responses[term.chain] for term in self.problem.response_terms), np.zeros(count))
            value = sum((term.weight * period[term.subchain] for term in self.problem.period_terms), value)
        else:
            value = sum(lengths.values(), np.zeros(count))
        return np.where(needed <= scale * (1 + feasibility), value, np.inf)

    def _best_aligned(
        self,
        grid: Floats,
        column: Mapping[str, Floats],
        fits: Mapping[int, Floats],
        relaxed: Floats,
        scale: float,
        *,
        least_scale: bool,
    ) -> Enumerated | None:
        """The best vector by :meth:`exact`, tried in order of a lower bound until that reaches the best.

        The bound is each vector's exact value computed at once as arrays, where the vectors times their
        candidate lengths are few (:data:`ALIGNED_AT_ONCE`): only the vectors within rounding of the best are
        then searched one by one, so the answer and its ties are :meth:`exact`'s.  Else the relaxed value.
        """
        bounds, margin = relaxed, 0.0
        exact = self._exact_values(column, fits, scale, least_scale=least_scale)
        if exact is not None:
            bounds, margin = exact, NEAR_TIE
        best: tuple[float, int, dict[str, int], RelaxedSolution] | None = None
        for row in np.argsort(bounds, kind="stable"):
            bound = float(bounds[row])
            if not math.isfinite(bound) or (best is not None and bound > best[0] + abs(best[0]) * margin):
                break
            runs = {name: int(grid[row, index]) for index, name in enumerate(self.shared)}
            # Only a plan as good as the best found is of interest (an equal one may win the tie on its row).
            cutoff = math.inf if best is None else math.nextafter(best[0], math.inf)
            found = self.exact(runs, scale, least_scale=least_scale, cutoff=cutoff)
            if found is not None and (best is None or (found.objective, int(row)) < (best[0], best[1])):
                best = (found.objective, int(row), runs, found)
        return None if best is None else Enumerated(best[2], best[3], len(grid))

    def _exact_values(
        self, column: Mapping[str, Floats], fits: Mapping[int, Floats], scale: float, *, least_scale: bool
    ) -> Floats | None:
        """Each vector's exact value, the least over its cores' candidate lengths
        (:func:`~catanc.planning.stage2.base.length_candidates`) as arrays; None where they are too many."""
        count = len(next(iter(fits.values())))
        rows = np.arange(count)
        lengths = dict(fits)
        for core in self.layout.shared:
            capped = self.capped(core)
            if not capped:
                continue
            fit = fits[core.core]
            options = [fit]  # the shortest T that fits, then each p_min / j above it that some k >= n allows
            for name in capped:
                min_period = self.by_name[name].min_period_ms
                most = np.floor(min_period / fit * (1 + EVERY_TOLERANCE))
                for j in range(1, int(np.max(most)) + 1):
                    length = np.full(count, min_period / j)
                    usable = (j >= np.maximum(column[name], 1)) & (j <= most) & (length > fit)
                    options.append(np.where(usable, length, np.nan))
            width = len(options)
            if len(rows) * width > ALIGNED_AT_ONCE:
                return None
            table = np.stack(options, axis=1)  # per vector, its candidate lengths of this core
            lengths = {key: np.repeat(value, width) for key, value in lengths.items()}
            lengths[core.core] = table[rows].reshape(-1)
            rows = np.repeat(rows, width)
        usable = ~np.isnan(sum(lengths.values(), np.zeros(len(rows))))
        spread = {name: values[rows] for name, values in column.items()}
        filled = {key: np.where(usable, value, 1.0) for key, value in lengths.items()}
        # Bounds met within rounding count as met here: :meth:`exact` decides (a bound, never a verdict).
        scored = self._values(
            spread, filled, scale, least_scale=least_scale, aligned=True, feasibility=FEASIBILITY + NEAR_TIE
        )
        values: Floats = np.where(usable, scored, np.inf).reshape(count, -1).min(axis=1)
        return values

    @staticmethod
    def size(box: dict[str, tuple[int, int]]) -> int:
        return math.prod(high - low + 1 for low, high in box.values())


def _unknown(bound: float | None) -> bool:
    return bound is not None and math.isnan(bound)
