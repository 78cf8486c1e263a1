"""The enforcer's safety net: a process that puts app threads back if the enforcer is SIGKILLed.

``catanc run`` raises app threads to SCHED_FIFO.  Its own handlers restore them on exit, SIGINT or
SIGTERM (:class:`catanc.runtime.linux.sched.Restorer`), but nothing runs in a process that gets SIGKILL.
So the enforcer starts a watchdog first and tells it, over a pipe, each thread's original policy,
priority and CPUs *before* it changes the thread.  When the enforcer ends without saying goodbye,
the watchdog puts every thread it was told about back, within well under a second.

Design:

- A separate program, ``python -I -S watchdog.py PARENT PRIORITY POLL_S``: an exec'd interpreter
  with nothing but the standard library.  This module imports nothing from catanc at run time (so
  the watchdog starts in ~10 ms with ~10 MB instead of ~0.5 s and ~45 MB for catanc's solvers, and
  no site-packages code runs at a real-time priority), and exec avoids forking the multi-threaded
  enforcer (locks held by other threads, Python's fork-with-threads warning).
- Its own session (``start_new_session``): SIGINT and SIGTERM sent to the enforcer's process group
  do not reach it.  It also ignores SIGINT, SIGTERM and SIGHUP, because systemd stops a service by
  signalling every process in its cgroup: the watchdog must outlive the enforcer's own clean-up.
  It ends when its job is done (SIGKILL still ends it, as it ends anything).
- SCHED_FIFO :data:`WATCHDOG_PRIORITY` (above the app threads at 1-3 and the enforcer's at 4), on
  every CPU it may use: when it wakes up, the spinning app threads cannot keep it off a CPU.  It
  sleeps in ``poll()`` almost all the time, and drops back to SCHED_OTHER before it exits.
- Protocol (stdin, one ASCII line each, written with one ``write()`` so lines never interleave):
  ``T <tid> <starttime or -> <policy> <priority> <cpu,cpu,...>`` remembers a thread's original
  (a later line for the same tid replaces it), ``C`` means the enforcer restored everything
  itself: exit without touching anything.  End of file without ``C`` means the enforcer is gone.
- The enforcer's death is noticed three ways: end of file on the pipe, its pidfd becoming
  readable, and, every :data:`POLL_S`, its main thread in ``/proc`` showing SIGKILL pending, the
  exiting flag or a zombie.  The last one matters: a killed process only closes its files when
  every one of its threads has run to its exit, and a SCHED_OTHER thread of the enforcer (its main
  thread, the re-optimizer) gets no CPU while app threads spin at SCHED_FIFO on every CPU: up to
  ~0.95 s with the kernel's default real-time throttling, forever without it.
- A thread's identity is a pidfd of that thread (``PIDFD_THREAD``, Linux 6.9), opened when its
  line arrives and readable once it exits, so a tid the kernel reused for another thread after
  the app thread exited is left alone; before 6.9, its tid and start time (``/proc/<tid>/task/<tid>/stat``
  field 22).
- No path under ``/proc`` is looked up at SCHED_FIFO: the enforcer's ``stat`` is
  opened before the watchdog raises itself, then only read.  Looking up a dead process's
  ``/proc`` entry invalidates its dentries (``d_invalidate``), which spins until the task
  releasing them finishes; a real-time watchdog that preempted that task on its CPU spins for
  ever (seen: 6 minutes at FIFO 10, 100% of a CPU, after a test's enforcer was killed).
- After restoring on a death it waits (at most :data:`DEATH_WAIT_S`) for the enforcer to be fully
  gone and restores once more, in case a dying enforcer thread's last system call raced with it.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Protocol

WATCHDOG_PRIORITY = 10
"""The watchdog's SCHED_FIFO priority: above app threads (1-3) and the enforcer's threads (4)."""

POLL_S = 0.05
"""How often the watchdog checks in ``/proc`` whether the enforcer is dying."""

START_TIMEOUT_S = 5.0
"""How long :meth:`Watchdog.start` waits for the watchdog to say it is ready."""

DEATH_WAIT_S = 2.0
"""After restoring, how long the watchdog waits for the enforcer to be fully gone before restoring again."""

SIGKILL_BIT = 1 << (signal.SIGKILL - 1)
PF_EXITING = 0x4  # task flag (``/proc/<pid>/stat`` field 9): the task is in do_exit()
PIDFD_THREAD = os.O_EXCL  # pidfd_open(2)'s flag for a pidfd of one thread, not of its process (Linux 6.9)


# --------------------------------------------------------------------------- shared with catanc.runtime.linux.sched


class Policy(Protocol):
    """A thread's scheduling as the watchdog restores it (:class:`catanc.runtime.linux.sched.ThreadPolicy` is one)."""

    @property
    def policy(self) -> int: ...

    @property
    def priority(self) -> int: ...

    @property
    def cpus(self) -> frozenset[int]: ...


