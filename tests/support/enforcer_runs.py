"""What the `catanc run` tests share: a compiled table, the enforcer as a process, and its log.

:class:`EnforcerRun` holds one test's enforcer process and reads its JSON-lines log
(:mod:`catanc.runtime.logs.writer`, flushed once a second); each test file subclasses it with how it
starts the enforcer and what it kills at teardown.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from catanc.artifacts.compile import Options, compile_spec
from catanc.artifacts.output import write
from catanc.runtime.logs.writer import read_log
from tests.support.linux import WAIT_S, poll

# The enforcer as `python -m catanc run`, but with Python's own SIGINT handler installed even if
# SIGINT was ignored where the tests run (a CI job in the background): it is what a terminal gives.
ENFORCER_MAIN = (
    "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "sys.argv[0] = 'catanc'; from catanc.cli import main; main()"
)

Event = dict[str, Any]


def of_kind(events: Sequence[Event], kind: str) -> list[Event]:
    return [event for event in events if event["event"] == kind]


def cmdline(pid: int) -> str:
    """Process ``pid``'s command line, words joined by spaces; empty once it is gone."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def process_name(pid: int) -> str:
    """Process ``pid``'s name (``comm``: the planner's is ``catanc-planner``); empty once it is gone."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def compile_table(spec_text: str, folder: Path, cores: int, cpus: tuple[int, ...] | None = None) -> Path:
    """``catanc compile`` the spec into ``folder`` (on ``cpus``: ``--cpus``); the runtime table's path."""
    folder.mkdir(parents=True, exist_ok=True)
    spec = folder / "spec.yaml"
    spec.write_text(spec_text)
    target = compile_spec(spec, cores, out=folder / f"cores-{cores}", options=Options(cpus=cpus))
    write(target.folder, target.files)
    return target.folder / "runtime.json"


def kill_groups(processes: Sequence[subprocess.Popen[bytes]]) -> None:
    """SIGKILL each process still running, with its process group (each has its own session), and reap it."""
    for proc in processes:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=WAIT_S)


@dataclass
class EnforcerRun:
    """One test's enforcer process and its log."""

    folder: Path
    short: Path  # for the socket: a Unix socket's path must stay under 108 bytes
    enforcer: subprocess.Popen[bytes] | None = None

    @property
    def socket(self) -> Path:
        return self.short / "s.sock"

    @property
    def log(self) -> Path:
        return self.folder / "log.jsonl"

    @property
    def pid(self) -> int:
        assert self.enforcer is not None
        return self.enforcer.pid

    def stderr(self) -> str:
        return (self.folder / "enforcer.err").read_text(errors="replace")

    def end_helpers(self, pids: Iterable[int]) -> None:
        """SIGKILL what is left of the enforcer's helpers among ``pids`` (the watchdog and the planner have
        sessions of their own, out of a process group kill's reach), then drop the socket's folder."""
        for pid in pids:
            if "catanc" in cmdline(pid) or "watchdog" in cmdline(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        shutil.rmtree(self.short, ignore_errors=True)

    def events(self) -> list[Event]:
        return read_log(self.log) if self.log.exists() else []

    def registered(self, nodes: Sequence[str]) -> dict[str, tuple[int, int]]:
        """Wait until every node in ``nodes`` registered; ``{node: (pid, tid)}``."""

        def check() -> dict[str, tuple[int, int]] | None:
            found = {e["node"]: (e["pid"], e["tid"]) for e in of_kind(self.events(), "register")}
            if set(nodes) <= set(found):
                return found
            assert self.enforcer is not None
            if self.enforcer.poll() is not None:  # they never will: say why now rather than time out
                pytest.fail(f"the enforcer exited ({self.enforcer.returncode}): {self.stderr()}")
            return None

        return poll(check, f"nodes {sorted(nodes)} to register")

    def wait(self, timeout: float = WAIT_S) -> int:
        assert self.enforcer is not None
        try:
            return self.enforcer.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the enforcer still runs {timeout} s later")
