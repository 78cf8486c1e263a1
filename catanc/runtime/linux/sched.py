"""Linux scheduling for the enforcer: thread policies, priorities and CPUs, and putting them back.

Thread-level wrappers over ``sched_setscheduler(2)`` and ``sched_setaffinity(2)`` (a Linux tid
works wherever a pid does) that turn ``errno`` into errors the enforcer can act on: a thread that
exited is :class:`ThreadGone` (log it, carry on), a refusal is a
:class:`~catanc.errors.PrivilegeError` saying how to fix it.

:class:`Restorer` records each thread's original before the enforcer first changes it and puts
them all back on normal exit, on an exception, on SIGINT, SIGTERM and SIGHUP; with a
:class:`~catanc.runtime.linux.watchdog.Watchdog` attached, also after a SIGKILL::

    with Restorer(Watchdog().start()) as restorer:   # from the main thread
        restorer.remember(tid)                         # before the first change
        set_fifo(tid, 2)
        set_affinity(tid, {1})
        ...
"""

from __future__ import annotations

import atexit
import contextlib
import os
import resource
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Self, TypeVar

from catanc.errors import PrivilegeError, SchedError
from catanc.runtime.linux.watchdog import Watchdog, pidfd_exited, thread_start_time

SCHED_DEADLINE = 6  # not in the os module; os.sched_setscheduler cannot set it back
SCHED_RESET_ON_FORK = getattr(os, "SCHED_RESET_ON_FORK", 0x40000000)
FIFO_PRIORITIES = range(os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO) + 1)
"""The SCHED_FIFO priorities (1-99 on Linux), read once: setting one is asked at every slot switch."""
POLICY_NAMES = {
    os.SCHED_OTHER: "SCHED_OTHER",
    os.SCHED_FIFO: "SCHED_FIFO",
    os.SCHED_RR: "SCHED_RR",
    os.SCHED_BATCH: "SCHED_BATCH",
    os.SCHED_IDLE: "SCHED_IDLE",
    SCHED_DEADLINE: "SCHED_DEADLINE",
}
CAP_SYS_NICE = 23
HANDLED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""What :meth:`Restorer.install` handles: they end a process, and it should end with its threads back."""


class ThreadGone(SchedError):  # noqa: N818 (it is not a failure of catanc: the thread exited)
    """The thread exited (``ESRCH``): the enforcer logs it and carries on."""

    def __init__(self, tid: int, doing: str) -> None:
        self.tid = tid
        super().__init__(f"thread {tid} exited (while trying to {doing})")


# --------------------------------------------------------------------------- one thread


@dataclass(frozen=True)
class ThreadPolicy:
    """A thread's scheduling: policy (``os.SCHED_*``, maybe with SCHED_RESET_ON_FORK), priority, CPUs."""

    policy: int
    priority: int
    cpus: frozenset[int]

    def __str__(self) -> str:
        base = self.policy & ~SCHED_RESET_ON_FORK
        name = POLICY_NAMES.get(base, f"policy {base}")
        name += "|SCHED_RESET_ON_FORK" if self.policy & SCHED_RESET_ON_FORK else ""
        priority = f" {self.priority}" if self.priority else ""
        return f"{name}{priority} on CPUs {format_cpus(self.cpus)}"


def format_cpus(cpus: Iterable[int]) -> str:
    """``{0, 1, 2, 5}`` -> ``0-2,5``."""
    runs: list[list[int]] = []
    for cpu in sorted(set(cpus)):
        if runs and runs[-1][1] == cpu - 1:
            runs[-1][1] = cpu
        else:
            runs.append([cpu, cpu])
    return ",".join(str(low) if low == high else f"{low}-{high}" for low, high in runs)


def read_policy(tid: int) -> ThreadPolicy:
    """Thread ``tid``'s policy, priority and CPUs; :class:`ThreadGone` if it exited."""
    policy = _call(tid, "read the policy", lambda: os.sched_getscheduler(tid))
    priority = _call(tid, "read the priority", lambda: os.sched_getparam(tid).sched_priority)
    cpus = _call(tid, "read the CPUs", lambda: os.sched_getaffinity(tid))
    return ThreadPolicy(policy, priority, frozenset(cpus))


