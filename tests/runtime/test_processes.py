"""Starting a process pinned (catanc run --launch): the child and its threads on the given CPUs, the caller not."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import pytest

from catanc.errors import UsageError
from catanc.model.load import load_spec
from catanc.runtime.enforcer.processes import Children, start_demo
from tests.support.linux import poll

THREADED = (
    "import json, os, sys, threading\n"
    "seen = {}\n"
    "t = threading.Thread(target=lambda: seen.update(thread=sorted(os.sched_getaffinity(0))))\n"
    "t.start(); t.join()\n"
    "open(sys.argv[1], 'w').write(json.dumps({'main': sorted(os.sched_getaffinity(0)), **seen}))\n"
)


def test_a_pinned_child_and_its_threads_run_only_on_its_cpus(tmp_path: Path) -> None:
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        pytest.skip(f"needs two CPUs (allowed: {allowed})")
    seen_path = tmp_path / "seen.json"
    children = Children()
    try:
        children.start("probe", [sys.executable, "-c", THREADED, str(seen_path)], None, [allowed[-1]])
        assert children.processes[0][1].wait(timeout=30) == 0
        assert json.loads(seen_path.read_text()) == {"main": [allowed[-1]], "thread": [allowed[-1]]}
        assert sorted(os.sched_getaffinity(0)) == allowed  # the calling thread is back where it was
    finally:
        children.stop()


def test_cpus_that_cannot_be_had_are_a_usage_error_and_stop_what_started() -> None:
    children = Children()
    children.start("first", [sys.executable, "-c", "import time; time.sleep(30)"], None)
    first = children.processes[0][1]
    with pytest.raises(UsageError, match=r"cannot pin second to CPUs 4095 \(this thread may use "):
        children.start("second", ["true"], None, [4095])
    assert first.wait(timeout=10) is not None
    assert children.processes == []


def test_stop_names_what_it_killed_and_what_failed_and_nothing_that_stopped_cleanly(tmp_path: Path) -> None:
    """SIGTERM to three real processes: one ends with 0, one with 3, one ignores it (SIGKILL 2 s later)."""
    program = "import pathlib, signal, sys, time\n{}\npathlib.Path(sys.argv[1]).touch()\ntime.sleep(60)\n"
    kinds = {
        "clean": "signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))",
        "failing": "signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))",
        "stubborn": "signal.signal(signal.SIGTERM, signal.SIG_IGN)",
    }
    children = Children()
    started = {}
    for name, handler in kinds.items():
        children.start(name, [sys.executable, "-c", program.format(handler), str(tmp_path / name)], None)
        started[name] = children.processes[-1][1]
    poll(lambda: all((tmp_path / name).exists() for name in kinds) or None, "the handlers", timeout=30.0)
    problems = children.stop()
    assert started["clean"].returncode == 0
    assert started["failing"].returncode == 3
    assert started["stubborn"].returncode == -signal.SIGKILL
    assert problems == [
        f"failing (pid {started['failing'].pid}) exited with status 3 on SIGTERM",
        f"stubborn (pid {started['stubborn'].pid}) still ran 2 s after SIGTERM: SIGKILL",
    ]


class RecordingChildren:
    """Stands in for :class:`Children`: what start_demo would start, by label and argv."""

    def __init__(self) -> None:
        self.started: dict[str, list[str]] = {}

    def start(self, label: str, argv: list[str], socket_path: str) -> None:  # noqa: ARG002 - Children's signature
        self.started[label] = argv


def test_demo_workers_serialise_the_nodes_a_process_makes_one_executor() -> None:
    # nav2d's Operator (LM, LP) and Navigator (GP, NC) run in one `ros2 run` process each, with no callback
    # groups: the plan takes each as one executor (docs/explanation/executor-planning.md, "Processes"), though
    # only the Mapper is written under `executors:`. The demo must run them as planned: one worker each,
    # taking turns. By hand from specs/nav2d.yaml's deploy section.
    spec = load_spec(Path(__file__).parents[2] / "specs" / "nav2d.yaml")
    children = RecordingChildren()
    start_demo(children, spec, "/tmp/unused.sock")  # type: ignore[arg-type]
    assert sorted(children.started) == sorted(["GL, GM", "GP, NC", "LM, LP", "scan"])
    for label, argv in children.started.items():
        if ", " in label:
            assert label.replace(", ", ",") in " ".join(argv)  # one --executor for the group
