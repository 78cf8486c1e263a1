"""catanc.runtime.linux.sched and catanc.runtime.linux.watchdog, on the real kernel.

The threads changed here belong to a helper process, the *app*: a small Python program whose
threads start with given policies, priorities and CPUs, sleep, and on ``go`` busy-spin (hashing a
large buffer, which releases the GIL, so they really spin on their CPUs at once) until ``stop`` or
a budget of a few seconds.  Every check of a thread's scheduling reads ``/proc/<pid>/task/<tid>``
(``stat`` fields 40 and 41, ``status``'s Cpus_allowed_list), never :func:`read_policy`.

The restore tests run an *enforcer*: a Python program using the API on the app's threads, then
leaving normally, raising, getting SIGINT, SIGTERM or SIGKILL.  The SIGKILL tests are the hard
case: the app's threads spin at SCHED_FIFO 1 on both CPUs, so the test itself runs at a higher
SCHED_FIFO priority while it kills the enforcer and watches; the spin is bounded (a few seconds)
and the kernel's real-time throttling stays on, so a failing test cannot wedge the machine.

The tests skip when SCHED_FIFO is not permitted (probed first) or CPUs 0 and 1 are not both
allowed; the unprivileged ones also need root, ``setpriv`` and ``prlimit``.  Every child is
killed at teardown, whatever happens.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import pytest

from catanc.errors import CatancError, ExitCode, PrivilegeError
from catanc.runtime.linux.sched import (
    Restorer,
    ThreadGone,
    ThreadPolicy,
    allowed_cpus,
    apply_policy,
    at_sched_other,
    check_fifo_allowed,
    exited,
    privilege_facts,
    read_policy,
    set_affinity,
    set_fifo,
    set_other,
)
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY, thread_start_time
from tests.support.linux import as_user, cpu_set, poll, stat_fields

WAIT_S = 10.0  # the longest any single wait in here may take
KILL_BOUND_S = 1.0  # the issue: no app thread stays at SCHED_FIFO longer than this after a SIGKILL
SPIN_BUDGET_S = 3.0  # the longest the app's threads spin
OBSERVER_PRIORITY = 20  # the test itself while the app spins: above the app, the enforcer and the watchdog
ENFORCER_PRIORITY = 4
BOTH = frozenset({0, 1})

APP = """\
import hashlib, json, os, sys, threading, time

originals = json.loads(sys.argv[1])  # [[policy, priority, cpus or null], ...] for each thread
budget = float(sys.argv[2])
go, stop = threading.Event(), threading.Event()
tids = [0] * len(originals)
ready = threading.Barrier(len(originals) + 1, timeout=10)
data = bytes(1 << 22)

def work(i, policy, priority, cpus):
    os.sched_setscheduler(0, policy, os.sched_param(priority))
    if cpus:
        os.sched_setaffinity(0, cpus)
    tids[i] = threading.get_native_id()
    ready.wait()
    if go.wait(30):
        deadline = time.monotonic() + budget
        while not stop.is_set() and time.monotonic() < deadline:
            hashlib.sha256(data)  # releases the GIL: every thread spins at once
    stop.wait(30)

threads = [threading.Thread(target=work, args=(i, *o), daemon=True) for i, o in enumerate(originals)]
for thread in threads:
    thread.start()
ready.wait()
print(json.dumps({"pid": os.getpid(), "tids": tids}), flush=True)
for line in sys.stdin:
    if line.strip() == "go":
        go.set()
    elif line.strip() == "stop":
        stop.set()
stop.set()
"""

ENFORCER = """\
import json, os, signal, sys, time
from catanc.runtime.linux.sched import Restorer, set_affinity, set_fifo
from catanc.runtime.linux.watchdog import Watchdog

signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, even if the test runner ignores it
how, changes, own_priority = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3])
with Restorer(Watchdog().start()) as restorer:
    for tid, priority, cpus in changes:
        restorer.remember(tid)
        set_fifo(tid, priority)
        set_affinity(tid, cpus)
    if own_priority:  # like the enforcer's scheduler threads
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(own_priority))
    print(json.dumps({"watchdog": restorer.watchdog.pid, "priority": restorer.watchdog.priority}), flush=True)
    if how == "wait":
        time.sleep(30)  # until the test's signal
    sys.stdin.readline()  # the test has looked at the changed threads
    if how == "raise":
        raise RuntimeError("the enforcer failed")
    if how == "abandon":
        os._exit(3)  # no clean-up at all: the watchdog must notice
"""

PROBE = """\
import sys
from catanc.errors import CatancError
from catanc.runtime.linux.sched import check_fifo_allowed

try:
    check_fifo_allowed(int(sys.argv[1]))
except CatancError as err:
    print(err, file=sys.stderr)
    sys.exit(int(err.exit_code))
print("allowed")
"""


# --------------------------------------------------------------------------- reading /proc


@dataclass(frozen=True)
class Sched:
    policy: int
    priority: int
    cpus: frozenset[int]


OTHER = Sched(os.SCHED_OTHER, 0, BOTH)


def sched_of(pid: int, tid: int) -> Sched:
    """Thread ``tid``'s policy (stat field 41), rt_priority (field 40) and Cpus_allowed_list."""
    folder = f"/proc/{pid}/task/{tid}"
    fields = stat_fields(f"{folder}/stat")
    for line in Path(f"{folder}/status").read_text().splitlines():
        if line.startswith("Cpus_allowed_list:"):
            cpus = cpu_set(line.split(":", 1)[1].strip())
            return Sched(int(fields[41 - 3]), int(fields[40 - 3]), cpus)
    raise AssertionError(f"no Cpus_allowed_list in {folder}/status")


def alive(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie."""
    try:
        return stat_fields(f"/proc/{pid}/stat")[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def on_cpu_ns(pid: int, tid: int) -> int:
    """How long thread ``tid`` has run (``schedstat``'s first field, in ns)."""
    return int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])


# --------------------------------------------------------------------------- the children


@dataclass
class App:
    proc: subprocess.Popen[str]
    pid: int
    tids: list[int]

    def sched(self, index: int) -> Sched:
        return sched_of(self.pid, self.tids[index])

    def say(self, word: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(word + "\n")
        self.proc.stdin.flush()


@dataclass
class Enforcer:
    proc: subprocess.Popen[str]
    watchdog: int
    watchdog_priority: int
    stderr: Path

    def wait(self) -> int:
        try:
            return self.proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the enforcer still runs after {WAIT_S} s")


def read_json_line(proc: subprocess.Popen[str], what: str) -> dict[str, Any]:
    """The first line ``proc`` prints, as JSON; fails if it does not come within :data:`WAIT_S`."""
    stream: IO[str] | None = proc.stdout
    assert stream is not None
    if not select.select([stream], [], [], WAIT_S)[0]:
        pytest.fail(f"{what} printed nothing within {WAIT_S} s")
    line = stream.readline()
    if not line:
        pytest.fail(f"{what} exited ({proc.wait(timeout=WAIT_S)}) before it was ready")
    found: dict[str, Any] = json.loads(line)
    return found


Spawner = Callable[..., subprocess.Popen[str]]
watchdogs: list[int] = []  # the watchdogs the current test's enforcers started (killed at teardown)


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator[Spawner]:
    """``spawn(argv, stderr=None)``: a child with pipes for stdin and stdout, SIGKILLed at teardown.

    Each child gets its own session (so a signal to its process group reaches it alone); a
    watchdog an enforcer reported is killed too (after checking it is one: pids are reused).
    """
    children: list[subprocess.Popen[str]] = []

    def start(argv: Sequence[str], stderr: Path | None = None) -> subprocess.Popen[str]:
        with (stderr or tmp_path / f"stderr-{len(children)}.txt").open("w") as err:
            proc = subprocess.Popen(
                list(argv),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                start_new_session=True,
            )
        children.append(proc)
        return proc

    yield start
    for proc in children:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=WAIT_S)
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
    for pid in watchdogs:
        with contextlib.suppress(OSError):
            if b"watchdog.py" in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)
    watchdogs.clear()