def set_fifo(tid: int, priority: int) -> None:
    """Run thread ``tid`` at SCHED_FIFO ``priority``."""
    if priority not in FIFO_PRIORITIES:
        raise ValueError(f"{priority} is not a SCHED_FIFO priority")
    param = os.sched_param(priority)
    _call(tid, f"set SCHED_FIFO {priority}", lambda: os.sched_setscheduler(tid, os.SCHED_FIFO, param), priority)


def set_other(tid: int) -> None:
    """Run thread ``tid`` at SCHED_OTHER (its nice value is kept)."""
    _call(tid, "set SCHED_OTHER", lambda: os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0)))


def set_affinity(tid: int, cpus: Iterable[int]) -> None:
    """Let thread ``tid`` run on ``cpus`` only."""
    wanted = frozenset(cpus)
    if not wanted:
        raise ValueError("an empty CPU set")
    _call(tid, f"pin to CPUs {format_cpus(wanted)}", lambda: os.sched_setaffinity(tid, wanted))


def apply_policy(tid: int, wanted: ThreadPolicy) -> None:
    """Give thread ``tid`` a whole :class:`ThreadPolicy`: policy and priority first, then CPUs."""
    param = os.sched_param(wanted.priority)
    _call(tid, f"set {wanted}", lambda: os.sched_setscheduler(tid, wanted.policy, param), wanted.priority or None)
    _call(tid, f"set {wanted}", lambda: os.sched_setaffinity(tid, wanted.cpus))


def name_thread(name: str) -> None:
    """Show the calling thread as ``name`` (its first 15 bytes) in ``top -H``, ``ps -L`` and ``/proc``; best effort."""
    with contextlib.suppress(OSError):
        Path(f"/proc/self/task/{threading.get_native_id()}/comm").write_text(name.encode()[:15].decode(errors="ignore"))


def threads_of(pid: int) -> list[int]:
    """Every thread id of process ``pid`` (empty if it is gone)."""
    if exited(pid):  # a dead process's /proc entry is not looked up (see at_sched_other)
        return []
    try:
        return sorted(int(entry.name) for entry in Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return []


def thread_name(pid: int, tid: int) -> str | None:
    """Thread ``tid`` of process ``pid``'s name (``comm``), or None if it is gone."""
    try:
        return Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
    except OSError:
        return None


MIDDLEWARE_THREADS = ("dds.", "recvUC", "recvMC", "dq.", "tev", "xmit.")
"""How middleware names its threads (``/proc/PID/task/TID/comm``): Fast DDS ``dds.*``; Cyclone DDS ``recvUC``,
``recvMC``, ``dq.*``, ``tev``, ``xmit.*``.  They never register: they carry the messages between processes."""
COMPANION_PREFIX = "catanc-"
"""A thread of a registered process named ``catanc-<node>`` serves ``<node>``'s thread (catanc.ros's watcher)."""


def exited(pid: int) -> bool:
    """Whether process ``pid`` has exited (a zombie too) or is gone, asked through a pidfd, not ``/proc``."""
    try:
        pidfd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    except OSError:  # no pidfds here (before Linux 5.3), or no descriptor left: say alive, look it up
        return False
    try:
        return pidfd_exited(pidfd)
    finally:
        os.close(pidfd)


def _lower_self() -> tuple[int, os.sched_param] | None:
    """Put the calling thread at SCHED_OTHER if it is real-time: its policy and parameter before, else None."""
    try:
        policy = os.sched_getscheduler(0)
        if policy & ~SCHED_RESET_ON_FORK not in (os.SCHED_FIFO, os.SCHED_RR):
            return None
        param = os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_OTHER | (policy & SCHED_RESET_ON_FORK), os.sched_param(0))
    except OSError:
        return None
    return policy, param


@contextlib.contextmanager
def at_sched_other() -> Iterator[None]:
    """Run the block with the calling thread at SCHED_OTHER if it is real-time, then put it back.

    For ``/proc`` path lookups of other processes: looking up a process that just died makes the
    kernel invalidate its dentries, which waits for the task releasing them; a real-time thread that
    preempted that task on its CPU waits for ever (catanc.runtime.linux.watchdog's notes).  At SCHED_OTHER
    the releasing task gets the CPU.  Two system calls each way: for rare events (registrations).
    """
    lowered = _lower_self()
    try:
        yield
    finally:
        if lowered is not None:
            os.sched_setscheduler(0, *lowered)


