"""Starting a process pinned (catanc run --launch): the child and its threads on the given CPUs, the caller not."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from catanc.errors import UsageError
from catanc.runtime.processes import Children

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