def start_app(spawn: Spawner, originals: Sequence[tuple[int, int, Sequence[int] | None]]) -> App:
    proc = spawn([sys.executable, "-c", APP, json.dumps(originals), str(SPIN_BUDGET_S)])
    ready = read_json_line(proc, "the app")
    return App(proc, ready["pid"], ready["tids"])


def start_enforcer(
    spawn: Spawner, tmp_path: Path, how: str, changes: Sequence[tuple[int, int, Sequence[int]]], own_priority: int = 0
) -> Enforcer:
    stderr = tmp_path / "enforcer-stderr.txt"
    argv = [sys.executable, "-c", ENFORCER, how, json.dumps(changes), str(own_priority)]
    proc = spawn(argv, stderr=stderr)
    ready = read_json_line(proc, "the enforcer")
    watchdogs.append(ready["watchdog"])
    return Enforcer(proc, ready["watchdog"], ready["priority"], stderr)


@contextlib.contextmanager
def realtime(priority: int) -> Iterator[None]:
    """Run the calling thread at SCHED_FIFO ``priority`` for a while (start no process meanwhile)."""
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


@contextlib.contextmanager
def sleeping_thread() -> Iterator[int]:
    """A thread of this process that sleeps until the block ends (then it exits): its tid."""
    tids: list[int] = []
    started, release = threading.Event(), threading.Event()

    def sleeper() -> None:
        tids.append(threading.get_native_id())
        started.set()
        release.wait(WAIT_S)

    thread = threading.Thread(target=sleeper, daemon=True)
    thread.start()
    try:
        assert started.wait(WAIT_S)
        yield tids[0]
    finally:
        release.set()
        thread.join(WAIT_S)


# --------------------------------------------------------------------------- what the machine allows


REALTIME_PRIORITY = OBSERVER_PRIORITY  # conftest's real_kernel: SCHED_FIFO up to the observer's priority


def run_probe(prefix: Sequence[str], priority: int) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*prefix, sys.executable, "-c", PROBE, str(priority)],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
        cwd="/",
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )


# --------------------------------------------------------------------------- one thread

MIXED = [(os.SCHED_OTHER, 0, None), (os.SCHED_RR, 5, [1]), (os.SCHED_BATCH, 0, [0])]
MIXED_SCHED = [OTHER, Sched(os.SCHED_RR, 5, frozenset({1})), Sched(os.SCHED_BATCH, 0, frozenset({0}))]


@pytest.mark.usefixtures("real_kernel")
def test_read_policy_reads_each_thread(spawn: Spawner) -> None:
    app = start_app(spawn, MIXED)
    assert len(set(app.tids)) == 3
    assert app.pid not in app.tids  # the app's threads, not its main thread
    for index, expected in enumerate(MIXED_SCHED):
        assert app.sched(index) == expected  # the premise: the threads differ
        assert read_policy(app.tids[index]) == ThreadPolicy(expected.policy, expected.priority, expected.cpus)


def test_exited_is_false_while_a_process_runs_and_true_once_it_is_a_zombie_or_reaped() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    assert not exited(child.pid)
    assert child.stdin is not None
    child.stdin.close()
    os.waitid(os.P_PID, child.pid, os.WEXITED | os.WNOWAIT)  # it has exited; not reaped yet: a zombie
    assert exited(child.pid)
    assert child.wait() == 0
    assert exited(child.pid)


