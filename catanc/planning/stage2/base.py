"""What every Stage II model shares: the layout it plans, the relaxed solution, the model interface.

Two models implement :class:`Stage2Model`: :class:`~catanc.planning.stage2.relaxed.RelaxedStage2`
(cvxpy, the reference) and :class:`~catanc.planning.stage2.conic.ConicStage2` (the same
program written directly for Clarabel, for the runtime). Neither this module
nor the conic model imports cvxpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

from catanc.model.problem import Problem, Subchain
from catanc.planning.stage1.estimate import Allocation
from catanc.spec.language import Schedule


@dataclass(frozen=True)
class SharedCore:
    """One shared core and its subchains, in schedule order."""

    core: int
    subchains: tuple[str, ...]


@dataclass(frozen=True)
class Layout:
    """Where every subchain runs: dedicated core counts and shared cores."""

    dedicated: tuple[tuple[str, int], ...]  # (subchain, cores)
    shared: tuple[SharedCore, ...]

    @property
    def shared_names(self) -> list[str]:
        """Every shared subchain, core by core, in schedule order."""
        return [name for core in self.shared for name in core.subchains]

    @property
    def dedicated_names(self) -> list[str]:
        return [name for name, _ in self.dedicated]

    def check_shared(self) -> None:
        if not self.shared:
            raise ValueError("Stage II's GP is for shared cores; this layout has none")

    @classmethod
    def from_allocation(cls, allocation: Allocation) -> Layout:
        indices = allocation.core_indices()
        shared = tuple(SharedCore(indices[group[0]][0], group) for group in allocation.groups)
        return cls(allocation.dedicated, shared)


@dataclass(frozen=True)
class RelaxedSolution:
    core_period_ms: dict[int, float]  # T per shared core
    fraction: dict[str, float]  # f per shared subchain
    period_ms: dict[str, float]  # p per shared subchain
    objective: float  # the GP's optimal value (ms)


class LayoutModel:
    """What every Stage II model knows of its layout: the :class:`Stage2Model` attributes, set once."""

    def __init__(self, problem: Problem, layout: Layout, schedule: Schedule) -> None:
        layout.check_shared()
        self.problem = problem
        self.layout = layout
        self.schedule = schedule
        self.shared_names = layout.shared_names
        self.dedicated_names = layout.dedicated_names
        # Non-batch subchains run whole runs, n = 1/f: the integer search boxes their f.
        self.integral = [name for name in self.shared_names if not problem.subchain(name).batch]


class Stage2Model(Protocol):
    """The relaxed Stage II program for one layout, built once and re-solved with new numbers.

    ``set_numbers`` loads compute times (and the dedicated constants they imply),
    ``set_box`` confines each non-batch ``n = 1/f`` (those named in ``integral``),
    ``solve`` minimises the objective with every bound scaled by ``scale``, and
    ``solve_least_scale`` minimises the scale the bounds need (its ``objective``);
    both return None when infeasible.
    """

    @property
    def problem(self) -> Problem: ...
    @property
    def layout(self) -> Layout: ...
    @property
    def schedule(self) -> Schedule: ...
    @property
    def shared_names(self) -> list[str]: ...
    @property
    def dedicated_names(self) -> list[str]: ...
    @property
    def integral(self) -> list[str]: ...

    def set_numbers(self, problem: Problem) -> None: ...
    def set_box(self, box: Mapping[str, tuple[int, int]]) -> None: ...
    def solve(self, scale: float = 1.0) -> RelaxedSolution | None: ...
    def solve_least_scale(self) -> RelaxedSolution | None: ...


EVERY_TOLERANCE = 1e-9
"""Relative: ``p_min / T`` this close above a whole number ``j`` counts as ``j`` (``T = p_min / j``)."""


def aligned_every(runs: int, length: float, min_period_ms: float) -> int:
    """``k``: the fewest schedule periods between a shared subchain's triggers (docs/explanation/model.md section 4).

    Its head is triggered at the start of its slot every ``k`` periods, ``k >= n`` (a run takes
    ``n`` periods) and ``k T >= p_min`` (its rate cap or fixed rate): ``p = k T``.
    """
    if min_period_ms <= 0:
        return runs
    return max(runs, math.ceil(min_period_ms / length * (1 - EVERY_TOLERANCE)))


def length_candidates(length: float, members: list[tuple[int, float]]) -> list[float]:
    """The schedule lengths ``T >= length`` worth trying on one core with these runs, ascending.

    ``members`` are its non-batch subchains' ``(n, p_min)``.  With every ``n`` fixed, each term
    and bound grows with ``T`` except where a member's ``k = max(n, ceil(p_min / T))`` drops,
    at ``T = p_min / j``: the best ``T`` is the shortest that fits, or one of those breakpoints.
    """
    found = {length}
    for runs, min_period in members:
        if min_period <= 0:
            continue
        most = math.floor(min_period / length * (1 + EVERY_TOLERANCE))
        found.update(min_period / j for j in range(max(runs, 1), most + 1) if min_period / j > length)
    return sorted(found)


def schedule_length(
    core: SharedCore, fractions: Mapping[str, float], by_name: Mapping[str, Subchain], schedule: Schedule
) -> float:
    """The shortest ``T`` that fits every slice ``f c``, the switches and the slack on one shared core."""
    load = math.fsum(fractions[name] * by_name[name].compute_ms for name in core.subchains)
    return (load + len(core.subchains) * schedule.switch_ms) / (1.0 - schedule.slack)