def thread_start_time(tid: int) -> int | None:
    """When thread ``tid`` started (clock ticks after boot, ``stat`` field 22); ``None`` if it is gone."""
    try:
        text = Path(f"/proc/{tid}/task/{tid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()  # from field 3 on: the name before it may hold spaces
    return int(fields[22 - 3])


def pidfd_exited(pidfd: int) -> bool:
    """Whether the process or thread ``pidfd`` refers to has exited (a pidfd is readable from then on)."""
    return bool(select.select([pidfd], [], [], 0)[0])


def format_line(tid: int, start_time: int | None, policy: int, priority: int, cpus: frozenset[int]) -> bytes:
    """The protocol's ``T`` line for one thread."""
    start = "-" if start_time is None else str(start_time)
    return f"T {tid} {start} {policy} {priority} {','.join(map(str, sorted(cpus)))}\n".encode()


CLEAN_LINE = b"C\n"


# --------------------------------------------------------------------------- the watchdog process


class _Entry:
    __slots__ = ("cpus", "pidfd", "policy", "priority", "start_time", "tid")

    def __init__(self, tid: int, start_time: int | None, policy: int, priority: int, cpus: frozenset[int]) -> None:
        self.tid = tid
        self.start_time = start_time
        self.policy = policy
        self.priority = priority
        self.cpus = cpus
        self.pidfd: int | None = None  # the thread's pidfd (see _thread_pidfd)


def _thread_pidfd(tid: int) -> int | None:
    """A pidfd of thread ``tid``, readable once it exits; None where the kernel has no thread pidfds (before 6.9)
    or no descriptor is left.  Raises ``ProcessLookupError`` if the thread is gone."""
    try:
        return os.pidfd_open(tid, PIDFD_THREAD)
    except ProcessLookupError:
        raise
    except OSError:
        return None


def _parse(line: str) -> _Entry | None:
    words = line.split()
    if len(words) != 6 or words[0] != "T":
        return None
    _, tid, start, policy, priority, cpus = words
    return _Entry(
        int(tid),
        None if start == "-" else int(start),
        int(policy),
        int(priority),
        frozenset(int(cpu) for cpu in cpus.split(",") if cpu),
    )


def _restore(entry: _Entry) -> str | None:
    """Put one thread back (policy first: that stops it hogging a CPU); ``"gone"``, an error, or ``None``."""
    if entry.pidfd is not None:
        if pidfd_exited(entry.pidfd):
            return "gone"
    elif entry.start_time is not None and thread_start_time(entry.tid) != entry.start_time:
        return "gone"
    try:
        os.sched_setscheduler(entry.tid, entry.policy, os.sched_param(entry.priority))
        if entry.cpus:
            os.sched_setaffinity(entry.tid, entry.cpus)
    except ProcessLookupError:
        return "gone"
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def _restore_all(table: dict[int, _Entry]) -> tuple[int, int, list[str]]:
    restored, gone, failed = 0, 0, []
    for entry in table.values():
        outcome = _restore(entry)
        if outcome is None:
            restored += 1
        elif outcome == "gone":
            gone += 1
        else:
            failed.append(f"thread {entry.tid}: {outcome}")
    return restored, gone, failed


def _open_stat(pid: int) -> int | None:
    """Process ``pid``'s ``/proc`` ``stat``, opened (at SCHED_OTHER: see the module's notes)."""
    try:
        return os.open(f"/proc/{pid}/stat", os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None


def _dying(stat_fd: int | None) -> bool:
    """Whether the process whose ``stat`` ``stat_fd`` holds open is gone or on its way out (SIGKILL pending,
    exiting, zombie).  Reads through the open descriptor only, never a path lookup.

    A fatal signal is put in every thread's own pending set as it is sent (the kernel's
    ``complete_signal``), so the main thread's (``stat`` field 31) shows a SIGKILL before any thread
    of the process ran again; ``status``'s SigPnd is the same set, read and parsed in ~4x the time.
    """
    if stat_fd is None:
        return True
    try:
        stat = os.pread(stat_fd, 4096, 0).decode("ascii", "replace").rsplit(")", 1)[1].split()
        return stat[3 - 3] in "ZXx" or bool(int(stat[9 - 3]) & PF_EXITING or int(stat[31 - 3]) & SIGKILL_BIT)
    except (OSError, IndexError, ValueError):
        return True


def _raise_priority(wanted: int) -> int:
    """SCHED_FIFO ``wanted``, or the highest RLIMIT_RTPRIO allows; the priority got (0: SCHED_OTHER)."""
    import resource  # noqa: PLC0415 (only the watchdog process needs it)

    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    tries = [wanted]
    if soft != resource.RLIM_INFINITY and 0 < soft < wanted:
        tries.append(int(soft))
    for priority in tries:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except OSError:
            continue
        return priority
    return 0


def _read_available(fd: int, buffer: bytearray) -> bool:
    """Append what the pipe holds now to ``buffer``; ``False`` at end of file."""
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            return True
        except InterruptedError:
            continue
        if not chunk:
            return False
        buffer += chunk


def main(argv: list[str]) -> int:
    """The watchdog process: ``watchdog.py PARENT_PID PRIORITY POLL_S`` (started by :meth:`Watchdog.start`)."""
    parent, wanted, poll_s = int(argv[0]), int(argv[1]), float(argv[2])
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_IGN)
    try:
        pidfd: int | None = os.pidfd_open(parent)
    except OSError:  # ESRCH: already gone (then getppid() tells), ENOSYS: a kernel before 5.3
        pidfd = None
    if os.getppid() != parent:
        return 0  # the enforcer died before it could tell us anything
    parent_stat = _open_stat(parent)  # before the watchdog is real-time: no /proc lookups after
    priority = _raise_priority(wanted)
    with contextlib.suppress(OSError):  # any CPU this process may use, not just the enforcer's
        os.sched_setaffinity(0, range(os.cpu_count() or 1))
    os.write(1, f"ready {os.getpid()} {priority}\n".encode())
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)
    os.set_blocking(0, False)

    table: dict[int, _Entry] = {}
    buffer = bytearray()
    poller = select.poll()
    poller.register(0, select.POLLIN)
    if pidfd is not None:
        poller.register(pidfd, select.POLLIN)

    def take_lines() -> bool:
        """Apply the complete lines in ``buffer``; ``True`` on a clean exit."""
        *lines, rest = buffer.split(b"\n")
        buffer[:] = rest
        for line in lines:
            text = line.decode("ascii", "replace")
            if text.strip() == "C":
                return True
            entry = _parse(text)
            if entry is None:
                continue
            old = table.pop(entry.tid, None)
            if old is not None and old.pidfd is not None:
                os.close(old.pidfd)
            try:
                entry.pidfd = _thread_pidfd(entry.tid)
            except ProcessLookupError:
                continue  # gone before it was changed: nothing to put back
            table[entry.tid] = entry
        return False

    why = ""
    while not why:
        events = poller.poll(poll_s * 1000)
        ready = {fd for fd, _ in events}
        open_pipe = _read_available(0, buffer) if 0 in ready else True
        if take_lines():
            return _leave(0)
        if not open_pipe:
            why = "closed its pipe"
        elif pidfd is not None and pidfd in ready:
            why = "exited"
        elif (pidfd is None and os.getppid() != parent) or _dying(parent_stat):
            why = "was killed"
    # Lines written just before the end may still wait in the pipe.
    _read_available(0, buffer)
    buffer += b"\n"
    if take_lines():
        return _leave(0)

    restored, gone, failed = _restore_all(table)
    message = f"catanc watchdog: the enforcer (pid {parent}) {why} without restoring its threads; "
    message += f"put {restored} back"
    message += f", {gone} had exited" if gone else ""
    message += "".join(f"\n  could not restore {failure}" for failure in failed)
    with contextlib.suppress(OSError):
        sys.stderr.write(message + "\n")
        sys.stderr.flush()
    if pidfd is not None and why != "exited":
        select.select([pidfd], [], [], DEATH_WAIT_S)
    _restore_all(table)  # again, in case a dying enforcer thread's last system call came after ours
    return _leave(1 if failed else 0)