@pytest.mark.usefixtures("real_kernel")
def test_at_sched_other_lowers_a_real_time_thread_for_the_block_only() -> None:
    seen: list[tuple[int, int]] = []
    failures: list[BaseException] = []

    def thread() -> None:
        def now() -> tuple[int, int]:
            return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority

        try:
            reset = os.SCHED_RESET_ON_FORK
            os.sched_setscheduler(0, os.SCHED_FIFO | reset, os.sched_param(1))
            with at_sched_other():
                seen.append(now())
            seen.append(now())
            with pytest.raises(KeyError), at_sched_other():
                raise KeyError("in the block")
            seen.append(now())
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            with at_sched_other():
                seen.append(now())
        except BaseException as exc:  # handed to the test's thread
            failures.append(exc)
        finally:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    worker = threading.Thread(target=thread)
    worker.start()
    worker.join(WAIT_S)
    assert failures == []
    fifo = (os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, 1)
    other = (os.SCHED_OTHER | os.SCHED_RESET_ON_FORK, 0)
    assert seen == [other, fifo, fifo, (os.SCHED_OTHER, 0)]


@pytest.mark.usefixtures("real_kernel")
def test_set_fifo_set_affinity_and_set_other_change_only_the_given_thread(spawn: Spawner) -> None:
    app = start_app(spawn, MIXED)
    tid = app.tids[0]
    set_fifo(tid, 3)
    assert app.sched(0) == Sched(os.SCHED_FIFO, 3, BOTH)
    set_affinity(tid, [1])
    assert app.sched(0) == Sched(os.SCHED_FIFO, 3, frozenset({1}))
    set_fifo(tid, 1)
    assert app.sched(0) == Sched(os.SCHED_FIFO, 1, frozenset({1}))
    set_other(tid)
    assert app.sched(0) == Sched(os.SCHED_OTHER, 0, frozenset({1}))
    assert [app.sched(index) for index in (1, 2)] == MIXED_SCHED[1:]
    apply_policy(app.tids[1], ThreadPolicy(os.SCHED_FIFO, 2, frozenset({0})))
    assert app.sched(1) == Sched(os.SCHED_FIFO, 2, frozenset({0}))


def test_bad_arguments_are_refused_before_any_system_call() -> None:
    tid = threading.get_native_id()
    with pytest.raises(ValueError, match="not a SCHED_FIFO priority"):
        set_fifo(tid, 0)
    with pytest.raises(ValueError, match="not a SCHED_FIFO priority"):
        set_fifo(tid, 100)
    with pytest.raises(ValueError, match="empty CPU set"):
        set_affinity(tid, [])


def exited_thread() -> int:
    """The tid of a thread of this process that has exited."""
    tids: list[int] = []
    thread = threading.Thread(target=lambda: tids.append(threading.get_native_id()))
    thread.start()
    thread.join(WAIT_S)
    gone(tids[0])
    return tids[0]


def gone(tid: int) -> None:
    """Waits until thread ``tid`` of this process has left the kernel (``join()`` returns a moment before)."""
    poll(lambda: not Path(f"/proc/self/task/{tid}").exists(), f"thread {tid} to exit")


@pytest.mark.parametrize(
    "call",
    [
        pytest.param(read_policy, id="read_policy"),
        pytest.param(lambda tid: set_fifo(tid, 1), id="set_fifo"),
        pytest.param(set_other, id="set_other"),
        pytest.param(lambda tid: set_affinity(tid, [0]), id="set_affinity"),
        pytest.param(lambda tid: apply_policy(tid, ThreadPolicy(os.SCHED_OTHER, 0, BOTH)), id="apply_policy"),
    ],
)
def test_a_thread_that_exited_is_thread_gone(call: Callable[[int], object]) -> None:
    tid = exited_thread()
    with pytest.raises(ThreadGone, match=f"thread {tid} exited") as caught:
        call(tid)
    assert caught.value.tid == tid
    assert isinstance(caught.value, CatancError)
    assert not isinstance(caught.value, PrivilegeError)


