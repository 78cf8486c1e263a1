"""The discrete-event loop: timed callbacks and the CPU's job completions, in time order.

Ties: job completions at a time come before callbacks at that time (a node
that finishes exactly at a slot switch has finished), and callbacks at one
time run in the order they were scheduled.  Nothing here is random: the same
calls give the same run.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Iterable

from catanc.sim.cpu import DONE_EPS_MS, Job, Pool


class Engine:
    """Simulated time (ms) with pools of cores."""

    def __init__(self, pools: Iterable[Pool] = ()) -> None:
        self.now = 0.0
        self.pools: list[Pool] = list(pools)
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self._arrivals = itertools.count()
        self._dirty: set[int] = set()  # pools (by id) whose jobs or priorities changed since the last allocation

    # -------------------------------------------------------------- scheduling

    def at(self, when_ms: float, callback: Callable[[], None]) -> None:
        """Run ``callback`` at ``when_ms`` (not before now)."""
        heapq.heappush(self._events, (max(when_ms, self.now), next(self._order), callback))

    def submit(self, pool: Pool, job: Job) -> None:
        """Make ``job`` runnable on ``pool`` now."""
        job.since = next(self._arrivals)
        pool.jobs.append(job)
        self.changed(pool)

    def changed(self, pool: Pool) -> None:
        """``pool``'s jobs or their priorities changed: re-allocate its cores before time moves on."""
        self._dirty.add(id(pool))

    def arrival(self) -> int:
        """A fresh first-come-first-served ticket (a job re-queued at a new priority goes to the back)."""
        return next(self._arrivals)

    # -------------------------------------------------------------- running

    def run_until(self, end_ms: float) -> None:
        """Advance to ``end_ms``, running every completion and callback due before it."""
        while True:
            self._allocate()
            done_in, pool = self._next_done()
            next_event = self._events[0][0] if self._events else float("inf")
            if min(self.now + done_in, next_event) > end_ms:
                self._advance_to(end_ms)
                return
            if self.now + done_in <= next_event and pool is not None:
                for job in self._advance_to(self.now + done_in):
                    job.on_done(job)
                continue
            finished = self._advance_to(next_event)  # a job may end on the way, within rounding
            if finished:
                for job in finished:
                    job.on_done(job)
                continue  # its completion may schedule work due before the callback: look again
            _, _, callback = heapq.heappop(self._events)
            callback()

    def _allocate(self) -> None:
        if not self._dirty:
            return
        for pool in self.pools:
            if id(pool) in self._dirty:
                pool.allocate()
        self._dirty.clear()

    def _next_done(self) -> tuple[float, Pool | None]:
        best, which = float("inf"), None
        for pool in self.pools:
            done_in = pool.next_done_ms()
            if done_in < best:
                best, which = done_in, pool
        return best, which

    def _advance_to(self, when_ms: float) -> list[Job]:
        """Move time to ``when_ms``; the jobs that finished on the way (their pools are re-allocated)."""
        dt = when_ms - self.now
        finished: list[Job] = []
        for pool in self.pools:  # dt may be 0: a job left with no work finishes now
            for job in pool.jobs:  # a job that runs for the first time (or ends having had no work) starts now
                if job.speed > 0.0 and not job.started and (dt > 0.0 or job.remaining_ms <= DONE_EPS_MS):
                    job.started = True
                    if job.on_start is not None:
                        job.on_start(job)
            done = pool.advance(max(dt, 0.0))
            if done:
                finished.extend(done)
                self.changed(pool)
        self.now = max(self.now, when_ms)
        return finished
