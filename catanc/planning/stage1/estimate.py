"""Stage I's model (docs/explanation/model.md section 3): crude periods for every way a subchain can run.

Each subchain either has ``k >= 1`` cores of its own (*dedicated*) or shares
one core with ``m - 1`` others (*shared*, ``m >= 2``).  Stage I estimates:

- shared in a group of ``m``: period and latency ``c(S) * m`` (fair share);
- dedicated on ``k`` cores: Eq. 1's period (divided by ``1 - slack``) and
  latency for the best ``q``;
- then the period is raised to the rate cap's shortest period.

A subchain alone on a core is *dedicated* with ``k = 1`` (the fair share of
a group of one is the same estimate), so every allocation has one spelling.
The MILP and the exhaustive enumerator both score allocations with
:func:`evaluate`, so they optimise the same function.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from catanc.model.metrics import Timing, bound_scale, capped_dedicated, objective
from catanc.model.problem import Problem, Subchain
from catanc.planning.stage1.together import pack_groups

SCALE_SLACK = 1e-6
"""Relative slack on the smallest bound scale when optimising under it (solver tolerance)."""

TIE_WEIGHT = 1e-8
"""Size of the tie-breaking preference relative to the objective's scale."""


@dataclass(frozen=True, order=True)
class Option:
    """How one subchain runs: shared in a group of ``size``, or on ``size`` cores of its own."""

    shared: bool
    size: int

    def __str__(self) -> str:
        return f"shared by {self.size}" if self.shared else f"{self.size} core{'s' if self.size > 1 else ''}"


@dataclass(frozen=True)
class Allocation:
    """Stage I's answer: dedicated core counts and shared groups (no core indices yet)."""

    dedicated: tuple[tuple[str, int], ...]  # (subchain, cores), in spec order
    groups: tuple[tuple[str, ...], ...]  # members in spec order; groups ordered by first member

    @property
    def cores_used(self) -> int:
        return sum(k for _, k in self.dedicated) + len(self.groups)

    def options(self) -> dict[str, Option]:
        found = {name: Option(False, k) for name, k in self.dedicated}
        found.update({name: Option(True, len(group)) for group in self.groups for name in group})
        return found

    def core_indices(self) -> dict[str, tuple[int, ...]]:
        """Cores per subchain, by the documented rule (docs/explanation/model.md section 3).

        Dedicated subchains first, in spec order, each taking the lowest free
        indices; then each shared group, in order of its first member, one core.
        """
        cores: dict[str, tuple[int, ...]] = {}
        next_core = 0
        for name, k in self.dedicated:
            cores[name] = tuple(range(next_core, next_core + k))
            next_core += k
        for group in self.groups:
            for name in group:
                cores[name] = (next_core,)
            next_core += 1
        return cores


def allocation_from_options(problem: Problem, options: Mapping[str, Option]) -> Allocation:
    """The canonical allocation for per-subchain options.

    Stage I's estimate depends only on each subchain's option, not on who its
    partners are, so subchains that share in groups of ``m`` are grouped in
    spec order: the first ``m`` together, then the next ``m``.
    Subchains that must share one core (an executor's, :mod:`catanc.planning.stage1.together`)
    are kept in one group; raises :class:`ValueError` when no grouping does.
    """
    dedicated = [(sub.name, options[sub.name].size) for sub in problem.subchains if not options[sub.name].shared]
    groups = pack_groups(problem, options)
    if groups is None:
        raise ValueError("these options cannot form whole groups with every executor's subchains together")
    return Allocation(tuple(dedicated), tuple(groups))


def options_for(problem: Problem, cores: int) -> list[Option]:
    """Every option a subchain may take on ``cores`` cores.

    With ``N >= K >= 2`` every core is used, so at least one subchain is
    outside the largest group (it may take all the other cores): a group holds
    at most ``N - 1``.  On one core, or with idle cores allowed, it may hold all.
    """
    count = len(problem.subchains)
    largest_group = count - 1 if count >= cores >= 2 else count
    return [Option(False, k) for k in range(1, cores + 1)] + [Option(True, m) for m in range(2, largest_group + 1)]


def option_timing(sub: Subchain, option: Option, slack: float) -> Timing:
    """Stage I's estimate of a subchain's period and processing latency under ``option``.

    A dedicated estimate keeps the schedule's ``slack`` idle, as Stage II does (docs/explanation/model.md 3, 4).
    """
    if option.shared:
        fair = sub.compute_ms * option.size
        return Timing(max(fair, sub.min_period_ms), fair)
    return capped_dedicated(sub, option.size, slack).timing


OptionTable = dict[str, dict[Option, Timing]]


def option_table(problem: Problem, cores: int) -> OptionTable:
    """Every subchain's estimate under every option (the MILP's coefficients)."""
    options = options_for(problem, cores)
    return {
        sub.name: {option: option_timing(sub, option, problem.slack) for option in options} for sub in problem.subchains
    }


@dataclass(frozen=True)
class Evaluation:
    objective: float  # Stage I's objective (ms)
    scale: float  # smallest factor on the bounds these estimates meet


def evaluate(problem: Problem, table: OptionTable, options: Mapping[str, Option]) -> Evaluation:
    """Score one allocation with the analytic model."""
    timings = {name: table[name][option] for name, option in options.items()}
    return Evaluation(objective(problem, timings), bound_scale(problem, timings))


def tie_rank(problem: Problem, options: Mapping[str, Option], cores: int) -> float:
    """A preference in [0, 1] among allocations of equal objective (the documented tie rule).

    Lower is preferred: subchains earlier in the spec share less and use
    fewer cores (idle cores, where allowed, save power).
    """
    count = len(problem.subchains)
    return sum(option_rank(i, count, cores, options[sub.name]) for i, sub in enumerate(problem.subchains))


def option_rank(index: int, count: int, cores: int, option: Option) -> float:
    """One subchain's share of :func:`tie_rank`: sharing costs most, then each core."""
    cost = 1.0 if option.shared else option.size / (cores + 1)
    return (count - index) / count * cost / count


def objective_scale(problem: Problem, table: OptionTable) -> float:
    """A size for the objective: weights times the longest estimates (for the tie weight)."""
    weight = math.fsum(t.weight for t in problem.response_terms) + math.fsum(t.weight for t in problem.period_terms)
    longest = max((t.period_ms + t.latency_ms for row in table.values() for t in row.values()), default=0.0)
    fixed = max(problem.fixed_periods_ms.values(), default=0.0)
    return (weight + 1.0) * (longest + 2 * fixed + 1.0)