def test_allowed_cpus_is_the_affinity_of_the_calling_thread() -> None:
    assert allowed_cpus() == frozenset(os.sched_getaffinity(0))
    assert allowed_cpus()


# --------------------------------------------------------------------------- the restorer, in this process


@pytest.mark.usefixtures("real_kernel")
def test_remember_records_the_original_once_and_restore_all_can_be_repeated(spawn: Spawner) -> None:
    app = start_app(spawn, MIXED)
    restorer = Restorer()
    for tid in app.tids:
        restorer.remember(tid)
    for tid, priority, cpus in zip(app.tids, (1, 2, 3), ({0}, {1}, {0, 1}), strict=True):
        set_fifo(tid, priority)
        set_affinity(tid, cpus)
    assert app.sched(1) == Sched(os.SCHED_FIFO, 2, frozenset({1}))
    # Remembering a changed thread again keeps its original.
    assert restorer.remember(app.tids[1]) == ThreadPolicy(os.SCHED_RR, 5, frozenset({1}))
    for _ in range(2):
        report = restorer.restore_all()
        assert sorted(report.restored) == sorted(app.tids)
        assert report.ok
        assert not report.gone
        assert [app.sched(index) for index in range(3)] == MIXED_SCHED
    # Threads changed again after a restore are put back again.
    set_fifo(app.tids[2], 3)
    restorer.restore_all()
    assert app.sched(2) == MIXED_SCHED[2]


@pytest.mark.usefixtures("real_kernel")
def test_restore_all_skips_and_forgets_a_thread_that_exited() -> None:
    with sleeping_thread() as tid:
        restorer = Restorer()
        assert restorer.remember(tid).policy == os.SCHED_OTHER
        set_fifo(tid, 1)  # it sleeps: nothing runs at SCHED_FIFO
    gone(tid)
    report = restorer.restore_all()
    assert report.gone == (tid,)
    assert report.ok
    assert not report.restored
    assert restorer.restore_all() == type(report)()  # forgotten
    with pytest.raises(ThreadGone):
        restorer.remember(tid)


@pytest.mark.usefixtures("real_kernel")
def test_restore_all_leaves_alone_a_thread_whose_tid_now_names_another(monkeypatch: pytest.MonkeyPatch) -> None:
    """A thread is its tid and its start time: a reused tid is not put back as if it were the old thread."""
    with sleeping_thread() as tid:
        try:
            restorer = Restorer()
            restorer.remember(tid)
            set_fifo(tid, 1)  # it sleeps: nothing runs at SCHED_FIFO
            monkeypatch.setattr("catanc.runtime.linux.sched.thread_start_time", lambda _tid: -1)
            report = restorer.restore_all()
            assert report.gone == (tid,)
            assert sched_of(os.getpid(), tid).policy == os.SCHED_FIFO
        finally:
            set_other(tid)


@contextlib.contextmanager
def restorer_over_a_raised_sleeper(
    handler: Callable[[int, Any], None] = lambda _signum, _frame: None,
) -> Iterator[tuple[Restorer, int]]:
    """An installed Restorer that remembered a sleeping thread, then raised to FIFO 1; SIGHUP's
    handler before it was ``handler``."""
    before = signal.signal(signal.SIGHUP, handler)
    try:
        with sleeping_thread() as tid:
            try:
                with Restorer() as restorer:
                    restorer.remember(tid)
                    set_fifo(tid, 1)  # it sleeps: nothing runs at SCHED_FIFO
                    yield restorer, tid
            finally:
                set_other(tid)
    finally:
        signal.signal(signal.SIGHUP, before)


