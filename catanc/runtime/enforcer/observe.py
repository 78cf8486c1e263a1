"""``catanc run --observe``: measure nodes that keep their own timers, scheduling nothing.

Before any plan is right, a profile needs measurements (``catanc profile``).  Observing
changes nothing about the app: no SCHED_FIFO, no affinity, no trigger.  It reads each
observed node's threads' CPU time from the kernel (``/proc/<pid>/task/<tid>/schedstat``,
:class:`~catanc.runtime.linux.cpu_clocks.OpenCpuClocks`) every :data:`POLL_MS` and cuts it into runs
(:class:`Bursts`): a run is CPU used between two polls that found the node idle (its CPU
time did not move over a whole poll interval).  Each run is logged as a ``compute`` sample
in the JSON-lines log :func:`catanc.runtime.logs.writer.RunLog` writes for ``catanc run``, whose
``start`` event says ``observe: true``.

What it cannot tell apart: two runs less than a poll interval apart are one (a node's idle
time between runs must exceed :data:`POLL_MS`); a run that blocks (I/O, a lock) for longer
than that is two; a node's threads are summed, so a helper thread's CPU counts as the
node's.  The CPU time itself is the kernel's count, exact.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType

from catanc.runtime.linux.cpu_clocks import NS_PER_MS, OpenCpuClocks
from catanc.runtime.linux.sched import threads_of
from catanc.runtime.logs.writer import LOG_FORMAT, RunLog

POLL_MS = 1.0
"""How often each node's CPU time is read: runs closer together than this merge."""
MIN_RUN_MS = 0.005
"""CPU below this between idle polls is the kernel's own accounting of a wake-up, not a run."""
THREADS_EVERY_S = 1.0
"""A node's thread list is read again this often (threads it starts later are counted too)."""
FLUSH_EVERY_S = 1.0


@dataclass
class Bursts:
    """One node's CPU time, read at every poll, cut into runs at the polls that found it idle."""

    last_ns: int | None = None
    start_ns: int | None = None  # the CPU count when the current run began; None while idle

    def poll(self, cpu_ns: int) -> float | None:
        """The node's total CPU time now: a finished run's CPU (ms) if it just went idle, else None."""
        last, self.last_ns = self.last_ns, cpu_ns
        if last is None:
            return None
        if cpu_ns > last:
            if self.start_ns is None:
                self.start_ns = last
            return None
        if self.start_ns is None:
            return None
        used_ms = (last - self.start_ns) / NS_PER_MS
        self.start_ns = None
        return used_ms if used_ms >= MIN_RUN_MS else None

    def rebase(self, delta_ns: int) -> None:
        """The node's count dropped by ``delta_ns`` (a thread of it exited): keep counting from the new total."""
        if self.last_ns is not None:
            self.last_ns -= delta_ns
        if self.start_ns is not None:
            self.start_ns -= delta_ns


@dataclass
class ObservedNode:
    """One node's process, its threads and their last CPU counts."""

    node: str
    pid: int
    bursts: Bursts = field(default_factory=Bursts)
    threads: dict[int, int] = field(default_factory=dict)  # tid -> its last CPU count (ns)
    gone: bool = False


