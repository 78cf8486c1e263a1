"""The enforcer's own threads: where they run and at what level.

Two threads: the main thread (it waits, and handles signals) and the loop
(:mod:`catanc.runtime.enforcer.run`).  Both are remembered by the restorer (the watchdog puts them
back too) and run at SCHED_FIFO :data:`~catanc.model.priorities.ENFORCER_FIFO` with real-time
scheduling on, reset on fork (processes they start, ``--demo`` workers, must not inherit it).
The loop is pinned to the plan core with the most switches a second: its wake-ups are that
core's slot switches, and a wake-up on another CPU would cost an inter-processor interrupt each.

Plan core ``i`` is the ``i``-th CPU this process may use (a cpuset {2, 3} runs cores 0, 1 there).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable

from catanc.control.schedule import RuntimeSchedule
from catanc.model.priorities import ENFORCER_FIFO
from catanc.runtime.linux.sched import Restorer


class OwnThreads:
    """The enforcer's main thread and loop: raised, pinned, remembered."""

    def __init__(self, restorer: Restorer, *, rt: bool, cpu_ids: Callable[[], list[int]]) -> None:
        self.restorer = restorer
        self.rt = rt
        self._cpu_ids = cpu_ids  # the CPUs this process may use, sorted (they change with its cpuset)
        self.loop_tid: int | None = None

    @property
    def cpu_ids(self) -> list[int]:
        return self._cpu_ids()

    def cpus_of(self, cores: Iterable[int]) -> frozenset[int]:
        """The CPUs of plan cores."""
        ids = self._cpu_ids()
        return frozenset(ids[core % len(ids)] for core in cores)

    @staticmethod
    def loop_core(schedule: RuntimeSchedule) -> int:
        """The plan core the loop runs on: the shared core with the most switches, else the last core."""
        busiest = max(
            schedule.shared, key=lambda core: ((len(core.slots) + 1) / core.period_ms, -core.core), default=None
        )
        return busiest.core if busiest is not None else schedule.cores - 1

    def raise_self(self, pin: int | None) -> None:
        """The calling thread: remembered, FIFO with RT, pinned to plan core ``pin`` if given."""
        tid = threading.get_native_id()
        self.restorer.remember(tid)
        if pin is not None:
            os.sched_setaffinity(tid, self.cpus_of([pin]))
        if self.rt:
            os.sched_setscheduler(tid, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(ENFORCER_FIFO))

    def start_loop(self, schedule: RuntimeSchedule) -> None:
        """The calling thread is the loop: raised and pinned to its core."""
        self.loop_tid = threading.get_native_id()
        self.raise_self(pin=self.loop_core(schedule))

    def pin_loop(self, schedule: RuntimeSchedule) -> None:
        """Called from the loop after a new allocation or cpuset: onto the loop core's CPU now."""
        if self.loop_tid is not None and threading.get_native_id() == self.loop_tid:
            os.sched_setaffinity(0, self.cpus_of([self.loop_core(schedule)]))