@pytest.mark.usefixtures("real_kernel")
def test_a_signal_restores_at_once_then_runs_the_handler_that_was_there() -> None:
    received: list[int] = []
    with restorer_over_a_raised_sleeper(lambda signum, _frame: received.append(signum)) as (restorer, tid):
        signal.raise_signal(signal.SIGHUP)
        assert received == [signal.SIGHUP]  # chained, and the process goes on
        assert sched_of(os.getpid(), tid) == Sched(os.SCHED_OTHER, 0, frozenset(os.sched_getaffinity(0)))
        restorer.close()  # what leaving its block does
        signal.raise_signal(signal.SIGHUP)  # the handler that was there is back
        assert received == [signal.SIGHUP, signal.SIGHUP]


@pytest.mark.usefixtures("real_kernel")
def test_a_signal_calls_before_restore_while_the_threads_are_still_changed() -> None:
    """The enforcer stops its loop first: a loop that ran between the restore and its stop read its
    CPU set as the main thread's first one and re-planned for fewer cores (CI, 2026-11-28)."""
    seen: list[int] = []
    with restorer_over_a_raised_sleeper() as (restorer, tid):
        restorer.before_restore = lambda: seen.append(sched_of(os.getpid(), tid).policy)
        signal.raise_signal(signal.SIGHUP)
        assert seen == [os.SCHED_FIFO]  # called once, before the thread was put back
        assert sched_of(os.getpid(), tid).policy == os.SCHED_OTHER


@pytest.mark.usefixtures("real_kernel")
def test_a_failing_before_restore_does_not_stop_the_restore() -> None:
    def broken() -> None:
        raise RuntimeError("a callback that fails")

    with restorer_over_a_raised_sleeper() as (restorer, tid):
        restorer.before_restore = broken
        signal.raise_signal(signal.SIGHUP)
        assert sched_of(os.getpid(), tid).policy == os.SCHED_OTHER


def test_install_leaves_the_signal_handlers_as_they_were() -> None:
    before = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    with Restorer() as restorer:
        assert signal.getsignal(signal.SIGTERM) != before[signal.SIGTERM]
        if before[signal.SIGINT] is signal.SIG_IGN:
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN  # an ignored signal stays ignored
        assert restorer.remembered == {}
    assert {signum: signal.getsignal(signum) for signum in before} == before


def test_install_from_another_thread_is_refused() -> None:
    errors: list[BaseException] = []

    def install() -> None:
        try:
            Restorer().install()
        except RuntimeError as exc:
            errors.append(exc)

    thread = threading.Thread(target=install)
    thread.start()
    thread.join(WAIT_S)
    assert len(errors) == 1
    assert "main thread" in str(errors[0])


# --------------------------------------------------------------------------- an enforcer ending


def watchdog_gone(enforcer: Enforcer) -> bool:
    return not alive(enforcer.watchdog)


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize(
    ("how", "signum", "status"),
    [
        ("exit", None, 0),
        ("raise", None, 1),
        ("wait", signal.SIGINT, -signal.SIGINT),
        ("wait", signal.SIGTERM, -signal.SIGTERM),
        ("abandon", None, 3),
    ],
    ids=["normal-exit", "exception", "SIGINT", "SIGTERM", "os._exit"],
)
def test_every_changed_thread_gets_its_original_back_when_the_enforcer_ends(
    spawn: Spawner, tmp_path: Path, how: str, signum: signal.Signals | None, status: int
) -> None:
    app = start_app(spawn, MIXED)
    changes = [(app.tids[0], 3, [1]), (app.tids[1], 2, [0]), (app.tids[2], 1, [0, 1])]
    enforcer = start_enforcer(spawn, tmp_path, how, changes)
    for index, (_, priority, cpus) in enumerate(changes):
        assert app.sched(index) == Sched(os.SCHED_FIFO, priority, frozenset(cpus))
    # The watchdog is in a session of its own: a signal to the enforcer's process group misses it.
    assert os.getsid(enforcer.watchdog) == enforcer.watchdog != os.getsid(enforcer.proc.pid)
    if signum is None:
        assert enforcer.proc.stdin is not None
        enforcer.proc.stdin.write("done\n")
        enforcer.proc.stdin.flush()
    else:
        os.killpg(enforcer.proc.pid, signum)
    assert enforcer.wait() == status
    poll(lambda: watchdog_gone(enforcer), "the watchdog to exit")
    assert [app.sched(index) for index in range(3)] == MIXED_SCHED
    stderr = enforcer.stderr.read_text()  # the watchdog's too, complete now
    if how == "abandon":  # nothing ran in the enforcer: the watchdog put them back
        assert f"catanc watchdog: the enforcer (pid {enforcer.proc.pid})" in stderr
        assert "put 3 back" in stderr
    else:  # the enforcer put them back and told the watchdog, which touched nothing
        assert "catanc watchdog" not in stderr, stderr
    if how == "raise":
        assert "RuntimeError: the enforcer failed" in stderr


