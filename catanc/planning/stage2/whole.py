"""Stage II with every ``n_i = 1/f_i`` fixed, in closed form (no batch subchain on a shared core).

With every ``f`` fixed, each term and bound only grows with the schedule
length ``T``, so the relaxation's optimum takes the shortest ``T`` that fits
the slices, switches and slack, then ``p = max(T n, p_min)`` and latency
``T n``: what the GP's constraints say, solved exactly.  That gives

- :class:`WholeRuns.solve`: one integer vector, evaluated without a solver
  (the leaves of the branch and bound);
- :class:`WholeRuns.best`: every integer vector of a small box at once, as
  numpy arrays: the exact integer optimum with no solver at all, used when
  the box holds at most :data:`ENUMERATE_UP_TO` vectors (VR on one core: 33).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from catanc.core.metrics import Timing, bound_scale, capped_dedicated, objective
from catanc.core.problem import Problem
from catanc.planning.stage2.base import RelaxedSolution, SharedCore, Stage2Model, schedule_length

ENUMERATE_UP_TO = 4096
"""Evaluate every integer vector at once when a box holds at most this many (a few hundred µs)."""

FEASIBILITY = 1e-9
"""Relative slack on the bounds when fixed runs are checked (rounding only)."""

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

    @staticmethod
    def applies(model: Stage2Model, problem: Problem) -> bool:
        """Closed forms hold when no shared subchain is batch (a batch ``f`` stays free)."""
        return not any(problem.subchain(name).batch for core in model.layout.shared for name in core.subchains)

    def length(self, core: SharedCore, fractions: Mapping[str, float]) -> float:
        """One shared core's schedule length ``T`` with these fractions."""
        return schedule_length(core, fractions, self.by_name, self.schedule)

    def solve(
        self, runs: dict[str, int], scale: float, *, least_scale: bool, batch: Mapping[str, float] | None = None
    ) -> RelaxedSolution | None:
        """The relaxation's optimum with these runs (None: they miss the scaled bounds).

        ``batch`` gives each batch subchain's fraction, chosen by the caller
        (:mod:`catanc.planning.stage2.onebatch`); without batch subchains it is empty.
        """
        batch = batch or {}
        timings = dict(self.dedicated)
        lengths: dict[int, float] = {}
        fractions = {name: batch[name] if name in batch else 1.0 / runs[name] for name in self.shared}
        for core in self.layout.shared:
            lengths[core.core] = self.length(core, fractions)
            for name in core.subchains:
                latency = lengths[core.core] / batch[name] if name in batch else lengths[core.core] * runs[name]
                timings[name] = Timing(max(latency, self.by_name[name].min_period_ms), latency)
        needed = bound_scale(self.problem, timings)
        if least_scale:
            value = max(1.0, needed)
        elif needed > scale * (1 + FEASIBILITY):
            return None
        else:
            value = objective(self.problem, timings) if self.problem.weighted else math.fsum(lengths.values())
        return RelaxedSolution(
            core_period_ms=lengths,
            fraction=fractions,
            period_ms={name: timings[name].period_ms for name in self.shared},
            objective=value,
        )

    def best(self, box: dict[str, tuple[int, int]], scale: float, *, least_scale: bool) -> Enumerated | None:
        """The best integer vector in ``box`` by evaluating them all at once; None if none is feasible.

        Ties go to the first vector in lexicographic order of ``self.shared``.
        """
        ranges = [range(box[name][0], box[name][1] + 1) for name in self.shared]
        grid = np.array(list(itertools.product(*ranges)), dtype=np.float64).reshape(-1, len(self.shared))
        column = {name: grid[:, index] for index, name in enumerate(self.shared)}
        usable = 1.0 - self.schedule.slack
        count = len(grid)
        latency: dict[str, Floats] = {name: np.full(count, t.latency_ms) for name, t in self.dedicated.items()}
        period: dict[str, Floats] = {name: np.full(count, t.period_ms) for name, t in self.dedicated.items()}
        lengths: list[Floats] = []
        for core in self.layout.shared:
            members = [self.problem.subchain(name) for name in core.subchains]
            load = sum((sub.compute_ms / column[sub.name] for sub in members), np.zeros(count))
            length = (load + len(members) * self.schedule.switch_ms) / usable
            lengths.append(length)
            for sub in members:
                latency[sub.name] = length * column[sub.name]
                period[sub.name] = np.maximum(latency[sub.name], sub.min_period_ms)
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
            value = needed
        else:
            if self.problem.weighted:
                value = sum(
                    (term.weight * responses[term.chain] for term in self.problem.response_terms), np.zeros(count)
                )
                value = sum((term.weight * period[term.subchain] for term in self.problem.period_terms), value)
            else:
                value = sum(lengths, np.zeros(count))
            value = np.where(needed <= scale * (1 + FEASIBILITY), value, np.inf)
        chosen = int(np.argmin(value))
        if not math.isfinite(float(value[chosen])):
            return None
        runs = {name: int(grid[chosen, index]) for index, name in enumerate(self.shared)}
        solution = self.solve(runs, scale, least_scale=least_scale)
        if solution is None:  # pragma: no cover - the vector was feasible above
            return None
        return Enumerated(runs, solution, len(grid))

    @staticmethod
    def size(box: dict[str, tuple[int, int]]) -> int:
        return math.prod(high - low + 1 for low, high in box.values())
