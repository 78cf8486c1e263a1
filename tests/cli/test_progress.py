"""The progress helper: a bar on stderr on a terminal, nothing at all otherwise."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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


ROOT = Path(__file__).parents[2]
FACE = str(ROOT / "specs" / "face_tracking.yaml")


def catanc(args: list[str], env_terminal: str | None, cwd: Path) -> subprocess.CompletedProcess[bytes]:
    env = {k: v for k, v in os.environ.items() if k not in ("TTY_COMPATIBLE", "FORCE_COLOR", "TTY_INTERACTIVE")}
    if env_terminal is not None:
        env["TTY_COMPATIBLE"] = env_terminal
    finished = subprocess.run(
        [sys.executable, "-m", "catanc", *args], env=env, cwd=cwd, capture_output=True, check=False
    )
    assert finished.returncode == 0, finished.stderr.decode()
    return finished


@pytest.mark.parametrize(
    ("args", "bar"),
    [
        (
            ["simulate", FACE, "-k", "1", "--duration", "2", "--policy", "catan", "--policy", "baseline", "--json"],
            "simulating: catan",
        ),
        (["compile", FACE, "-k", "1", "-k", "2", "--dry-run"], "planning: "),
    ],
    ids=["simulate-json", "compile"],
)
def test_commands_output_is_the_same_bytes_with_or_without_a_bar(args: list[str], bar: str, tmp_path: Path) -> None:
    quiet = catanc([*args, "--quiet"], "1", tmp_path)  # a terminal, but told to be quiet
    piped = catanc(args, None, tmp_path)  # not a terminal
    shown = catanc(args, "1", tmp_path)  # rich told stdout and stderr are terminals
    # Told quiet or not a terminal: no bar; what stderr keeps is the command's own warnings, the same either way
    # (face tracking on 1 core warns that none of the camera's offered rates fits).
    assert bar not in quiet.stderr.decode()
    assert quiet.stderr == piped.stderr
    assert bar in shown.stderr.decode()
    assert piped.stdout == quiet.stdout
    assert shown.stdout == quiet.stdout  # the bar never reaches stdout
