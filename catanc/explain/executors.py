"""What an executor's one thread does to the rates under a plan, where its nodes span several subchains.

Nodes of one single-threaded executor never run at once (docs/explanation/model.md section 6): a run that
finds the thread busy waits for the run on it to end, and once late it steals the slots of the
subchains its own outranks, for the thread to run in.  The slot model plans each subchain as if
its threads were its own, so neither the wait, nor the triggers lost meanwhile, nor the stolen
slots are in its latencies or rates.  :mod:`catanc.model.executor_thread` predicts them; this module
feeds it a plan's timings, core groups and slack.  nav2d is the example: on one core GM's 150 ms run
holds the thread ~210 ms, so GL, planned at 50 Hz, runs at about 39 Hz, and NC, whose slots GL takes
meanwhile, at about 105 Hz of 134 (simulated: 38 and 103.6 Hz).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from catanc.model.executor_thread import CoreGroup, ExecutorTurns, MemberRate, as_run_objective, executor_turns
from catanc.model.metrics import Timing
from catanc.model.problem import Executor, Problem
from catanc.spec.language import Schedule

if TYPE_CHECKING:
    from catanc.planning.types import Plan

LOSS_WORTH_A_WARNING = 0.01
"""A subchain predicted to lose more than this share of its planned rate gets a warning."""


def core_groups(plan: Plan, schedule: Schedule) -> list[CoreGroup]:
    """The plan's shared subchains grouped by the cores they share (``schedule``: the one it was planned with)."""
    by_cores: dict[tuple[int, ...], list[str]] = {}
    for sub in plan.subchains.values():
        if sub.shared:
            by_cores.setdefault(sub.cores, []).append(sub.name)
    return [
        CoreGroup(
            tuple(names),
            len(cores),
            {name: plan.subchains[name].priority for name in names},
            schedule.stealing,
            schedule.slack,
        )
        for cores, names in by_cores.items()
    ]


def plan_timings(plan: Plan) -> dict[str, Timing]:
    return {name: Timing(sub.period_ms, sub.latency_ms) for name, sub in plan.subchains.items()}


def plan_turns(executor: Executor, plan: Plan, problem: Problem, schedule: Schedule) -> ExecutorTurns | None:
    """The thread's turns under ``plan``; None unless the executor's nodes span two or more shared subchains."""
    return executor_turns(problem, executor, plan_timings(plan), core_groups(plan, schedule))


def objective_as_run(plan: Plan, problem: Problem, schedule: Schedule) -> float:
    """The plan's objective with the periods the executors' turns leave (:func:`as_run_objective`)."""
    return as_run_objective(problem, plan_timings(plan), core_groups(plan, schedule))


def member_warning(turns: ExecutorTurns, rate: MemberRate) -> str:
    blocker = turns.member(rate.blocked_by)
    return (
        f"executor {turns.executor.name}: {rate.node} runs at about {rate.rate_hz:.1f} Hz of its planned "
        f"{rate.planned_hz:.1f} Hz: a run of {rate.blocked_by} ({blocker.compute_ms:.3g} ms of compute) holds "
        f"their thread about {rate.longest_wait_ms:.1f} ms and {rate.node}'s triggers meanwhile are lost "
        "(what is left once the planner has spaced out the members' triggers: docs/explanation/executor-planning.md)"
    )


def stolen_warning(turns: ExecutorTurns, subchain: str, planned_hz: float, lost_hz: float) -> str:
    waiting = [rate for rate in turns.rates if rate.lost_share > 0.0]
    who = " and ".join(f"{rate.node}'s run, waiting for {rate.blocked_by}'s," for rate in waiting) or "a waiting run"
    return (
        f"executor {turns.executor.name}: subchain {subchain} runs at about {planned_hz - lost_hz:.1f} Hz of its "
        f"planned {planned_hz:.1f} Hz: {who} is late and takes {subchain}'s slots for their thread "
        "(what is left once the planner has spaced out the members' triggers: docs/explanation/executor-planning.md)"
    )


def rate_warnings(plan: Plan, problem: Problem, schedule: Schedule) -> list[str]:
    """A warning per subchain predicted to lose more than :data:`LOSS_WORTH_A_WARNING` of its planned rate."""
    warnings = []
    for executor in problem.executors:
        turns = plan_turns(executor, plan, problem, schedule)
        if turns is None:
            continue
        warnings += [member_warning(turns, rate) for rate in turns.rates if rate.lost_share > LOSS_WORTH_A_WARNING]
        for name, lost_hz in turns.stolen_hz.items():
            planned_hz = 1000.0 / plan.subchains[name].period_ms
            if lost_hz > LOSS_WORTH_A_WARNING * planned_hz:
                warnings.append(stolen_warning(turns, name, planned_hz, lost_hz))
    return warnings
