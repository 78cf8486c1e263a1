"""Helpers the real-kernel tests share: probing for SCHED_FIFO, and running a command as ``nobody``.

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
