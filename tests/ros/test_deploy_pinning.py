"""Every thread of every deployed process, Fast DDS's included, may run only on the process's planned CPUs.

The deployments of tests/ros/test_deploy_params.py (real rclpy processes that never register),
started by ``catanc run --launch`` and by ``launch.sh``: once each node has made its ROS node
(and with it its ``dds.*`` threads), every thread's ``Cpus_allowed_list`` in /proc must lie
within its process's CPUs in runtime.json.  ``catanc run`` also says which processes have
middleware threads on the CPUs it schedules.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.ros.test_deploy_params import PROCESSES, WAIT_S, compiled, deploy, ros_nodes, stop
from tests.support.linux import cpu_set, poll, threads_of

__all__ = ["compiled", "deploy"]  # the fixtures these tests use


def allowed(pid: int, tid: int) -> tuple[str, frozenset[int]]:
    """A thread's name and the CPUs it may run on, from /proc."""
    folder = Path(f"/proc/{pid}/task/{tid}")
    status = (folder / "status").read_text()
    line = next(line for line in status.splitlines() if line.startswith("Cpus_allowed_list:"))
    return (folder / "comm").read_text().strip(), cpu_set(line.split(":", 1)[1].strip())


def planned_cpus(folder: Path) -> dict[str, frozenset[int]]:
    """Each ROS node's process's CPUs, from the runtime table."""
    table = json.loads((folder / "runtime.json").read_text())
    hosts = ros_nodes(table)
    return {
        ros: frozenset(p["cpus"]) for p in table["processes"] for ros in hosts if set(hosts[ros]) <= set(p["nodes"])
    }


@pytest.mark.parametrize("launcher", ["catanc run --launch", "launch.sh", "launch.sh --static"])
def test_every_thread_stays_on_its_process_cpus(compiled: Path, deploy: Any, launcher: str) -> None:
    folder = compiled / "cores-2"
    planned = planned_cpus(folder)
    every_cpu = frozenset().union(*planned.values())
    assert any(cpus != every_cpu for cpus in planned.values())  # the premise: some process may not use them all
    run = deploy(folder, launcher)
    records = poll(run.read_records, f"{PROCESSES} nodes' records from {launcher}", timeout=WAIT_S, step=0.1)
    middleware = 0
    for record in records:
        name = next(iter(record["nodes"]))  # the process of all its ROS nodes
        for tid in threads_of(record["pid"]):
            comm, cpus = allowed(record["pid"], tid)
            middleware += comm.startswith("dds.")
            assert cpus <= planned[name], (name, comm, sorted(cpus), sorted(planned[name]))
    assert middleware >= PROCESSES  # the premise: Fast DDS threads were there to check
    if launcher.startswith("catanc"):
        poll(lambda: run.output().count("middleware thread") == PROCESSES, "a line per process", timeout=WAIT_S)
    stop(run, launcher)