def allowed_cpus() -> frozenset[int]:
    """The CPUs this process may run on: its main thread's affinity, within the cpuset.

    The main thread's, not the calling thread's: ``taskset -p`` changes only the main thread's
    mask, and a thread the caller pinned itself says nothing about the process.
    """
    return frozenset(os.sched_getaffinity(os.getpid()))


T = TypeVar("T")


def _call(tid: int, doing: str, call: Callable[[], T], priority: int | None = None) -> T:
    try:
        return call()
    except ProcessLookupError as exc:
        raise ThreadGone(tid, doing) from exc
    except PermissionError as exc:
        raise PrivilegeError(
            f"may not {doing} for thread {tid}: {exc.strerror} ({privilege_facts()}).\n" + fix_message(priority)
        ) from exc
    except OSError as exc:
        raise SchedError(f"cannot {doing} for thread {tid}: {exc.strerror or exc}") from exc


# --------------------------------------------------------------------------- privileges


def fix_message(priority: int | None) -> str:
    """How to get the privilege SCHED_FIFO ``priority`` needs (``None``: changing another user's threads)."""
    user = _user_name(os.geteuid())
    if priority is None:
        return (
            "Fix: run catanc as root (sudo) or give it CAP_SYS_NICE, or run the app as the same user "
            f"as catanc ({user})."
        )
    return (
        "Fix: run catanc as root (sudo), or give it CAP_SYS_NICE (for instance AmbientCapabilities=CAP_SYS_NICE\n"
        f"in a systemd unit), or let the user use real-time priorities (a line '{user} - rtprio {priority}' in\n"
        "/etc/security/limits.conf, then log in again; RLIMIT_RTPRIO covers only the user's own threads),\n"
        "or enforce rates only, without real-time priorities: catanc run --no-rt"
    )


@dataclass(frozen=True)
class PrivilegeFacts:
    """What decides whether this process may use SCHED_FIFO."""

    euid: int
    cap_sys_nice: bool | None  # None: /proc/self/status unreadable
    rtprio_soft: int  # resource.RLIM_INFINITY for unlimited
    rtprio_hard: int

    def __str__(self) -> str:
        cap = {True: "CAP_SYS_NICE", False: "no CAP_SYS_NICE", None: "CAP_SYS_NICE unknown"}[self.cap_sys_nice]
        return f"euid {self.euid}, {cap}, RLIMIT_RTPRIO {_limit(self.rtprio_soft)} (hard {_limit(self.rtprio_hard)})"


def _limit(value: int) -> str:
    return "unlimited" if value == resource.RLIM_INFINITY else str(value)


def privilege_facts() -> PrivilegeFacts:
    """The effective uid, CAP_SYS_NICE (bit 23 of CapEff in /proc/self/status) and RLIMIT_RTPRIO."""
    cap: bool | None = None
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("CapEff:"):
                cap = bool(int(line.split(":", 1)[1].strip(), 16) >> CAP_SYS_NICE & 1)
    soft, hard = resource.getrlimit(resource.RLIMIT_RTPRIO)
    return PrivilegeFacts(os.geteuid(), cap, soft, hard)