def _leave(code: int) -> int:
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return code


# --------------------------------------------------------------------------- the enforcer's handle on it


class Watchdog:
    """The enforcer's handle on its watchdog process.

    ``Watchdog().start()`` starts it and waits until it runs at its real-time priority;
    :meth:`remember` tells it a thread's original before the enforcer changes the thread (the
    :class:`~catanc.runtime.linux.sched.Restorer` does this itself once attached); :meth:`clean_exit`
    tells it the enforcer restored everything, so it exits without touching anything.
    """

    def __init__(self, *, priority: int = WATCHDOG_PRIORITY, poll_s: float = POLL_S) -> None:
        if not 1 <= priority <= os.sched_get_priority_max(os.SCHED_FIFO):
            raise ValueError(f"watchdog priority {priority} is not a SCHED_FIFO priority")
        if poll_s <= 0:
            raise ValueError(f"poll_s must be positive, not {poll_s}")
        self._wanted = priority
        self._poll_s = poll_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._pipe: int | None = None
        self.priority = 0
        """The SCHED_FIFO priority the watchdog got (0: it runs at SCHED_OTHER); set by :meth:`start`."""

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    @property
    def running(self) -> bool:
        """Whether the watchdog was started, has not been told to exit and has not died."""
        return self._pipe is not None and self._proc is not None and self._proc.poll() is None

    def start(self, timeout: float = START_TIMEOUT_S) -> Watchdog:
        """Start the watchdog process and wait (at most ``timeout`` s) until it is ready."""
        if self._proc is not None:
            raise RuntimeError("this watchdog was started already")
        if not sys.executable:
            raise _error("cannot start the watchdog: sys.executable is unknown")
        argv = [sys.executable, "-I", "-S", str(Path(__file__).resolve())]
        argv += [str(os.getpid()), str(self._wanted), repr(self._poll_s)]
        try:
            self._proc = subprocess.Popen(
                argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True, close_fds=True
            )
        except OSError as exc:
            raise _error(f"cannot start the watchdog ({sys.executable}): {exc}") from exc
        assert self._proc.stdin is not None
        assert self._proc.stdout is not None
        self._pipe = self._proc.stdin.fileno()
        line = _read_line(self._proc.stdout, timeout)
        words = line.split()
        if len(words) != 3 or words[0] != "ready":
            self._abandon()
            raise _error(f"the watchdog did not start within {timeout} s (it said {line!r})")
        self.priority = int(words[2])
        self._proc.stdout.close()
        return self

    def remember(self, tid: int, original: Policy, start_time: int | None = None) -> None:
        """Tell the watchdog thread ``tid``'s original; call it before changing the thread.

        ``start_time`` identifies the thread (see :func:`thread_start_time`); read now if not given.
        """
        if start_time is None:
            start_time = thread_start_time(tid)
        self._send(format_line(tid, start_time, original.policy, original.priority, original.cpus))

    def clean_exit(self, *, wait: float = START_TIMEOUT_S) -> None:
        """The enforcer put everything back: the watchdog exits without touching anything.

        Waits at most ``wait`` s for it to exit (0: not at all).  Safe to call twice, or after it died.
        """
        if self._pipe is None or self._proc is None:
            return
        with contextlib.suppress(OSError):
            _write_all(self._pipe, CLEAN_LINE)
        self._close_pipe()
        if wait > 0:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=wait)

    def _send(self, line: bytes) -> None:
        if self._pipe is None or self._proc is None:
            raise RuntimeError("the watchdog is not running: call start() first (and not after clean_exit())")
        try:
            _write_all(self._pipe, line)
        except OSError as exc:
            raise _error(
                f"the watchdog (pid {self._proc.pid}) is gone ({exc.strerror}): "
                "a SIGKILL of the enforcer would leave app threads at their real-time priorities"
            ) from exc

    def _close_pipe(self) -> None:
        if self._proc is not None and self._proc.stdin is not None:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
        self._pipe = None

    def _abandon(self) -> None:
        if self._proc is not None:
            self._close_pipe()
            self._proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=START_TIMEOUT_S)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _read_line(stream: IO[bytes], timeout: float) -> str:
    """One line from a pipe, waiting at most ``timeout`` s; whatever came if it did not end in time."""
    fd = stream.fileno()
    deadline = time.monotonic() + timeout
    data = b""
    while not data.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            break
        chunk = os.read(fd, 4096)
        if not chunk:
            break
        data += chunk
    return data.decode("ascii", "replace")


def _error(message: str) -> Exception:
    # Here, not at the top: run as a script (``-I -S``), this file imports nothing from catanc.
    from catanc.errors import SchedError  # noqa: PLC0415

    return SchedError(message)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