def spinning(app: App, window: float = 0.25) -> list[float]:
    """The share of a ``window`` each of the app's threads spent on a CPU."""
    before = [on_cpu_ns(app.pid, tid) for tid in app.tids]
    time.sleep(window)
    after = [on_cpu_ns(app.pid, tid) for tid in app.tids]
    return [(end - start) / 1e9 / window for start, end in zip(before, after, strict=True)]


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("own_priority", [0, ENFORCER_PRIORITY], ids=["enforcer-at-SCHED_OTHER", "enforcer-at-FIFO-4"])
def test_after_a_sigkill_the_watchdog_restores_threads_spinning_at_fifo_on_every_cpu(
    spawn: Spawner, tmp_path: Path, own_priority: int
) -> None:
    """The enforcer at SCHED_OTHER is the harder case: starved, it cannot even finish dying."""
    app = start_app(spawn, [(os.SCHED_OTHER, 0, None), (os.SCHED_OTHER, 0, None)])
    changes = [(app.tids[0], 1, [0]), (app.tids[1], 1, [1])]
    enforcer = start_enforcer(spawn, tmp_path, "wait", changes, own_priority)
    assert [app.sched(0), app.sched(1)] == [Sched(os.SCHED_FIFO, 1, frozenset({cpu})) for cpu in (0, 1)]
    watchdog = Path(f"/proc/{enforcer.watchdog}/stat")
    assert int(stat_fields(str(watchdog))[41 - 3]) == os.SCHED_FIFO
    assert int(stat_fields(str(watchdog))[40 - 3]) == enforcer.watchdog_priority == WATCHDOG_PRIORITY
    assert WATCHDOG_PRIORITY > ENFORCER_PRIORITY

    with realtime(OBSERVER_PRIORITY):
        app.say("go")
        time.sleep(0.1)
        shares = spinning(app)
        # The premise: both threads hold their CPUs (nothing at SCHED_OTHER runs now).
        assert min(shares) > 0.5, shares
        killed = time.monotonic()
        os.kill(enforcer.proc.pid, signal.SIGKILL)
        deadline = killed + WAIT_S
        while [app.sched(0), app.sched(1)] != [OTHER, OTHER] and time.monotonic() < deadline:
            time.sleep(0.001)
        restored = time.monotonic()
        final = [app.sched(0), app.sched(1)]
        app.say("stop")
    assert final == [OTHER, OTHER]
    assert restored - killed < KILL_BOUND_S
    assert enforcer.wait() == -signal.SIGKILL
    poll(lambda: watchdog_gone(enforcer), "the watchdog to exit")
    stderr = enforcer.stderr.read_text()
    assert f"catanc watchdog: the enforcer (pid {enforcer.proc.pid})" in stderr
    assert "put 2 back" in stderr
    if not own_priority:  # it noticed the SIGKILL while the starved enforcer could not yet finish dying
        assert "was killed" in stderr, stderr


# --------------------------------------------------------------------------- privileges


