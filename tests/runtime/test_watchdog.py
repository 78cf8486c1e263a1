"""The watchdog process on the real kernel, traced: it never looks a path up in /proc at SCHED_FIFO.

Looking up a dead process's ``/proc`` entry makes the kernel invalidate its dentries, and that
spins until the task releasing them (its reaper) finishes; a real-time watchdog that preempted
the reaper on its CPU spun for 6 minutes at FIFO 10 in a full test run.  The trace (strace's
``openat`` and ``sched_setscheduler``) shows every path the watchdog opens and when it became
real-time, so the test fails on any ``/proc`` lookup after that, whatever the kernel's timing.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY, _dying, _open_stat
from tests.support.linux import stat_fields

REALTIME_PRIORITY = WATCHDOG_PRIORITY
REALTIME_TOOLS = ("strace",)
pytestmark = pytest.mark.usefixtures("real_kernel")

# The enforcer's part, cut to the bone: start a watchdog, tell it two app processes' originals and
# raise them (one exits before the end), then die without saying goodbye.
ENFORCER = """
import os, subprocess, sys, time
from catanc.runtime.linux.sched import ThreadPolicy
from catanc.runtime.linux.watchdog import Watchdog

watchdog = Watchdog().start()
assert watchdog.priority > 0, watchdog.priority
here = ThreadPolicy(os.SCHED_OTHER, 0, frozenset(os.sched_getaffinity(0)))
app = int(sys.argv[1])  # started by the test: strace -ff would wait for it
brief = subprocess.Popen(["sleep", "0.3"], start_new_session=True)
for pid in (app, brief.pid):
    watchdog.remember(pid, here)
    os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(1))
brief.wait()
time.sleep(0.1)
os._exit(0)
"""


def traces(prefix: Path) -> dict[int, str]:
    return {int(path.name.rsplit(".", 1)[1]): path.read_text() for path in prefix.parent.glob(prefix.name + ".*")}


def test_the_watchdog_restores_without_a_proc_lookup_at_sched_fifo(tmp_path: Path) -> None:
    prefix = tmp_path / "trace"
    command = ["strace", "-ff", "-qq", "-e", "trace=openat,sched_setscheduler", "-o", str(prefix)]
    app = subprocess.Popen(["sleep", "60"], start_new_session=True)
    try:
        command += [sys.executable, "-c", ENFORCER, str(app.pid)]
        done = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
        assert done.returncode == 0, done.stderr
        assert os.sched_getscheduler(app.pid) == os.SCHED_OTHER  # the watchdog put it back
    finally:
        app.kill()
        app.wait()
    # strace -ff follows the watchdog until it exits, so its report is complete now.
    assert "catanc watchdog: the enforcer" in done.stderr, done.stderr
    assert "put 1 back, 1 had exited" in done.stderr, done.stderr
    raised = "sched_setscheduler(0, SCHED_FIFO"  # only the watchdog makes itself real-time
    watchdogs = [text for text in traces(prefix).values() if raised in text]
    assert len(watchdogs) == 1, sorted(traces(prefix))
    before, realtime = watchdogs[0].split(raised, 1)
    lookups = re.findall(r'openat\([^,]*, "(/proc/[^"]*)"', realtime)
    assert lookups == [], f"the watchdog looked up {lookups} at SCHED_FIFO"
    # The premise: before it was real-time, it did open the enforcer's /proc stat (to read it later).
    assert re.search(r'openat\([^,]*, "/proc/\d+/stat"', before), before


# A process on CPU 0 kept off it by a SCHED_FIFO spinner there: once killed it cannot run to its exit
# until the spinner ends, so its SIGKILL shows pending while it is neither exiting nor a zombie.
VICTIM = "import os, time; os.sched_setaffinity(0, {0}); time.sleep(60)"
SPINNER = """
import os, sys, time
os.sched_setaffinity(0, {0})
os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
sys.stdout.write("spinning\\n"); sys.stdout.flush()
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    pass
"""


def test_a_killed_process_that_cannot_run_yet_is_dying_from_its_stat_alone() -> None:
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {1})  # off the spinner's CPU (put back below: later tests need both)
    victim = subprocess.Popen([sys.executable, "-c", VICTIM])
    spinner = None
    stat_fd = None
    try:
        time.sleep(0.3)  # asleep in time.sleep
        stat_fd = _open_stat(victim.pid)
        assert stat_fd is not None
        assert not _dying(stat_fd)
        spinner = subprocess.Popen([sys.executable, "-c", SPINNER, "0.6"], stdout=subprocess.PIPE, text=True)
        assert spinner.stdout is not None
        assert spinner.stdout.readline() == "spinning\n"
        os.kill(victim.pid, signal.SIGKILL)
        time.sleep(0.02)
        state = stat_fields(f"/proc/{victim.pid}/stat")[0]
        assert state not in "ZXx", "the premise: the victim has not run to its exit"
        assert _dying(stat_fd), "a SIGKILL pending is a death on its way"
        spinner.wait(timeout=10)
        victim.wait(timeout=10)
        assert _dying(stat_fd)  # reaped
    finally:
        for process in (spinner, victim):
            if process is not None:
                if process.poll() is None:
                    process.kill()
                    process.wait()
                if process.stdout is not None:
                    process.stdout.close()
        if stat_fd is not None:
            os.close(stat_fd)
        os.sched_setaffinity(0, cpus)
    assert _dying(None)
