"""Node threads' SCHED_FIFO levels as the enforcer last set them, so that a change touches only the threads it must.

A slot switch lowers the threads the previous owner has raised and raises those of the new
owner that may run in its slice; :class:`Levels` remembers what each thread was set to and
makes a system call only where that differs.  A thread that exited is reported back (the
caller unregisters it).  Without real-time priorities (``--no-rt``) nothing is set.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

from catanc.runtime.linux.sched import FIFO_PRIORITIES, ThreadGone, set_fifo

_PARAMS = {level: os.sched_param(level) for level in FIFO_PRIORITIES}


class Levels:
    """The SCHED_FIFO level each node thread was last given, and the threads raised on each core."""

    __slots__ = ("_level", "calls", "raised", "resting", "rt")

    def __init__(self, *, rt: bool) -> None:
        self.rt = rt
        self._level: dict[int, int] = {}
        self.resting: dict[int, int] = {}  # tid -> the level it rests at (set when it is placed)
        self.raised: dict[int, set[int]] = {}  # core -> threads set above their resting level there
        self.calls = 0  # system calls made (for the cost figures)

    def level(self, tid: int) -> int | None:
        return self._level.get(tid)

    def set(self, tid: int, level: int) -> bool:
        """Give ``tid`` ``level`` unless it has it; False if the thread is gone."""
        if not self.rt or self._level.get(tid) == level:
            return True
        self.calls += 1
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, _PARAMS[level])  # the hot path: no wrapper
        except ProcessLookupError:
            self._level.pop(tid, None)
            return False
        except (OSError, KeyError):
            try:
                set_fifo(tid, level)  # says why (privilege, a level out of range) the way the rest of catanc does
            except ThreadGone:
                self._level.pop(tid, None)
                return False
        self._level[tid] = level
        return True

    def raise_on(self, core: int, tids: Iterable[int], level: int) -> list[int]:
        """Raise ``tids`` to ``level`` on ``core``; the threads found gone."""
        gone = []
        raised = self.raised.setdefault(core, set())
        for tid in tids:
            if self.set(tid, level):
                raised.add(tid)
            else:
                gone.append(tid)
        return gone

    def rest(self, tid: int, level: int) -> bool:
        """Place ``tid`` at its resting ``level``; False if the thread is gone."""
        self.resting[tid] = level
        return self.set(tid, level)

    def lower_on(self, core: int) -> list[int]:
        """Put every thread raised on ``core`` back to its resting level; the threads found gone."""
        gone = []
        resting = self.resting
        for tid in self.raised.pop(core, ()):
            if tid in resting and not self.set(tid, resting[tid]):
                gone.append(tid)
        return gone

    def active(self, core: int) -> bool:
        """Whether some thread is raised on ``core``."""
        return bool(self.raised.get(core))

    def forget(self, tid: int) -> None:
        self._level.pop(tid, None)
        self.resting.pop(tid, None)
        for raised in self.raised.values():
            raised.discard(tid)

    def reset(self) -> None:
        """Forget what was raised (after a re-pin sets every thread's resting level again)."""
        self.raised.clear()