@pytest.mark.usefixtures("real_kernel")
def test_check_fifo_allowed_passes_here_and_leaves_the_calling_thread_alone() -> None:
    before = (os.sched_getscheduler(0), os.sched_getparam(0), os.sched_getaffinity(0))
    check_fifo_allowed(ENFORCER_PRIORITY)
    check_fifo_allowed(OBSERVER_PRIORITY)
    assert (os.sched_getscheduler(0), os.sched_getparam(0), os.sched_getaffinity(0)) == before
    assert privilege_facts().euid == os.geteuid()


def test_check_fifo_allowed_refuses_a_priority_that_is_not_one() -> None:
    with pytest.raises(ValueError, match="not a SCHED_FIFO priority"):
        check_fifo_allowed(0)


def test_without_privilege_the_error_says_how_to_fix_it_and_exits_with_no_privilege(nobody: tuple[int, int]) -> None:
    result = run_probe(as_user(*nobody, rtprio=0), ENFORCER_PRIORITY)
    assert result.returncode == ExitCode.NO_PRIVILEGE, result.stderr
    assert int(ExitCode.NO_PRIVILEGE) == 4  # documented in docs/reference/spec.md
    message = result.stderr
    assert f"cannot use SCHED_FIFO priority {ENFORCER_PRIORITY}" in message
    assert f"not root (euid {nobody[0]}), no CAP_SYS_NICE, and RLIMIT_RTPRIO is 0 (needs 4)" in message
    for fix in ("root", "CAP_SYS_NICE", "rtprio 4", "/etc/security/limits.conf", "--no-rt"):
        assert fix in message, fix
    assert "Traceback" not in message


def test_cap_sys_nice_is_enough(nobody: tuple[int, int]) -> None:
    result = run_probe(as_user(*nobody, rtprio=0, caps="sys_nice"), ENFORCER_PRIORITY)
    assert (result.returncode, result.stdout.strip()) == (0, "allowed"), result.stderr


def test_rlimit_rtprio_allows_up_to_its_value(nobody: tuple[int, int]) -> None:
    check = subprocess.run(
        ["prlimit", "--rtprio=4:4", "true"], capture_output=True, text=True, timeout=WAIT_S, check=False
    )
    if check.returncode != 0:
        pytest.skip(f"may not raise RLIMIT_RTPRIO here: {check.stderr.strip()}")
    allowed = run_probe(as_user(*nobody, rtprio=4), 4)
    assert (allowed.returncode, allowed.stdout.strip()) == (0, "allowed"), allowed.stderr
    refused = run_probe(as_user(*nobody, rtprio=4), 5)
    assert refused.returncode == ExitCode.NO_PRIVILEGE, refused.stderr
    assert "RLIMIT_RTPRIO is 4 (needs 5)" in refused.stderr


@pytest.mark.usefixtures("real_kernel")
def test_restore_all_looks_threads_up_in_proc_only_below_sched_fifo(monkeypatch: pytest.MonkeyPatch) -> None:
    """A raised caller remembered last (bench's driver) is put back first; the others are looked up at
    SCHED_OTHER: a /proc lookup of an exited thread at SCHED_FIFO can spin in the kernel for good."""
    policies: list[int] = []

    def start_time(tid: int) -> int | None:
        policies.append(os.sched_getscheduler(0))
        return thread_start_time(tid)

    with sleeping_thread() as tid:
        try:
            restorer = Restorer()
            restorer.remember(tid)
            set_fifo(tid, 1)  # it sleeps: nothing runs at SCHED_FIFO
            restorer.remember(threading.get_native_id())  # at SCHED_OTHER, remembered last
            with realtime(2):
                monkeypatch.setattr("catanc.runtime.linux.sched.thread_start_time", start_time)
                report = restorer.restore_all()
                after = os.sched_getscheduler(0)
        finally:
            set_other(tid)
    assert sorted(report.restored) == sorted([tid, threading.get_native_id()])
    assert after == os.SCHED_OTHER  # the caller is back at its original
    assert len(policies) == 2
    assert os.SCHED_FIFO not in policies
