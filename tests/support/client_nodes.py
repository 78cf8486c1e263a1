"""Node processes built on the clients as a user would: the C++ example compiled with the system's
compiler against the installed header, and a node script beside a copy of the Python client.

Both programs take ``NAME:MS`` per node (a thread each, burning MS ms of its CPU per run), end
their loops on SIGINT or SIGTERM, and print one line per run at the end, ``NAME SEQ START_NS
END_NS``; they exit 0, or 1 when a node failed or lost its enforcer (stderr says why).
:class:`ClientRun` starts ``catanc run`` for them and reads its log.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import pytest

import catanc.client
from tests.support.enforcer_runs import ENFORCER_MAIN, EnforcerRun, kill_groups, of_kind
from tests.support.linux import WAIT_S, poll

REPO = Path(__file__).resolve().parents[2]
CPP_EXAMPLE = REPO / "examples" / "cpp" / "node.cpp"
CXX_FLAGS = ["-std=c++17", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-pthread"]

PY_NODE = """\
import os, signal, sys, threading, time
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # -I leaves the script's folder out
from catanc_client import ClientError, Node

args = sys.argv[1:]
fallback = None
if args[-2:-1] == ["--fallback-ms"]:
    fallback, args = float(args[-1]), args[:-2]
served = [(arg.split(":")[0], float(arg.split(":")[1])) for arg in args]
nodes = [Node(name, fallback_period_ms=fallback) for name, _ in served]
runs, errors = [], []

def on_signal(signum, frame):
    for node in nodes:
        node.interrupt()

signal.signal(signal.SIGINT, on_signal)
signal.signal(signal.SIGTERM, on_signal)

def serve(node, compute_ms):
    try:
        with node:
            for trigger in node:
                start = time.monotonic_ns()
                used = time.thread_time()
                while time.thread_time() - used < compute_ms / 1000.0:
                    pass
                node.done()
                runs.append("%s %d %d %d" % (node.name, trigger.seq, start, time.monotonic_ns()))
        if node.lost:
            errors.append("%s: %s" % (node.name, node.lost))
    except ClientError as exc:
        errors.append("%s: %s" % (node.name, exc))
    for other in nodes:  # one node ending on its own ends the others
        other.interrupt()

threads = [threading.Thread(target=serve, args=(node, ms)) for node, (_, ms) in zip(nodes, served)]
for thread in threads:
    thread.start()
while any(thread.is_alive() for thread in threads):
    time.sleep(0.05)  # the main thread takes the signals
print("\\n".join(runs))
for error in errors:
    print("node: " + error, file=sys.stderr)
sys.exit(1 if errors else 0)
"""


class Run(NamedTuple):
    node: str
    seq: int
    start_ns: int
    end_ns: int


def parse_runs(stdout: str) -> list[Run]:
    runs = []
    for line in stdout.splitlines():
        if line.strip():
            name, seq, start, end = line.split()
            runs.append(Run(name, int(seq), int(start), int(end)))
    return runs


def rate_hz(starts: Sequence[int]) -> float:
    """Runs per second from their start times (ns): first to last."""
    assert len(starts) >= 10, f"only {len(starts)} runs"
    return (len(starts) - 1) * 1e9 / (starts[-1] - starts[0])


def compiler() -> str:
    """The system's C++ compiler; skips where there is none."""
    for name in ("c++", "g++", "clang++"):
        if found := shutil.which(name):
            return found
    pytest.skip("no C++ compiler (c++, g++ or clang++) on this machine")


def cflags() -> list[str]:
    """What ``catanc client --cflags`` prints, as a user's build would take it."""
    done = subprocess.run(
        [sys.executable, "-m", "catanc", "client", "--cflags"], capture_output=True, text=True, timeout=60, check=True
    )
    return done.stdout.split()


def build_cpp_example(folder: Path) -> Path:
    """The C++ example node, compiled with warnings as errors; its executable."""
    binary = folder / "node"
    argv = [compiler(), *CXX_FLAGS, *cflags(), str(CPP_EXAMPLE), "-o", str(binary)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, f"{' '.join(argv)}\n{done.stderr}"
    return binary


def python_node(folder: Path, python: str | Path) -> list[str]:
    """A node script beside a copy of the standalone client, run isolated (no environment, no
    site-packages): the argv to start it, before its NAME:MS arguments."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(catanc.client.__file__, folder / "catanc_client.py")
    (folder / "node.py").write_text(PY_NODE)
    return [str(python), "-I", "-S", str(folder / "node.py")]


def without_enforcer() -> dict[str, str]:
    return {name: value for name, value in os.environ.items() if name != "CATANC_SOCKET"}


@dataclass
class ClientRun(EnforcerRun):
    """``catanc run`` and the node processes of one test; :meth:`close` kills what is left."""

    nodes: list[subprocess.Popen[str]] = field(default_factory=list)
    helpers: list[int] = field(default_factory=list)

    def start(self, table: Path, duration: float, extra: Sequence[str] = ()) -> None:
        argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--start", "spec", *extra]
        argv += ["--socket", str(self.socket), "--log", str(self.log), "--duration", str(duration)]
        with (self.folder / "enforcer.out").open("wb") as out, (self.folder / "enforcer.err").open("wb") as err:
            self.enforcer = subprocess.Popen(argv, stdout=out, stderr=err, start_new_session=True)
        enforcer = self.enforcer
        poll(lambda: enforcer.poll() is not None or self.socket.exists(), "the enforcer's socket")
        assert enforcer.poll() is None, self.stderr()
        self.helpers = children(enforcer.pid)

    def node(self, argv: Sequence[str]) -> subprocess.Popen[str]:
        """A node process with ``CATANC_SOCKET`` set, as ``catanc run --launch`` would start it."""
        env = {**os.environ, "CATANC_SOCKET": str(self.socket)}
        proc = subprocess.Popen(
            list(argv), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
        )
        self.nodes.append(proc)
        return proc

    def close(self) -> None:
        kill_groups([*self.nodes, *([self.enforcer] if self.enforcer else [])])  # type: ignore[list-item]
        for proc in self.nodes:
            with contextlib.suppress(subprocess.TimeoutExpired, ValueError):
                proc.communicate(timeout=WAIT_S)
        self.end_helpers(self.helpers)  # the watchdog and the planner


def children(pid: int) -> list[int]:
    found: list[int] = []
    with contextlib.suppress(FileNotFoundError, ProcessLookupError):
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(FileNotFoundError, ProcessLookupError):
                found += [int(word) for word in (task / "children").read_text().split()]
    return found


@contextlib.contextmanager
def client_run(folder: Path) -> Iterator[ClientRun]:
    run = ClientRun(folder, Path(tempfile.mkdtemp(prefix="catanc-test-")))
    try:
        yield run
    finally:
        run.close()


def finish(proc: subprocess.Popen[str], timeout: float = WAIT_S) -> tuple[int, list[Run], str]:
    """Wait for a node process: its exit status, its runs, its stderr."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the node process still runs {timeout} s later (it hangs)")
    return proc.returncode, parse_runs(out), err


def stop_after(proc: subprocess.Popen[str], seconds: float) -> tuple[int, list[Run], str]:
    """Let a node process run ``seconds``, SIGTERM it, and :func:`finish` it."""
    time.sleep(seconds)
    proc.send_signal(signal.SIGTERM)
    return finish(proc)


def planned_period_ms(events: Sequence[dict[str, Any]], subchain: str) -> float:
    (start,) = of_kind(events, "start")
    period: float = start["plan"]["subchains"][subchain]["period_ms"]
    assert not of_kind(events, "resolve"), "the plan changed during the run"
    return period