def check_fifo_allowed(priority: int) -> None:
    """Raise :class:`~catanc.errors.PrivilegeError` unless this process may use SCHED_FIFO ``priority``.

    Tries it for real, on a helper thread that sleeps meanwhile, and puts the helper back.
    """
    if priority not in FIFO_PRIORITIES:
        raise ValueError(f"{priority} is not a SCHED_FIFO priority")
    tid: list[int] = []
    started, release = threading.Event(), threading.Event()

    def helper() -> None:
        tid.append(threading.get_native_id())
        started.set()
        release.wait(10.0)

    thread = threading.Thread(target=helper, name="catanc-fifo-probe", daemon=True)
    thread.start()
    refused: OSError | None = None
    try:
        started.wait(10.0)
        if not tid:
            raise SchedError("the SCHED_FIFO probe thread did not start")
        original = read_policy(tid[0])
        try:
            os.sched_setscheduler(tid[0], os.SCHED_FIFO, os.sched_param(priority))
        except OSError as exc:
            refused = exc
        else:
            apply_policy(tid[0], original)
    finally:
        release.set()
        thread.join(10.0)
    if refused is None:
        return
    facts = privilege_facts()
    if facts.euid != 0 and not facts.cap_sys_nice:
        why = (
            f"not root (euid {facts.euid}), no CAP_SYS_NICE, "
            f"and RLIMIT_RTPRIO is {_limit(facts.rtprio_soft)} (needs {priority})"
        )
    else:
        why = (
            f"the kernel refused it ({facts}; see /proc/sys/kernel/sched_rt_runtime_us "
            "and the cgroup's real-time budget, cpu.rt_runtime_us)"
        )
    raise PrivilegeError(
        f"cannot use SCHED_FIFO priority {priority}: {refused.strerror or refused}: {why}.\n" + fix_message(priority)
    )


def _user_name(uid: int) -> str:
    try:
        import pwd  # noqa: PLC0415

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return str(uid)


# --------------------------------------------------------------------------- putting threads back


@dataclass(frozen=True)
class Remembered:
    """A thread's original, with its start time (so a reused tid is not mistaken for it)."""

    original: ThreadPolicy
    start_time: int | None


@dataclass(frozen=True)
class RestoreReport:
    """What :meth:`Restorer.restore_all` did."""

    restored: tuple[int, ...] = ()
    gone: tuple[int, ...] = ()  # exited before they could be put back
    failed: tuple[tuple[int, str], ...] = ()  # (tid, why)

    @property
    def ok(self) -> bool:
        return not self.failed

    def __str__(self) -> str:
        text = f"restored {len(self.restored)} thread(s)"
        text += f", {len(self.gone)} had exited" if self.gone else ""
        return text + "".join(f"; thread {tid}: {why}" for tid, why in self.failed)


SignalHandler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None


