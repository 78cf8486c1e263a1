"""What a plan is: the planner's answer, as plain frozen data.

Everything downstream of planning (the explanation, the runtime table, the
deployment, the runtime schedule, the simulator) reads a plan through these
types, so they import no solver: this module depends on the problem's types
and Stage I's answer only.  :func:`catanc.planning.planner.plan` makes them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from catanc.model.priorities import resting_fifo
from catanc.planning.stage1.estimate import Allocation
from catanc.planning.stage1.result import Stage1Result


@dataclass(frozen=True)
class SubchainPlan:
    name: str
    nodes: tuple[str, ...]
    cores: tuple[int, ...]
    shared: bool
    threads: int  # Eq. 1's q (1 on a shared core)
    period_ms: float
    latency_ms: float
    fraction: float  # f: share of one run per schedule period (1.0 when dedicated)
    priority: int  # higher steals from lower
    every: int | None = None  # k: a shared non-batch subchain is triggered at its slot every k periods
    # The period once an executor's thread has taken its share (docs/explanation/executor-planning.md: triggers
    # lost while another member holds the thread, slots a late member steals); None where that is
    # period_ms.  It may be inf: a subchain predicted to get no run at all.
    period_as_run_ms: float | None = None

    @property
    def rate_as_run_hz(self) -> float:
        """The runs a second the plan promises: its rate, less what an executor's thread takes (0: none)."""
        period = self.period_ms if self.period_as_run_ms is None else self.period_as_run_ms
        return 1000.0 / period if math.isfinite(period) else 0.0


@dataclass(frozen=True)
class CorePlan:
    core: int
    period_ms: float  # T, the schedule's length
    order: tuple[str, ...]


@dataclass(frozen=True)
class ChainPlan:
    nodes: tuple[str, ...]
    subchains: tuple[str, ...]
    latency_ms: float
    period_ms: float
    response_ms: float


@dataclass(frozen=True)
class OfferedChoice:
    """A subchain whose driver offers rates: the one planned, and what a free rate would have given."""

    subchain: str
    node: str  # whose constraint lists the offered rates
    offered_hz: tuple[float, ...]  # ascending
    picked_hz: float  # the offered rate the plan picked
    planned_hz: float  # the plan's rate: the one picked, unless none fits and the bounds were scaled
    free_hz: float  # the rate planned if the driver took any (within its other bounds)
    free_objective: float  # that plan's objective (ms)
    free_scale: float  # and the scale its bounds needed


@dataclass(frozen=True)
class TwoStageComparison:
    """How the plan compares with the paper's plain two-stage result (Stage I's allocation)."""

    allocations: int  # allocations considered
    planned: int  # of those, planned by Stage II (the rest were bounded out, or beyond the planner's PLAN_AT_MOST)
    complete: bool  # every other allocation was bounded out: the plan is the best of them all
    two_stage_objective: (
        float | None
    )  # Stage I's allocation under Stage II, as run (None: it could not meet the bounds)
    two_stage_scale: float | None


@dataclass(frozen=True)
class Plan:
    app: str
    cores: int
    objective: float
    constraint_scale: float
    subchains: dict[str, SubchainPlan]
    shared_cores: tuple[CorePlan, ...]
    chains: tuple[ChainPlan, ...]
    stage1: Stage1Result
    warnings: tuple[str, ...]
    allocation: Allocation  # the one planned (Stage I's, or a runner-up that Stage II found better)
    comparison: TwoStageComparison
    runs: dict[str, int]  # n = 1/f per non-batch shared subchain (exact)
    every: dict[str, int] = field(default_factory=dict)  # k >= n per non-batch shared subchain: p = k T
    objective_as_run: float | None = None  # with the triggers executors' threads lose: what plans are ranked by
    offered_periods_ms: dict[str, float] = field(default_factory=dict)  # the offered period picked per subchain
    offered: tuple[OfferedChoice, ...] = ()  # those subchains: their rates, and what a free rate would give

    def placement(self, node: str) -> tuple[tuple[int, ...], int]:
        """A node's plan cores and resting SCHED_FIFO level (docs/explanation/model.md section 6): its
        subchain's cores and level, or, for a node in no subchain (on its own clock), every core and the
        unscheduled level."""
        sub = next((sub for sub in self.subchains.values() if node in sub.nodes), None)
        if sub is None:
            return tuple(range(self.cores)), resting_fifo(None)
        return tuple(sorted(sub.cores)), resting_fifo(sub.shared)

    def process_placement(self, nodes: Iterable[str]) -> tuple[tuple[int, ...], int]:
        """A process's plan cores and SCHED_FIFO level at launch: the union of its ``nodes``' cores and the highest
        of their resting levels (:meth:`placement`)."""
        cores: set[int] = set()
        level = 0
        for node in nodes:
            node_cores, node_level = self.placement(node)
            cores.update(node_cores)
            level = max(level, node_level)
        return tuple(sorted(cores)), level
