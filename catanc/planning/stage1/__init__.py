"""Stage I: which subchains get cores of their own, and which share one (docs/explanation/model.md section 3).

:func:`allocate` is the entry point. ``method="milp"`` solves the MILP of
:mod:`catanc.planning.stage1.milp`; ``method="exhaustive"`` scores every allocation
(:mod:`catanc.planning.stage1.exhaustive`) and is the MILP's test oracle; the default
``method="auto"`` enumerates where that is faster than the MILP (up to
:data:`AUTO_EXHAUSTIVE` subchains and cores: benchmarks/RESULTS.md) and solves the
MILP otherwise. Both are exact and break ties by the same rule.
"""

from __future__ import annotations

from collections.abc import Sequence

from catanc.errors import UsageError
from catanc.model.problem import Problem
from catanc.planning.stage1.estimate import Allocation, Option
from catanc.planning.stage1.exhaustive import solve_exhaustive
from catanc.planning.stage1.result import Stage1Result

METHODS = ("auto", "milp", "exhaustive")
SOLVERS = ("highs", "cbc")

AUTO_EXHAUSTIVE = (6, 4)
"""``auto`` enumerates up to this many subchains and cores (at most ~130 allocations, under 10 ms)."""


def allocate(
    problem: Problem,
    cores: int,
    *,
    method: str = "auto",
    solver: str | None = None,
    time_limit_s: float | None = None,
) -> Stage1Result:
    """Stage I's allocation of ``problem``'s subchains to ``cores`` identical cores."""
    if cores < 1:
        raise UsageError(f"--cores must be at least 1, got {cores}")
    if method not in METHODS:
        raise UsageError(f"unknown Stage I method {method!r}; choose one of {', '.join(METHODS)}")
    if solver is not None and solver not in SOLVERS:
        raise UsageError(f"unknown Stage I solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    most_subchains, most_cores = AUTO_EXHAUSTIVE
    small = len(problem.subchains) <= most_subchains and cores <= most_cores
    if method == "exhaustive" or (method == "auto" and small):
        return solve_exhaustive(problem, cores)
    from catanc.planning.stage1 import milp  # noqa: PLC0415 - pulp and HiGHS load only when a MILP is solved

    return milp.solve_milp(
        problem,
        cores,
        solver=solver or milp.DEFAULT_SOLVER,
        time_limit_s=milp.DEFAULT_TIME_LIMIT_S if time_limit_s is None else time_limit_s,
    )


def next_best(
    problem: Problem,
    cores: int,
    found: Sequence[Allocation],
    *,
    solver: str | None = None,
    time_limit_s: float | None = None,
) -> Stage1Result:
    """The best allocation by Stage I's estimate other than those ``found`` (the MILP with no-good cuts)."""
    from catanc.planning.stage1 import milp  # noqa: PLC0415 - pulp and HiGHS load only when a MILP is solved

    return milp.solve_milp(
        problem,
        cores,
        solver=solver or milp.DEFAULT_SOLVER,
        time_limit_s=milp.DEFAULT_TIME_LIMIT_S if time_limit_s is None else time_limit_s,
        exclude=found,
    )


__all__ = [
    "AUTO_EXHAUSTIVE",
    "METHODS",
    "SOLVERS",
    "Allocation",
    "Option",
    "Stage1Result",
    "allocate",
    "next_best",
]
