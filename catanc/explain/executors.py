"""What an executor's one thread does to its nodes' rates under a plan, where its nodes span several subchains.

Nodes of one single-threaded executor never run at once (catan-model.md section 6): a run that
finds the thread busy waits for the run on it to end.  Across subchains on a shared core the slot
model plans each subchain as if its threads were its own, so neither the wait nor the triggers
lost meanwhile are in its latency or rate.  :mod:`catanc.core.executor_thread` predicts both; this
module feeds it a plan's periods and core groups.  nav2d is the example: GM's 150 ms run holds the
thread ~265 ms on one core, so GL, planned at 50 Hz, runs at about 34 Hz (simulated: 38 Hz;
49-50 Hz without the executor).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from catanc.core.executor_thread import CoreGroup, ExecutorTurns, MemberRate, executor_turns, periods_as_run
from catanc.core.metrics import Timing, objective
from catanc.core.problem import Executor, Problem

if TYPE_CHECKING:
    from catanc.planning.types import Plan

LOSS_WORTH_A_WARNING = 0.01
"""A member predicted to lose more than this share of its planned triggers gets a warning."""


def core_groups(plan: Plan) -> list[CoreGroup]:
    """The plan's shared subchains grouped by the cores they share."""
    by_cores: dict[tuple[int, ...], list[str]] = {}
    for sub in plan.subchains.values():
        if sub.shared:
            by_cores.setdefault(sub.cores, []).append(sub.name)
    return [CoreGroup(tuple(names), len(cores)) for cores, names in by_cores.items()]


def plan_turns(executor: Executor, plan: Plan, problem: Problem) -> ExecutorTurns | None:
    """The thread's turns under ``plan``; None unless the executor's nodes span two or more shared subchains."""
    periods = {name: sub.period_ms for name, sub in plan.subchains.items()}
    return executor_turns(problem, executor, periods, core_groups(plan))


def objective_as_run(plan: Plan, problem: Problem) -> float:
    """The plan's objective with each executor node's predicted rate in place of its planned one."""
    periods = {name: sub.period_ms for name, sub in plan.subchains.items()}
    as_run = periods_as_run(problem, periods, core_groups(plan))
    timings = {name: Timing(as_run[name], sub.latency_ms) for name, sub in plan.subchains.items()}
    return objective(problem, timings)


def warning(turns: ExecutorTurns, rate: MemberRate) -> str:
    return (
        f"executor {turns.executor.name}: {rate.node} runs at about {rate.rate_hz:.1f} Hz of its planned "
        f"{rate.planned_hz:.1f} Hz: a run of {rate.blocked_by} holds their thread about "
        f"{rate.longest_wait_ms:.1f} ms ({turns.compute_ms[rate.blocked_by]:.3g} ms of compute at the "
        f"{turns.share:.0%} of a core the others leave) and {rate.node}'s triggers meanwhile are lost "
        "(the planner does not yet plan an executor's thread across subchains)"
    )


def rate_losses(plan: Plan, problem: Problem) -> list[tuple[ExecutorTurns, MemberRate]]:
    """Every executor node predicted to lose more than :data:`LOSS_WORTH_A_WARNING` of its planned rate."""
    losses = []
    for executor in problem.executors:
        turns = plan_turns(executor, plan, problem)
        if turns is not None:
            losses += [(turns, rate) for rate in turns.rates if rate.lost_share > LOSS_WORTH_A_WARNING]
    return losses