class Observer:
    """Polls the observed nodes until :meth:`stop` (any thread, or SIGINT/SIGTERM) or the duration ends."""

    def __init__(
        self,
        nodes: Mapping[str, int],
        log_path: str | Path,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
        poll_ms: float = POLL_MS,
    ) -> None:
        self.nodes = [ObservedNode(node, pid) for node, pid in sorted(nodes.items())]
        self.log_path = Path(log_path)
        self.clock = clock
        self.poll_ms = poll_ms
        self.clocks = OpenCpuClocks()
        self.counts: dict[str, int] = dict.fromkeys(nodes, 0)
        self._stop = threading.Event()
        self.started_ns = clock()

    def stop(self) -> None:
        self._stop.set()

    def run(
        self,
        duration_s: float | None = None,
        *,
        on_start: Callable[[Observer], None] | None = None,
        on_tick: Callable[[Observer], None] | None = None,
    ) -> None:
        """Observe from the main thread; ``on_start`` (start the app) runs once the log is open, ``on_tick``
        once a second (a progress bar)."""
        previous = {signum: signal.signal(signum, self._on_signal) for signum in (signal.SIGINT, signal.SIGTERM)}
        try:
            with RunLog(self.log_path) as log:
                self.started_ns = self.clock()
                log.write("start", 0.0, {"format": LOG_FORMAT, "observe": True, "nodes": self._pids(), "plan": {}})
                if on_start is not None:
                    on_start(self)
                self._loop(log, duration_s, on_tick)
                log.write("stop", self.elapsed_s(), {"summary": {"samples": dict(sorted(self.counts.items()))}})
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            self.clocks.close()

    def observe(self, node: str, pid: int) -> None:
        """Observe ``pid`` as ``node`` too (a process started after :meth:`run` began)."""
        self.nodes.append(ObservedNode(node, pid))
        self.counts.setdefault(node, 0)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:  # noqa: ARG002 - a handler's signature
        self.stop()

    def _pids(self) -> dict[str, int]:
        return {observed.node: observed.pid for observed in self.nodes}

    def elapsed_s(self) -> float:
        return (self.clock() - self.started_ns) / 1e9

    def _loop(self, log: RunLog, duration_s: float | None, on_tick: Callable[[Observer], None] | None) -> None:
        deadline = None if duration_s is None else self.clock() + int(duration_s * 1e9)
        next_threads = next_flush = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            if deadline is not None and now >= deadline:
                return
            if now >= next_threads:
                next_threads = now + int(THREADS_EVERY_S * 1e9)
                for observed in self.nodes:
                    self._refresh_threads(observed, log)
            for observed in self.nodes:
                self._poll(observed, log, now)
            if now >= next_flush:
                next_flush = now + int(FLUSH_EVERY_S * 1e9)
                log.flush()
                if on_tick is not None:
                    on_tick(self)
            self._stop.wait(self.poll_ms / 1000.0)

    def _refresh_threads(self, observed: ObservedNode, log: RunLog) -> None:
        if observed.gone:
            return
        tids = threads_of(observed.pid)
        if not tids:
            observed.gone = True
            log.write("gone", self.elapsed_s(), {"node": observed.node, "pid": observed.pid})
            return
        for tid in tids:
            observed.threads.setdefault(tid, -1)  # -1: not read yet

    def _poll(self, observed: ObservedNode, log: RunLog, now: int) -> None:
        if observed.gone:
            return
        total = 0
        for tid, before in list(observed.threads.items()):
            try:
                count = self.clocks.read_ns(observed.pid, tid)
            except (OSError, ValueError):
                del observed.threads[tid]
                if before > 0:
                    observed.bursts.rebase(before)  # its CPU leaves the node's total: not a backwards step
                continue
            if before < 0:  # a thread seen for the first time: its CPU so far is no run of this one's
                observed.bursts.rebase(-count)
            observed.threads[tid] = count
            total += count
        used_ms = observed.bursts.poll(total)
        if used_ms is not None:
            self.counts[observed.node] += 1
            t_s = (now - self.started_ns) / 1e9
            log.sample("compute", t_s, observed.node, (round(used_ms, 4), None, round(used_ms, 4), 1, None))


def launched_nodes(processes: Iterable[tuple[Iterable[str], int]]) -> tuple[dict[str, int], list[list[str]]]:
    """Node -> pid of the launched processes that serve exactly one node; the node lists of those that serve
    several (their CPU cannot be split between their nodes: attach each node's process on its own)."""
    found: dict[str, int] = {}
    shared: list[list[str]] = []
    for nodes, pid in processes:
        names = list(nodes)
        if len(names) == 1:
            found[names[0]] = pid
        elif names:
            shared.append(names)
    return found, shared