class Restorer:
    """Remembers each thread's original scheduling and puts it back, whatever ends the enforcer.

    Call :meth:`remember` before first changing a thread.  Use it as a context manager (or call
    :meth:`install` and :meth:`close`) from the main thread: on leaving the block, on an exception,
    on SIGINT, SIGTERM or SIGHUP every remembered thread gets its original back.  A signal handler
    that was there before is chained: it runs after the restore (Python's SIGINT handler raises
    KeyboardInterrupt); a signal whose action was the default one ends the process as it would
    have, after the restore and with the same status; an ignored signal stays ignored.  With a
    watchdog attached, each remembered original is sent to it too, so SIGKILL is covered.
    :attr:`before_restore`, if set, runs on such a signal before the restore.
    """

    def __init__(self, watchdog: Watchdog | None = None) -> None:
        self._lock = threading.RLock()
        self._threads: dict[int, Remembered] = {}
        self._watchdog: Watchdog | None = None
        self._previous: dict[int, SignalHandler] = {}
        self._installed = False
        # Called on a signal before the restore: whoever changes threads stops first, so it does
        # not act on what the restore puts back (the enforcer read its CPU set as shrunk).
        self.before_restore: Callable[[], None] | None = None
        if watchdog is not None:
            self.attach(watchdog)

    @property
    def watchdog(self) -> Watchdog | None:
        return self._watchdog

    @property
    def remembered(self) -> dict[int, ThreadPolicy]:
        """``{tid: original}`` of every thread remembered and not found gone."""
        with self._lock:
            return {tid: entry.original for tid, entry in self._threads.items()}

    def attach(self, watchdog: Watchdog) -> None:
        """Send every original remembered so far to ``watchdog``, and each later one as it comes."""
        with self._lock:
            for tid, entry in self._threads.items():
                watchdog.remember(tid, entry.original, entry.start_time)
            self._watchdog = watchdog

    def remember(self, tid: int, original: ThreadPolicy | None = None) -> ThreadPolicy:
        """Record thread ``tid``'s original (once) and return it; :class:`ThreadGone` if it exited.

        ``original`` stands in for what the thread runs at now when that is not its own (a
        thread that inherited a raised thread's priority).  A tid seen before but now naming
        another thread (its start time differs) is recorded anew.
        """
        with self._lock:
            start_time = thread_start_time(tid)
            known = self._threads.get(tid)
            if known is not None and known.start_time == start_time:
                return known.original
            if original is None:
                original = read_policy(tid)
            elif start_time is None:
                raise ThreadGone(tid, "remember it")
            if original.policy & ~SCHED_RESET_ON_FORK == SCHED_DEADLINE:
                raise SchedError(f"thread {tid} runs at SCHED_DEADLINE, which catanc could not put back")
            self._threads[tid] = Remembered(original, start_time)
            if self._watchdog is not None:
                self._watchdog.remember(tid, original, start_time)
            return original

    def restore_all(self) -> RestoreReport:
        """Put every remembered thread back (vanished ones are skipped and forgotten); never raises.

        At SCHED_OTHER: each thread is looked up in ``/proc`` (its start time), which must not happen
        at SCHED_FIFO (:func:`at_sched_other`; ``catanc bench``'s raised driver spun in the kernel for
        16 minutes restoring its exited workers).  A real-time caller is lowered for it, and raised
        again after unless it was one of the threads put back.  Idempotent: calling it again puts back
        threads changed again since.
        """
        restored: list[int] = []
        gone: list[int] = []
        failed: list[tuple[int, str]] = []
        with self._lock:
            lowered = _lower_self()
            try:
                for tid, entry in list(self._threads.items()):
                    try:
                        if entry.start_time is not None and thread_start_time(tid) != entry.start_time:
                            raise ThreadGone(tid, "restore it")
                        apply_policy(tid, entry.original)
                    except ThreadGone:
                        gone.append(tid)
                        del self._threads[tid]
                    except Exception as exc:  # never raises: restore every thread it can
                        failed.append((tid, (str(exc).splitlines() or [type(exc).__name__])[0]))
                    else:
                        restored.append(tid)
            finally:
                if lowered is not None and threading.get_native_id() not in restored:
                    with contextlib.suppress(OSError):
                        os.sched_setscheduler(0, *lowered)
        return RestoreReport(tuple(restored), tuple(gone), tuple(failed))

    # ----------------------------------------------------------------------- the safety net

    def install(self) -> Self:
        """Restore on SIGINT, SIGTERM, SIGHUP and at interpreter exit; call it from the main thread."""
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("Restorer.install() must be called from the main thread (signal handlers)")
        with self._lock:
            if self._installed:
                return self
            for signum in HANDLED_SIGNALS:
                previous = signal.getsignal(signum)
                if previous is None:  # set outside Python: cannot be chained, take it as the default
                    previous = signal.SIG_DFL
                if previous is signal.SIG_IGN:
                    continue  # an ignored signal does not end the process: nothing to restore for it
                self._previous[signum] = previous
                signal.signal(signum, self._on_signal)
            atexit.register(self.close)
            self._installed = True
        return self

    def close(self) -> RestoreReport:
        """Restore every thread, let the watchdog go and take the signal handlers back; never raises."""
        report = self.restore_all()
        self._finish_watchdog(wait=True)
        self._uninstall()
        return report

    def __enter__(self) -> Self:
        return self.install()

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        if self.before_restore is not None:
            with contextlib.suppress(Exception):  # the restore must happen whatever the callback does
                self.before_restore()
        self.restore_all()
        previous = self._previous.get(signum, signal.SIG_DFL)
        if callable(previous):
            previous(signum, frame)
            return
        # The default action ends the process: do that now, with the signal's status.
        self._finish_watchdog(wait=False)
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    def _finish_watchdog(self, *, wait: bool) -> None:
        with self._lock:
            watchdog = self._watchdog
        if watchdog is not None:
            with contextlib.suppress(Exception):
                watchdog.clean_exit(wait=5.0 if wait else 0.0)

    def _uninstall(self) -> None:
        with self._lock:
            if not self._installed:
                return
            self._installed = False
            atexit.unregister(self.close)
            if threading.current_thread() is threading.main_thread():
                for signum, previous in self._previous.items():
                    if signal.getsignal(signum) == self._on_signal:
                        signal.signal(signum, previous)
            self._previous.clear()
