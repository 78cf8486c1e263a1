"""Stage I: which subchains get cores of their own, and which share one (catan-model.md section 3).

:func:`allocate` is the entry point; ``method="milp"`` (default) solves the
MILP of :mod:`catanc.stage1.milp`, ``method="exhaustive"`` scores every
allocation (:mod:`catanc.stage1.exhaustive`) and is the MILP's test oracle.
"""

from __future__ import annotations

from catanc.errors import UsageError
from catanc.problem import Problem
from catanc.stage1.estimate import Allocation, Option
from catanc.stage1.exhaustive import solve_exhaustive
from catanc.stage1.result import Stage1Result

METHODS = ("milp", "exhaustive")


def allocate(
    problem: Problem,
    cores: int,
    *,
    method: str = "milp",
    solver: str | None = None,
    time_limit_s: float | None = None,
) -> Stage1Result:
    """Stage I's allocation of ``problem``'s subchains to ``cores`` identical cores."""
    if cores < 1:
        raise UsageError(f"--cores must be at least 1, got {cores}")
    if method == "exhaustive":
        return solve_exhaustive(problem, cores)
    if method != "milp":
        raise UsageError(f"unknown Stage I method {method!r}; choose one of {', '.join(METHODS)}")
    from catanc.stage1 import milp  # noqa: PLC0415 - pulp and HiGHS load only when a MILP is solved

    return milp.solve_milp(
        problem,
        cores,
        solver=solver or milp.DEFAULT_SOLVER,
        time_limit_s=milp.DEFAULT_TIME_LIMIT_S if time_limit_s is None else time_limit_s,
    )


__all__ = ["METHODS", "Allocation", "Option", "Stage1Result", "allocate"]
