"""What Stage I returns, whichever method found it."""

from __future__ import annotations

from dataclasses import dataclass

from catanc.planning.stage1.estimate import Allocation


@dataclass(frozen=True)
class Stage1Result:
    """An allocation with its Stage I objective and how sure the solver is of it."""

    allocation: Allocation
    objective: float  # Stage I's estimate for this allocation (ms), re-evaluated by the model
    constraint_scale: float  # factor the spec's bounds were scaled by (1.0: as written)
    optimal: bool  # proven optimal
    gap: float | None  # relative optimality gap when stopped early (None: unknown)
    method: str  # "milp/highs", "milp/cbc" or "exhaustive"
    candidates: int = 0  # allocations scored (exhaustive) or 0
    model_objective: float | None = None  # the MILP's own value for it, without the tie term (a self-check)

    @property
    def warnings(self) -> list[str]:
        notes = []
        if self.constraint_scale > 1.0:
            notes.append(
                f"the bounds cannot all be met: Stage I scaled every bound by {self.constraint_scale:.4g} "
                "(chain response bounds and rate floors)"
            )
        if not self.optimal:
            gap = "unknown" if self.gap is None else f"{self.gap:.2%}"
            notes.append(f"Stage I stopped at its time limit: best allocation found, optimality gap {gap}")
        return notes
