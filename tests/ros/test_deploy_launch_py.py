"""launch.py's command lines, run with real rclpy nodes.

``launch_ros`` is not installable here: an emitted launch.py is loaded against the recording
stand-in of tests/support/launch_api.py, and each process action's command line (what launch
and launch_ros would run: the prefix, the executable, ``name=`` as ``-r __node:=``, the
parameters file) is run for real, the package's executable being :mod:`tests.ros.rate_node`
under a name of its code's own.  Every node must come up under its planned name with the plan's
rate (the oracle of tests/ros/test_deploy_params.py: the runtime table's periods, converted here).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from tests.ros.rate_node import RECORDS_ENV
from tests.ros.test_deploy_params import GRAPH, NODE_SCRIPT, WAIT_S, expected_parameters, received
from tests.support.launch_api import command_line, describe, environment_of
from tests.support.linux import missing_tools, poll, require_fifo

SPEC = (
    GRAPH
    + """\
deploy:
  cam: {{ros_node: /sensors/camera, rate_param: fps, package: cams, executable: vision, process: vision}}
  det: {{ros_node: /detector, rate_param: period, rate_unit: s, process: vision}}
  gl: {{ros_node: /mapper, rate_param: scan_period, rate_unit: ms, command: "{node} /mapper=scan_period,map_rate"}}
  gm: {{ros_node: /mapper, rate_param: map_rate}}
  imu: {{ros_node: /imu, rate_param: rate, rate_type: int, package: imus, executable: imu_node}}
"""
)
PROCESSES = 3
# What each package's executable is here: rate_node making nodes.  The IMU's code names its node otherwise, and
# name= renames it; the vision process (a container of two nodes) names its own nodes, and nothing renames them.
EXECUTABLES = {
    ("cams", "vision"): ["/sensors/camera=fps", "/detector=period"],
    ("imus", "imu_node"): ["/imu_node=rate"],
}


def executable(package: str, name: str) -> Sequence[str]:
    return [sys.executable, str(NODE_SCRIPT), *EXECUTABLES[package, name]]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if missing := missing_tools("taskset", "chrt"):
        pytest.skip(f"needs {', '.join(missing)}")
    require_fifo(3)
    spec = tmp_path_factory.mktemp("specs") / "rospy_launch.yaml"
    spec.write_text(SPEC.format(app="rospy_launch", node=f"{sys.executable} {NODE_SCRIPT}"))
    out = tmp_path_factory.mktemp("compiled")
    catanc = str(Path(sys.executable).with_name("catanc"))
    subprocess.run([catanc, "compile", str(spec), "-k", "2", "--out", str(out)], check=True, timeout=300)
    return out


@pytest.fixture
def started(tmp_path: Path) -> Iterator[list[subprocess.Popen[bytes]]]:
    """The processes a test starts, each leading a session of its own; SIGKILLed at teardown."""
    processes: list[subprocess.Popen[bytes]] = []
    yield processes
    for process in processes:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=WAIT_S)


@pytest.mark.parametrize("arguments", [{"static": "true"}, {"static": "true", "no_rt": "true"}, {}])
def test_every_process_of_launch_py_reads_the_planned_rate_under_its_name(
    folder: Path,
    started: list[subprocess.Popen[bytes]],
    arguments: dict[str, str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the socket folder of the enforced launch
    description = describe(folder / "launch.py", monkeypatch, **arguments)
    actions = [action for action in description.actions if "prefix" in action.kwargs]
    assert len(actions) == PROCESSES
    records = tmp_path / "records"
    records.mkdir()
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as enforcer:
        if not arguments:  # stands for the enforcer's socket: the prefix holds each process until it is up
            socket_path = environment_of(actions[0])["CATANC_SOCKET"]
            enforcer.bind(socket_path)
        for action in actions:
            env = {**os.environ, **environment_of(action), RECORDS_ENV: str(records)}
            started.append(
                subprocess.Popen(command_line(action, executable), env=env, cwd=tmp_path, start_new_session=True)
            )

        def all_records() -> list[Path] | None:
            found = list(records.glob("*.json"))
            return found if len(found) == PROCESSES else None

        paths = poll(all_records, "every process's record", timeout=WAIT_S, step=0.1)
        got = received([json.loads(path.read_text()) for path in paths])
    want = expected_parameters(folder)
    assert set(got) == set(want)
    for name, params in want.items():
        assert got[name].pop("catan.node") == params.pop("catan.node"), name
        assert got[name] == pytest.approx(params, rel=1e-6), name
    for process in started:
        os.killpg(process.pid, signal.SIGTERM)
