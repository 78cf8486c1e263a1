"""A thread's on-CPU time as the kernel counts it (``/proc/<pid>/task/<tid>/schedstat``).

:func:`parse_schedstat` reads one ``schedstat`` line, :class:`CpuClock` one thread's,
:class:`OpenCpuClocks` many threads' through descriptors kept open, and :func:`cpu_ms` turns
two readings into milliseconds (:func:`catanc.control.measure.reconcile` weighs them against a
client's own figure).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

NS_PER_MS = 1_000_000


def schedstat_path(pid: int, tid: int, proc: Path = Path("/proc")) -> Path:
    return proc / str(pid) / "task" / str(tid) / "schedstat"


def parse_schedstat(text: str) -> int:
    """The first field of a ``schedstat`` line: nanoseconds the thread has run on a CPU.

    (The other two: ns spent runnable waiting for a CPU, and the number of time slices.)
    Raises ``ValueError`` if the text is not such a line.
    """
    fields = text.split()
    if len(fields) < 1 or not fields[0].isdigit():
        raise ValueError(f"not a schedstat line: {text!r}")
    return int(fields[0])


@dataclass(frozen=True)
class CpuClock:
    """A thread's cumulative on-CPU time, as the kernel counts it (``/proc/<pid>/task/<tid>/schedstat``).

    Needs a kernel with ``CONFIG_SCHED_INFO`` (``schedstat`` files exist).  :meth:`read_ns`
    raises ``OSError`` (``FileNotFoundError`` once the thread has exited) or ``ValueError``.
    """

    pid: int
    tid: int
    proc: Path = Path("/proc")

    @property
    def path(self) -> Path:
        return schedstat_path(self.pid, self.tid, self.proc)

    def read_ns(self) -> int:
        return parse_schedstat(self.path.read_text(encoding="ascii"))


class OpenCpuClocks:
    """Threads' :class:`CpuClock` readings through descriptors kept open, one per thread.

    Opening and closing ``schedstat`` per reading cost ~30 us on the test VM, a ``pread``
    on an open descriptor ~2 us.  A descriptor stays bound to its thread: once the thread
    exits, reading it raises ``OSError`` (and the descriptor is closed), even if the
    thread's id is reused.  Not thread-safe: the caller serialises readings.
    """

    def __init__(self, proc: Path = Path("/proc")) -> None:
        self.proc = proc
        self._fds: dict[int, int] = {}
        self.generation = 0  # counts descriptors opened and closed: a copy of them (the compiled walk's) is stale

    def read_ns(self, pid: int, tid: int) -> int:
        """Like ``CpuClock(pid, tid).read_ns()``: ``OSError`` once the thread has exited, or ``ValueError``."""
        fd = self._fds.get(tid)
        if fd is None:
            fd = os.open(schedstat_path(pid, tid, self.proc), os.O_RDONLY | os.O_CLOEXEC)
            self._fds[tid] = fd
            self.generation += 1
        try:
            return parse_schedstat(os.pread(fd, 128, 0).decode("ascii"))
        except (OSError, ValueError):
            self.forget(tid)
            raise

    def open(self, pid: int, tid: int) -> bool:
        """Open thread ``tid``'s descriptor afresh (closing one it had); False if the thread is gone."""
        self.forget(tid)
        try:
            self._fds[tid] = os.open(schedstat_path(pid, tid, self.proc), os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            return False
        self.generation += 1
        return True

    def opened_fd(self, tid: int) -> int | None:
        """The descriptor :meth:`open` opened for ``tid`` (valid until :attr:`generation` moves)."""
        return self._fds.get(tid)

    def read_opened_ns(self, tid: int) -> int | None:
        """Like :meth:`read_ns` for a thread given to :meth:`open`, None for any other: no path is looked up.

        For a real-time caller: looking up a thread that just died in ``/proc`` can stall it
        (:func:`catanc.runtime.linux.sched.at_sched_other`).
        """
        fd = self._fds.get(tid)
        if fd is None:
            return None
        try:
            return parse_schedstat(os.pread(fd, 128, 0).decode("ascii"))
        except (OSError, ValueError):
            self.forget(tid)
            raise

    def forget(self, tid: int) -> None:
        """Close ``tid``'s descriptor, if open (its thread is gone or no longer a node's)."""
        fd = self._fds.pop(tid, None)
        if fd is not None:
            os.close(fd)
            self.generation += 1

    def close(self) -> None:
        for tid in list(self._fds):
            self.forget(tid)


def cpu_ms(before_ns: int, after_ns: int) -> float:
    """Compute time between two readings of one thread's :class:`CpuClock`, in ms.

    Raises ``ValueError`` if the counter went backwards (the tid now names another thread).
    """
    if after_ns < before_ns:
        raise ValueError(f"on-CPU time went backwards ({before_ns} ns -> {after_ns} ns): not the same thread")
    return (after_ns - before_ns) / NS_PER_MS
