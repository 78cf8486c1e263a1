"""The simulated CPU: pools of identical cores running jobs, advanced in time by the event loop.

A *pool* is a set of cores that schedules its jobs one way:

- ``fifo``: SCHED_FIFO. Jobs run by priority (higher first), first come first
  served within a priority; a job on ``q`` threads takes up to ``q`` of the
  pool's cores, and runs at ``cores given / q`` of its full speed when it
  gets fewer (its threads share them).
- ``fair``: Linux CFS as processor sharing: the cores are shared equally
  among the runnable threads (water-filling: no thread gets more than one
  core), priorities ignored.

A job's ``remaining_ms`` is wall time at full speed (on all its threads).
Between two events every speed is constant, so advancing is exact.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

Discipline = Literal["fifo", "fair"]

DONE_EPS_MS = 1e-9
"""A job with this little work left is done (rounding of many small steps)."""


@dataclass(eq=False)
class Job:
    """One run of one node on the simulated CPU."""

    node: str
    remaining_ms: float
    threads: int
    priority: int
    since: int  # arrival order: first come first served within a priority
    on_done: Callable[[Job], None]
    speed: float = 0.0  # share of full speed now (0: waiting for a core)
    on_start: Callable[[Job], None] | None = None  # told when the job first runs (a real thread reads then)
    started: bool = False


@dataclass(eq=False)
class Pool:
    """Cores that share their jobs by one discipline."""

    name: str
    cores: tuple[int, ...]
    discipline: Discipline
    jobs: list[Job] = field(default_factory=list)
    busy_core_ms: float = 0.0  # core time spent running jobs

    def allocate(self) -> None:
        """Set each job's speed for the current set of jobs and priorities."""
        free = float(len(self.cores))
        if self.discipline == "fifo":
            for job in sorted(self.jobs, key=lambda j: (-j.priority, j.since)):
                given = min(float(job.threads), free)
                job.speed = given / job.threads
                free -= given
            return
        demand = sum(job.threads for job in self.jobs)
        if demand <= free:
            for job in self.jobs:
                job.speed = 1.0
            return
        # Water-filling: every thread gets the same share of a core; equal shares when all are single-threaded.
        share = free / demand
        for job in self.jobs:
            job.speed = min(1.0, share)

    def next_done_ms(self) -> float:
        """Time (from now) until the first running job finishes; inf if none runs."""
        best = float("inf")
        for job in self.jobs:
            if job.speed > 0.0:
                best = min(best, job.remaining_ms / job.speed)
        return best

    def advance(self, dt_ms: float) -> list[Job]:
        """Run every job for ``dt_ms`` at its speed; return (and remove) the jobs that finished."""
        finished = []
        for job in self.jobs:
            if job.speed > 0.0:
                job.remaining_ms -= dt_ms * job.speed
                self.busy_core_ms += dt_ms * job.speed * job.threads
                if job.remaining_ms <= DONE_EPS_MS:
                    finished.append(job)
        if finished:
            self.jobs = [job for job in self.jobs if job.remaining_ms > DONE_EPS_MS]
        return finished
