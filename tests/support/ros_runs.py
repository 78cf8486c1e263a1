"""``catanc run`` with real rclpy node processes (tests/ros/ros_app.py) for the tests in tests/ros.

:class:`RosRun` starts the enforcer as the enforcer tests do (:mod:`tests.support.enforcer_runs`)
and the app's ROS nodes as processes in sessions of their own, each printing what its callbacks
did as JSON lines (read back with :meth:`RosRun.lines`).  Everything started is SIGKILLed at
teardown, the nodes first.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from catanc.runtime.protocol.messages import SOCKET_ENV
from tests.runtime.test_enforcer import children_of
from tests.support.enforcer_runs import ENFORCER_MAIN, EnforcerRun, kill_groups, of_kind
from tests.support.linux import poll

APP = Path(__file__).resolve().parents[1] / "ros" / "ros_app.py"
ROOT = Path(__file__).resolve().parents[2]

# cam -> det, one subchain on one core: cam's timer publishes, det's subscription runs on its message.
# 1 ms each, capped at 50 Hz: the period (20 ms) dwarfs the DDS hop between the processes.
CHAIN_SPEC = """\
catan: 1
app: roschain
nodes:
  cam: {compute_ms: 1}
  det: {compute_ms: 1}
edges:
  - [cam, det]
subchains:
  front: [cam, det]
objective:
  - {chain: [cam, det], weight: 1.0}
constraints:
  - {node: cam, max_rate_hz: 50}
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""
PLANNED_HZ = 50.0
REGISTER_S = 30.0


@dataclass
class RosNode:
    proc: subprocess.Popen[bytes]
    out: Path
    err: Path

    def lines(self) -> list[dict[str, Any]]:
        found = []
        for line in self.out.read_text(errors="replace").splitlines():
            with contextlib.suppress(json.JSONDecodeError):
                found.append(json.loads(line))
        return found

    def of(self, event: str) -> list[dict[str, Any]]:
        return [line for line in self.lines() if line.get("event") == event]

    def stderr(self) -> str:
        return self.err.read_text(errors="replace")

    def wait_for(self, event: str, count: int = 1, timeout: float = 20.0) -> list[dict[str, Any]]:
        def enough() -> list[dict[str, Any]] | None:
            found = self.of(event)
            if len(found) >= count:
                return found
            if self.proc.poll() is not None:
                code = self.proc.returncode
                raise AssertionError(f"the node exited ({code}) before {count} {event}: {self.stderr()}")
            return None

        return poll(enough, f"{count} {event} lines", timeout=timeout)


@dataclass
class RosRun(EnforcerRun):
    nodes: list[RosNode] = field(default_factory=list)
    helpers: list[int] = field(default_factory=list)  # the enforcer's watchdog and planner

    def start(self, table: Path, *options: str, duration: float) -> None:
        argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--socket", str(self.socket)]
        argv += ["--log", str(self.log), "--duration", str(duration), *options]
        with (self.folder / "enforcer.err").open("wb") as err:
            self.enforcer = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        enforcer = self.enforcer
        poll(lambda: enforcer.poll() is not None or self.socket.exists(), "the enforcer's socket", timeout=30.0)
        assert enforcer.poll() is None, self.stderr()
        self.helpers = children_of(self.pid)

    def node(self, role: str, *args: str, dag: str | None = None, socket: bool = True, **env: str) -> RosNode:
        """A ros_app.py process: ``role`` with ``args``; ``dag`` as its ``catan.node`` parameter."""
        index = len(self.nodes)
        out, err = self.folder / f"{role}-{index}.out", self.folder / f"{role}-{index}.err"
        environment = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1", **env}
        if socket:
            environment[SOCKET_ENV] = str(self.socket)
        else:
            environment.pop(SOCKET_ENV, None)
        argv = [sys.executable, str(APP), role, *args]
        if dag is not None:
            argv += ["--ros-args", "-p", f"catan.node:={dag}"]
        with out.open("wb") as stdout, err.open("wb") as stderr:
            proc = subprocess.Popen(argv, stdout=stdout, stderr=stderr, env=environment, start_new_session=True)
        node = RosNode(proc, out, err)
        self.nodes.append(node)
        return node

    def registered(self, nodes: Sequence[str]) -> dict[str, tuple[int, int]]:
        """Wait until every node in ``nodes`` registered (``{node: (pid, tid)}``): up to 30 s, as a process that
        imports rclpy can take 10 s to start on a loaded 2-core VM."""

        def check() -> dict[str, tuple[int, int]] | None:
            found = {e["node"]: (e["pid"], e["tid"]) for e in of_kind(self.events(), "register")}
            return found if set(nodes) <= set(found) else None

        return poll(check, f"nodes {sorted(nodes)} to register", timeout=REGISTER_S)

    def registered_tids(self, nodes: Sequence[str]) -> dict[str, int]:
        return {node: tid for node, (_, tid) in self.registered(nodes).items()}

    def computes(self, node: str) -> list[dict[str, Any]]:
        return [e for e in of_kind(self.events(), "compute") if e["node"] == node]

    def close(self) -> None:
        kill_groups([node.proc for node in self.nodes])
        kill_groups([self.enforcer] if self.enforcer else [])
        self.end_helpers(self.helpers)


@contextlib.contextmanager
def ros_run(folder: Path) -> Iterator[RosRun]:
    run = RosRun(folder, Path(tempfile.mkdtemp(prefix="catanc-ros-")))
    try:
        yield run
    finally:
        run.close()


def exits_within(proc: subprocess.Popen[bytes], seconds: float) -> int | None:
    """``proc``'s exit code if it exits within ``seconds``, else None."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        code = proc.poll()
        if code is not None:
            return code
        time.sleep(0.01)
    return proc.poll()
