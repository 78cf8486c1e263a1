"""How long a run may wait for an executor's thread, where the executor's nodes span several subchains.

Nodes of one single-threaded executor never run at once (catan-model.md section 6): a run that
finds the thread busy waits for the run on it to end.  Across subchains on a shared core the slot
model plans each subchain as if its threads were its own, so the wait is in neither its latency
nor its rate.  The wait of a node's run is the others' compute in wall time, at about the
executor's share of the core (its subchains' slices over ``T``; it may take other slots' idle
time too).  A node whose wait is longer than its own subchain's period loses the triggers that
come meanwhile (a head still busy is not triggered again): it runs below its planned rate.  nav2d
is the example: GL may wait ~408 ms behind GM on one core, 20 times its 20 ms period; simulated,
GL runs at 40, 37 and 27 Hz of its planned 50 on 1, 2 and 3 cores, and at 49-50 Hz without the
executor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from catanc.core.problem import Executor, Problem

if TYPE_CHECKING:
    from catanc.planning.types import Plan


@dataclass(frozen=True)
class ExecutorWait:
    """How long a run of ``node`` may wait for its executor's thread, behind the executor's other nodes."""

    executor: Executor
    node: str
    subchain: str  # the node's
    compute_ms: float  # the other nodes' compute
    share: float  # the executor's share of its core (slices over T)
    period_ms: float  # the node's subchain's planned period

    @property
    def wait_ms(self) -> float:
        return self.compute_ms / min(self.share, 1.0)

    @property
    def behind(self) -> str:
        return ", ".join(other for other in self.executor.nodes if other != self.node)

    @property
    def loses_triggers(self) -> bool:
        return self.wait_ms > self.period_ms

    @property
    def warning(self) -> str:
        return (
            f"executor {self.executor.name}: a run of {self.node} may wait about {self.wait_ms:.1f} ms for "
            f"{self.behind} to end, longer than {self.subchain}'s planned period ({self.period_ms:.3f} ms): "
            f"its triggers meanwhile are lost and it runs below its planned rate (the planner does not yet "
            "plan an executor's thread across subchains)"
        )


def executor_waits(executor: Executor, plan: Plan, problem: Problem) -> list[ExecutorWait]:
    """How long each node of ``executor`` may wait for its thread, in the executor's node order; empty unless
    its nodes span two or more subchains on a shared core."""
    subs = executor.subchains
    if len(subs) < 2:
        return []
    cores = {core for name in subs for core in plan.subchains[name].cores}
    period = next((core.period_ms for core in plan.shared_cores if core.core in cores), None)
    if period is None:
        return []
    share = math.fsum(plan.subchains[name].fraction * problem.subchain(name).compute_ms for name in subs) / period
    compute, owner = {}, {}
    for name in subs:
        sub = problem.subchain(name)
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True):
            compute[node], owner[node] = c, name
    return [
        ExecutorWait(
            executor,
            node,
            owner[node],
            math.fsum(compute[other] for other in executor.nodes if other != node),
            share,
            plan.subchains[owner[node]].period_ms,
        )
        for node in executor.nodes
    ]


def longest_wait(executor: Executor, plan: Plan, problem: Problem) -> ExecutorWait | None:
    """The longest wait a node of ``executor`` may have for its thread (the first such node on a tie)."""
    waits = executor_waits(executor, plan, problem)
    return max(waits, key=lambda wait: wait.wait_ms) if waits else None


def lost_triggers(plan: Plan, problem: Problem) -> list[ExecutorWait]:
    """Every node of an executor whose wait for the thread is longer than its subchain's period."""
    return [
        wait
        for executor in problem.executors
        for wait in executor_waits(executor, plan, problem)
        if wait.loses_triggers
    ]
