"""Helpers the real-kernel tests share: probing for SCHED_FIFO, running a command as ``nobody``,
reading what a thread runs at from ``/proc``.

Probes use Python and util-linux directly, never catanc's own checks, so a bug
in those fails a test instead of skipping it.
"""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")

BOTH_CPUS = frozenset({0, 1})
WAIT_S = 10.0


def missing_tools(*tools: str) -> list[str]:
    return [tool for tool in tools if shutil.which(tool) is None]


def require_fifo(priority: int) -> None:
    """Skip unless CPUs 0 and 1 are allowed and a process may use SCHED_FIFO ``priority``."""
    if not os.sched_getaffinity(0) >= BOTH_CPUS:
        pytest.skip(f"needs CPUs 0 and 1 (allowed: {sorted(os.sched_getaffinity(0))})")
    probe = subprocess.run(
        [sys.executable, "-c", f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
    )
    if probe.returncode != 0:
        why = (probe.stderr.strip().splitlines() or ["refused"])[-1]
        pytest.skip(f"SCHED_FIFO {priority} is not permitted here: {why}")


def nobody_ids() -> tuple[int, int]:
    """``nobody``'s uid and gid; skips unless the tests may switch to it."""
    if missing := missing_tools("setpriv", "prlimit"):
        pytest.skip(f"needs {', '.join(missing)}")
    if os.geteuid() != 0:
        pytest.skip("switching to an unprivileged user needs root")
    try:
        user = pwd.getpwnam("nobody")
    except KeyError:
        pytest.skip("no user 'nobody'")
    return user.pw_uid, user.pw_gid


def as_user(uid: int, gid: int, *, rtprio: int, caps: str = "") -> list[str]:
    """A prefix running a command as ``uid``, with RLIMIT_RTPRIO ``rtprio`` and no capabilities but ``caps``."""
    keep = f",+{caps}" if caps else ""
    return [
        "prlimit",
        f"--rtprio={rtprio}:{rtprio}",
        "setpriv",
        f"--reuid={uid}",
        f"--regid={gid}",
        "--clear-groups",
        f"--inh-caps=-all{keep}",
        f"--ambient-caps=-all{keep}",
        f"--bounding-set=-all{keep}",
    ]


def stat_fields(path: str) -> list[str]:
    """A ``stat`` file from field 3 (state) on: the name before it may hold spaces."""
    return Path(path).read_text().rsplit(")", 1)[1].split()


def cpu_set(text: str) -> frozenset[int]:
    """``0-2,5`` -> {0, 1, 2, 5}."""
    cpus: set[int] = set()
    for part in text.split(","):
        low, _, high = part.partition("-")
        cpus.update(range(int(low), int(high or low) + 1))
    return frozenset(cpus)


def poll(check: Callable[[], T | None], what: str, timeout: float = WAIT_S, step: float = 0.005) -> T:
    """``check()``'s first truthy value, tried every ``step`` s; fails after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(step)


@dataclass(frozen=True)
class Sched:
    """A thread's policy (``os.SCHED_*``), real-time priority and CPUs, as ``/proc`` shows them."""

    policy: int
    priority: int
    cpus: frozenset[int]

    def __str__(self) -> str:
        names = {os.SCHED_OTHER: "OTHER", os.SCHED_BATCH: "BATCH", os.SCHED_FIFO: "FIFO", os.SCHED_RR: "RR"}
        return f"{names.get(self.policy, str(self.policy))} {self.priority} on {sorted(self.cpus)}"


def sched_of(pid: int, tid: int) -> Sched | None:
    """Thread ``tid``'s policy (stat field 41), rt_priority (field 40) and CPUs; None once it is gone."""
    folder = f"/proc/{pid}/task/{tid}"
    try:
        fields = stat_fields(f"{folder}/stat")
        status = Path(f"{folder}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    if fields[0] in ("Z", "X"):
        return None
    for line in status.splitlines():
        if line.startswith("Cpus_allowed_list:"):
            return Sched(int(fields[41 - 3]), int(fields[40 - 3]), cpu_set(line.split(":", 1)[1].strip()))
    raise AssertionError(f"no Cpus_allowed_list in {folder}/status")


def threads_of(pid: int) -> list[int]:
    """Process ``pid``'s thread ids (empty once it is gone)."""
    try:
        return sorted(int(entry.name) for entry in Path(f"/proc/{pid}/task").iterdir())
    except FileNotFoundError:
        return []


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        return stat_fields(f"/proc/{pid}/stat")[0] not in ("Z", "X")
    except (FileNotFoundError, ProcessLookupError):
        return False
