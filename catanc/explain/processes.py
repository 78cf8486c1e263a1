"""The processes of a plan, for ``explain`` and PLAN.md: each one's nodes, cores, level and threads.

A process (:mod:`catanc.spec.executors`) gets the union of its nodes' cores and the highest of their
resting SCHED_FIFO levels (:meth:`~catanc.planning.types.Plan.placement`), as the launchers start it
(:mod:`catanc.artifacts.deploy`); its scheduled nodes are planned as one executor when it runs them in
one thread, and the view says why or why not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from catanc.model.problem import Problem
from catanc.spec.executors import spec_processes
from catanc.spec.language import Spec

if TYPE_CHECKING:
    from catanc.planning.types import Plan


@dataclass(frozen=True)
class ProcessView:
    """One process under a plan."""

    key: str
    nodes: tuple[str, ...]  # its DAG nodes, in spec order
    cores: tuple[int, ...]  # plan cores: the union of its nodes'
    level: int  # SCHED_FIFO at launch: the highest of its nodes' resting levels
    executor: str | None  # the executor its scheduled nodes are planned as, if they are one
    threads: str  # whether its nodes are planned as one executor, and why, in a sentence's clause


def process_views(spec: Spec, problem: Problem, plan: Plan) -> tuple[ProcessView, ...]:
    """The deploy section's processes (none without one), sorted by name as runtime.json lists them."""
    views = []
    for process in sorted(spec_processes(spec), key=lambda found: found.key):
        cores, level = plan.process_placement(process.nodes)
        executor = next((e for e in problem.executors if e.process == process.key), None)
        inside = [e.name for e in problem.executors if e.process is None and set(e.nodes) & set(process.nodes)]
        if executor is not None:
            named = "" if executor.name == process.key else f" (executors.{executor.name})"
            threads = f"one executor{named}: {process.reason}"
        elif len(process.scheduled) < 2:
            threads = process.reason
        else:
            declared = f"; executors {', '.join(inside)} say which share a thread" if inside else ""
            threads = f"may run at once: {process.reason}{declared}"
        views.append(
            ProcessView(
                process.key,
                process.nodes,
                cores,
                level,
                executor.name if executor is not None else None,
                threads,
            )
        )
    return tuple(views)
