"""Re-planning as compute times drift: what the runtime enforcer calls every few seconds.

A :class:`Replanner` plans once (both stages, runners-up included) and then
keeps its problem and every Stage II model it built:

- :meth:`Replanner.resolve` re-solves Stage II on the current allocation with
  new compute times (docs/explanation/model.md section 5: every 5 s).  The model is not
  rebuilt: only its numbers change, and the previous plan's whole runs are
  the branch and bound's first incumbent.
- :meth:`Replanner.reallocate` runs Stage I and the runners-up again (every
  20 s, or when the number of cores changes), reusing the models of layouts
  it has seen; the current layout's search starts from the current runs.

Both stop at a plan within :data:`RUNTIME_GAP` of the optimum; the first plan
is exact, as ``catanc compile``'s.

Both use the direct conic model (:mod:`catanc.planning.stage2.conic`), which the
tests hold to the cvxpy model's optimum.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

from catanc.errors import UsageError
from catanc.model.build import build_problem
from catanc.model.problem import Problem
from catanc.planning.planner import STAGE2_RELAXATIONS, assemble, conic_model, plan_problem
from catanc.planning.stage2.base import Layout, SharedCore, Stage2Model
from catanc.planning.stage2.solve import solve_layout
from catanc.planning.types import Plan, TwoStageComparison
from catanc.spec.language import Spec

RUNTIME_GAP = 1e-2
"""Re-plans stop at an integer plan proven within 1% of Stage II's optimum. The compute times they
plan with are p95s of 50 noisy samples, far coarser than that. With aligned triggers (a capped
subchain's ``p = k T``, docs/explanation/model.md section 4) the relaxation leaves ``k`` continuous, and on
nav2d its bound sits up to ~0.7% below the integer plan (GP's 1 Hz cap: ``p`` in ``[1000, 1000 +
T)``): proving 0.01% took ~35 relaxations and ~20 exact evaluations (~40 ms) a re-plan, 1% takes
~2 of each (~1.1 ms; main's 0.01% before aligned triggers: ~0.7 ms)."""


class Replanner:
    """One app's planner, kept warm between re-plans."""

    def __init__(
        self,
        spec: Spec,
        cores: int,
        *,
        stage1_method: str = "auto",
        solver: str | None = None,
        time_limit_s: float | None = None,
        gap: float = RUNTIME_GAP,
    ) -> None:
        """``gap``: re-plans may stop at an integer plan proven within this relative distance of
        Stage II's optimum, ``(plan - optimum) / plan <= gap`` (0: exact, as :func:`catanc.plan`
        and the first plan always are)."""
        if not (0.0 <= gap < 1.0):
            raise UsageError(f"gap must be in [0, 1), got {gap!r}")
        self.gap = gap
        self.spec = spec
        self._stage1_method, self._solver, self._time_limit_s = stage1_method, solver, time_limit_s
        self.spec_problem: Problem = build_problem(spec)  # with the spec's compute times
        self._problem = self.spec_problem
        self._importance = self._problem.importance()
        self._models: dict[Layout, Stage2Model] = {}
        self.plan: Plan = self._allocate(cores, first=True)

    @property
    def cores(self) -> int:
        return self.plan.cores

    @property
    def problem(self) -> Problem:
        """The problem with the latest compute times."""
        return self._problem

    @property
    def layout(self) -> Layout:
        """Where the current plan runs each subchain (its Stage II model is ``models[layout]``)."""
        return Layout(
            self.plan.allocation.dedicated,
            tuple(SharedCore(core.core, core.order) for core in self.plan.shared_cores),
        )

    @property
    def models(self) -> Mapping[Layout, Stage2Model]:
        """The Stage II models built so far, by layout (each is built once)."""
        return self._models

    def resolve(self, compute_ms: Mapping[str, float]) -> Plan:
        """Re-plan Stage II with new compute times (ms, one thread) for some scheduled nodes.

        The other nodes keep their last times; the allocation stays. Raises
        :class:`~catanc.errors.UsageError` for an unknown node or a bad time.
        """
        self._problem = self._problem.with_compute(compute_ms)
        current = self.plan
        layout = self.layout
        result = solve_layout(
            self._problem,
            layout,
            self.spec.schedule,
            conic_model(self._models, self._problem, layout, self.spec.schedule),
            start=current.runs or None,
            spacing=current.every or None,
            gap=self.gap,
            node_limit=STAGE2_RELAXATIONS,
        )
        assert result is not None  # pragma: no cover - only a ``beat`` makes it None
        self.plan = assemble(
            problem=self._problem,
            schedule=self.spec.schedule,
            cores=current.cores,
            result=result,
            allocation=current.allocation,
            first=current.stage1,
            comparison=TwoStageComparison(
                allocations=1, planned=1, complete=True, two_stage_objective=None, two_stage_scale=None
            ),
            importance=self._importance,
            orders={core.core: core.order for core in current.shared_cores},
        )
        return self.plan

    def reallocate(self, compute_ms: Mapping[str, float] | None = None, cores: int | None = None) -> Plan:
        """Re-plan both stages (Stage I, its runners-up, Stage II), optionally with new times or cores."""
        if compute_ms:
            self._problem = self._problem.with_compute(compute_ms)
        self.plan = self._allocate(self.plan.cores if cores is None else cores)
        return self.plan

    def reconfigure(self, switch_ms: float, slack: float, compute_ms: Mapping[str, float] | None = None) -> Plan:
        """Plan both stages from now on with another ``switch_ms`` and ``slack`` (the runtime's measured costs,
        docs/explanation/model.md section 5), optionally with new times; the problem's compute times are kept.

        The Stage II models hold the old costs, so they are built again as the search meets their layouts (each
        ~1 ms), and the search starts from the current plan's layout and runs (evaluated under the new costs,
        dropped if they no longer fit), stopping within the gap, as :meth:`reallocate` does: a fresh
        :class:`Replanner` would plan exactly, with every runner-up, ~20x the CPU (nav2d)."""
        schedule = self.spec.schedule.model_copy(update={"switch_ms": switch_ms, "slack": slack})
        problem = replace(self._problem, slack=slack)
        if compute_ms:
            problem = problem.with_compute(compute_ms)
        kept = self.spec, self._problem, self._models
        self.spec, self._problem, self._models = self.spec.model_copy(update={"schedule": schedule}), problem, {}
        try:
            self.plan = self._allocate(self.plan.cores)
        except Exception:  # no plan with the new costs: the replanner stays as it was, as its plan does
            self.spec, self._problem, self._models = kept
            raise
        return self.plan

    def _allocate(self, cores: int, *, first: bool = False) -> Plan:
        return plan_problem(
            self._problem,
            self.spec.schedule,
            cores,
            stage1_method=self._stage1_method,
            solver=self._solver,
            time_limit_s=self._time_limit_s,
            backend="conic",
            compare_offered=False,
            models=self._models,
            gap=0.0 if first else self.gap,
            start=None if first else (self.layout, self.plan.runs),
        )
