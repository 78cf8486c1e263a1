"""The progress helper: a bar on stderr on a terminal, nothing at all otherwise."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SCRIPT = """
import sys
from catanc.cli.progress import progress, tracked
quiet = sys.argv[1] == "quiet"
for item in tracked(["alpha", "beta"], "items", quiet=quiet):
    print(item)
with progress("seconds", total=2.0, unit="s", quiet=quiet) as bar:
    for step in range(3):
        bar.update(step, "measuring")
print("done", bar.shown)
"""


def run(env_terminal: str | None, quiet: bool = False) -> subprocess.CompletedProcess[bytes]:
    env = {k: v for k, v in os.environ.items() if k not in ("TTY_COMPATIBLE", "FORCE_COLOR", "TTY_INTERACTIVE")}
    if env_terminal is not None:
        env["TTY_COMPATIBLE"] = env_terminal
    return subprocess.run(
        [sys.executable, "-c", SCRIPT, "quiet" if quiet else "loud"], env=env, capture_output=True, check=True
    )


def test_not_a_terminal_prints_nothing_extra() -> None:
    finished = run(None)
    assert finished.stdout == b"alpha\nbeta\ndone False\n"
    assert finished.stderr == b""


def test_a_terminal_gets_a_bar_on_stderr_and_stdout_stays_the_same() -> None:
    finished = run("1")
    assert finished.stdout == b"alpha\nbeta\ndone True\n"
    err = finished.stderr.decode()
    assert "items: alpha" in err
    assert "items: beta" in err
    assert "seconds" in err
    assert "1/2" in err  # alpha done while beta runs


@pytest.mark.parametrize("terminal", ["1", "0"])
def test_quiet_or_forced_off_prints_nothing(terminal: str) -> None:
    finished = run(terminal, quiet=terminal == "1")
    assert finished.stdout == b"alpha\nbeta\ndone False\n"
    assert finished.stderr == b""
