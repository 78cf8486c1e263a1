"""What an executor's one thread does to its nodes' rates, where its nodes span several subchains.

Nodes of one single-threaded executor never run at once (catan-model.md section 6): a run that
finds the thread busy waits for the run on it to end.  Across subchains on a shared core the slot
model plans each subchain as if its threads were its own, so neither the wait nor the triggers
lost meanwhile are in its latency or rate.  :mod:`catanc.core.executor_thread` predicts both from
the plan; this module feeds it a plan's periods, compute times and the share of a core the thread
gets (what the core's other subchains leave).  nav2d is the example: GM's 150 ms run holds the
thread ~265 ms on one core, so GL, planned at 50 Hz, runs at about 34 Hz (simulated: 38 Hz;
49-50 Hz without the executor).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from catanc.core.executor_thread import Member, MemberRate, member_rates, thread_share, utilisation
from catanc.core.problem import Executor, Problem

if TYPE_CHECKING:
    from catanc.planning.types import Plan

LOSS_WORTH_A_WARNING = 0.01
"""A member predicted to lose more than this share of its planned triggers gets a warning."""


@dataclass(frozen=True)
class ExecutorTurns:
    """An executor's thread across subchains of a plan: its share of a core and each node's predicted rate."""

    executor: Executor
    share: float  # of a core, while one of its runs holds the thread
    rates: tuple[MemberRate, ...]  # in the executor's node order
    compute_ms: dict[str, float]  # each node's run

    def warning(self, rate: MemberRate) -> str:
        return (
            f"executor {self.executor.name}: {rate.node} runs at about {rate.rate_hz:.1f} Hz of its planned "
            f"{rate.planned_hz:.1f} Hz: a run of {rate.blocked_by} holds their thread about "
            f"{rate.longest_wait_ms:.1f} ms ({self.compute_ms[rate.blocked_by]:.3g} ms of compute at the "
            f"{self.share:.0%} of a core the others leave) and {rate.node}'s triggers meanwhile are lost "
            "(the planner does not yet plan an executor's thread across subchains)"
        )


def executor_turns(executor: Executor, plan: Plan, problem: Problem) -> ExecutorTurns | None:
    """The thread's turns under ``plan``; None unless the executor's nodes span two or more shared subchains."""
    subs = executor.subchains
    if len(subs) < 2:
        return None
    cores = {core for name in subs for core in plan.subchains[name].cores}
    period = next((core.period_ms for core in plan.shared_cores if core.core in cores), None)
    if period is None:
        return None
    own = sum(plan.subchains[name].fraction * problem.subchain(name).compute_ms for name in subs) / period
    others = sum(
        utilisation(problem.subchain(name).compute_ms, sub.period_ms)
        for name, sub in plan.subchains.items()
        if name not in subs and cores & set(sub.cores)
    )
    share = thread_share(own, others, len(cores))
    members: dict[str, Member] = {}
    for name in subs:
        sub = problem.subchain(name)
        for node, compute in zip(sub.nodes, sub.node_compute_ms, strict=True):
            if node in executor.nodes:
                members[node] = Member(node, plan.subchains[name].period_ms, compute)
    ordered = [members[node] for node in executor.nodes]
    return ExecutorTurns(executor, share, tuple(member_rates(ordered, share)), {m.node: m.compute_ms for m in ordered})


def rate_losses(plan: Plan, problem: Problem) -> list[tuple[ExecutorTurns, MemberRate]]:
    """Every executor node predicted to lose more than :data:`LOSS_WORTH_A_WARNING` of its planned rate."""
    losses = []
    for executor in problem.executors:
        turns = executor_turns(executor, plan, problem)
        if turns is not None:
            losses += [(turns, rate) for rate in turns.rates if rate.lost_share > LOSS_WORTH_A_WARNING]
    return losses
