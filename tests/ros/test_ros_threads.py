"""The threads of a ROS node process that no node registers, placed by the enforcer on the real kernel.

- catanc.ros's watcher (``catanc-<node>``: it wakes the executor when a trigger comes) follows its
  node's executor thread: its CPUs and level, after a Stage I re-pin too;
- Fast DDS's threads (``dds.*``: they deliver every message between processes) run at SCHED_FIFO
  :data:`~catanc.runtime.enforcer.nodes.MIDDLEWARE_FIFO` on the CPUs the plan gives the process's nodes;
- when the enforcer ends, every one of them is back as it was.

Everything is read from /proc (the kernel's view), never from catanc.  The re-pin is the enforcer's
CPU set shrinking (``taskset -a -p``), as tests/runtime/test_enforcer.py makes it.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from catanc.runtime.enforcer.nodes import MIDDLEWARE_FIFO
from tests.support.enforcer_runs import compile_table
from tests.support.linux import missing_tools, poll
from tests.support.ros_runs import CHAIN_SPEC, RosRun, ros_run

pytestmark = pytest.mark.usefixtures("real_kernel")
WAIT_S = 20.0


@pytest.fixture
def run(tmp_path: Path) -> Iterator[RosRun]:
    with ros_run(tmp_path) as made:
        yield made


def named(pid: int) -> dict[int, str]:
    found = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found[int(task.name)] = (task / "comm").read_text().strip()
        except OSError:
            continue
    return found


def placed(tid: int) -> tuple[int, int, frozenset[int]]:
    """A thread's policy, priority and CPUs, from the kernel."""
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority, frozenset(os.sched_getaffinity(tid))


def test_the_watcher_and_dds_threads_follow_the_plan_and_are_put_back(run: RosRun, tmp_path: Path) -> None:
    if missing_tools("taskset"):
        pytest.skip("needs taskset")
    allowed = sorted(os.sched_getaffinity(0))
    if allowed[:2] != [0, 1]:
        pytest.skip(f"needs CPUs 0 and 1 (allowed: {allowed})")
    table = compile_table(CHAIN_SPEC, tmp_path / "table", cores=2)  # its one subchain on one of them
    run.start(table, duration=12.0)
    cam = run.node("head", dag="cam")
    run.node("sub", dag="det")
    executor = run.registered_tids(["cam", "det"])["cam"]
    pid = cam.proc.pid
    original = (os.SCHED_OTHER, 0, frozenset(allowed))  # as the node process started, unpinned

    def where(cpus: frozenset[int]) -> dict[str, tuple[int, int, frozenset[int]]] | None:
        """The watcher and every dds thread where they should be with the executor on ``cpus``; else None."""
        threads = named(pid)
        watchers = [tid for tid, name in threads.items() if name == "catanc-cam"]
        if len(watchers) != 1 or placed(executor)[2] != cpus:
            return None
        policy, level, watcher_cpus = placed(watchers[0])
        if policy != os.SCHED_FIFO or level < 1 or watcher_cpus != cpus:
            return None
        dds = {name: placed(tid) for tid, name in threads.items() if name.startswith("dds.")}
        if any(value != (os.SCHED_FIFO, MIDDLEWARE_FIFO, cpus) for value in dds.values()):
            return None
        return dds

    def pinned() -> frozenset[int] | None:
        cpus = placed(executor)[2]
        return cpus if len(cpus) == 1 else None

    first = poll(pinned, "the executor pinned", timeout=WAIT_S)
    poll(lambda: where(first), f"the watcher and the dds threads on CPU {set(first)}", timeout=WAIT_S, step=0.1)
    (other,) = {0, 1} - first
    shrink = ["taskset", "-a", "-p", "-c", str(other), str(run.pid)]  # Stage I again, for the one core left
    subprocess.run(shrink, capture_output=True, text=True, timeout=WAIT_S, check=True)
    poll(lambda: where(frozenset({other})), f"the watcher and dds threads on CPU {other}", timeout=WAIT_S, step=0.1)

    assert run.wait(12.0 + WAIT_S) == 0
    after = {name: placed(tid) for tid, name in named(pid).items() if name.startswith("dds.")}
    assert after  # the premise: the node still runs (on its own timer now; its watcher has ended)
    assert after == dict.fromkeys(after, original)  # every one of them put back as it was
