"""launch.py, run against a recording stand-in of the ROS 2 launch API (tests/support/launch_api.py).

Each test loads an emitted launch.py for some launch arguments (``static``,
``no_rt``) and compares the actions it makes with the runtime table written
beside it: which processes start and how (a ``Node`` for a ROS package, an
``ExecuteProcess`` for a command), their CPUs and policies, the parameters
file, the enforcer and what happens when it exits.  The shell prefix that
holds a process until the enforcer's socket is up is run for real;
tests/ros/test_deploy_launch_py.py runs the resulting command lines with
real rclpy nodes.
"""

from __future__ import annotations

import ast
import json
import shlex
import socket
import subprocess
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from catanc.artifacts.compile import Target, compile_spec
from tests.support.launch_api import Action, Description, describe

ROOT = Path(__file__).parents[2]
SPECS = sorted((ROOT / "specs").glob("*.yaml"))

ROBOT = """catan: 1
app: robot
nodes:
  cam: {compute_ms: 4}
  det: {compute_ms: 30}
  imu: {scheduled: false, rate_hz: 200}
  map: {compute_ms: 80}
  plan: {compute_ms: 60}
  motor: {scheduled: false}
edges: [[cam, det], [det, motor], [imu, det], [det, map], [map, plan]]
subchains:
  front: [cam, det]
  map: [map]
  plan: [plan]
objective:
  - {chain: [cam, det, motor], weight: 1.0}
  - {node: map, weight: 0.01}
  - {node: plan, weight: 0.01}
constraints:
  - {node: map, max_rate_hz: 2}
deploy:
  cam: {ros_node: /sensors/camera, package: cams, executable: cam_node, rate_param: fps}
  det: {ros_node: /perception, package: percept, executable: perception, rate_param: rate}
  map: {ros_node: /mapper, package: mapping, executable: mapper, rate_param: rate}
  plan: {ros_node: /planner, command: "planner-node --fast", rate_param: rate}
  imu: {ros_node: /imu_driver, package: imu, executable: driver, rate_param: rate}
  motor: {command: "motor-driver --port /dev/ttyUSB0"}
"""


# --------------------------------------------------------------------------- what the table says


def shared_processes(table: dict[str, Any]) -> set[str]:
    """Keys of the processes with a node in a shared subchain, from the table's plan."""
    shared_nodes = {node for sub in table["plan"]["subchains"].values() if sub["shared"] for node in sub["nodes"]}
    return {p["key"] for p in table["processes"] if shared_nodes & set(p["nodes"])}


def launched(table: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The table's processes a launch starts (a ROS package or a command), by key."""
    return {p["key"]: p for p in table["processes"] if p["package"] is not None or p["argv"]}


def key_of(action: Action) -> str:
    """The process an action starts: a Node's full name, an ExecuteProcess's ``name``."""
    if action.kind == "Node":
        namespace = action.kwargs["namespace"].rstrip("/")
        return f"{namespace}/{action.kwargs['name']}"
    return str(action.kwargs["name"])


def processes_of(description: Description) -> dict[str, Action]:
    found = {key_of(a): a for a in description.actions if a.kind == "Node" or "prefix" in a.kwargs}
    assert len(found) == len([a for a in description.actions if a.kind == "Node" or "prefix" in a.kwargs])
    return found


def check_started_as_planned(action: Action, process: dict[str, Any], folder: Path) -> None:
    """A Node for a ROS package with the folder's parameters; the command otherwise, with them for a ROS node."""
    params = str(folder / "params.yaml")
    if process["package"] is not None:
        assert action.kind == "Node"
        assert (action.kwargs["package"], action.kwargs["executable"]) == (process["package"], process["executable"])
        assert action.kwargs["parameters"] == [params]
    else:
        assert action.kind == "ExecuteProcess"
        ros = ["--ros-args", "--params-file", params] if process["ros_node"] is not None else []
        assert action.kwargs["cmd"] == [*process["argv"], *ros]


def write(target: Target, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in target.files.items():
        (folder / name).write_text(text)
    return folder / "launch.py"


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Target:
    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_text(ROBOT)
    return compile_spec(path, 2)


@pytest.fixture
def own_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A temporary folder of the test's own for what launch.py makes with ``tempfile``."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


EXAMPLES = ["robot", *[f"{p.stem}-{k}" for p in SPECS for k in (1, 2)]]


@pytest.fixture(scope="module")
def targets(robot: Target, example_targets: Mapping[tuple[str, int], Target]) -> dict[str, Target]:
    """Each of :data:`EXAMPLES`, compiled: the robot, and the example specs (once: tests/artifacts/conftest.py)."""
    found = {"robot": robot, **{f"{stem}-{cores}": target for (stem, cores), target in example_targets.items()}}
    assert sorted(found) == sorted(EXAMPLES)
    return found


# --------------------------------------------------------------------------- the tests


def test_the_robot_has_every_kind_of_process(robot: Target) -> None:
    """The premise: shared and dedicated ROS packages, a ROS node and a plain program started by command."""
    table = json.loads(robot.files["runtime.json"])
    ros = {p["key"] for p in table["processes"] if p["package"]}
    assert shared_processes(table) & ros
    assert ros - shared_processes(table)
    commands = {p["key"]: p["ros_node"] for p in table["processes"] if p["argv"] and not p["package"]}
    assert commands == {"/planner": "/planner", "motor": None}


@pytest.mark.parametrize("example", EXAMPLES)
@pytest.mark.parametrize("no_rt", ["false", "true"])
def test_by_default_the_enforcer_runs_and_every_process_waits_for_its_socket(  # noqa: PLR0917  fixtures
    example: str, no_rt: str, targets: dict[str, Target], tmp_path: Path, own_tmp: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = targets[example]
    launch_file = write(target, tmp_path / "out")
    folder = launch_file.parent
    table = json.loads(target.files["runtime.json"])
    description = describe(launch_file, monkeypatch, no_rt=no_rt)
    assert description.declared == {"static": "false", "no_rt": "false"}
    want = launched(table)
    if not want:  # nothing to start: no enforcer either
        assert description.actions == []
        assert list(own_tmp.iterdir()) == []
        return
    enforcer, on_exit, on_shutdown = description.actions[:3]
    cmd = enforcer.kwargs["cmd"]
    assert cmd[1:3] == ["run", str(folder / "runtime.json")]
    assert cmd[cmd.index("--start") + 1] == "spec"
    assert ("--no-rt" in cmd) == (no_rt == "true")
    socket_path = Path(cmd[cmd.index("--socket") + 1])
    # The enforcer's exit shuts the whole launch down, and the shutdown removes the socket's folder.
    handler = on_exit.kwargs["positional"][0]
    assert handler.kind == "OnProcessExit"
    assert handler.kwargs["target_action"] is enforcer
    assert [action.kind for action in handler.kwargs["on_exit"]] == ["Shutdown"]
    assert socket_path.parent.parent == own_tmp
    assert socket_path.parent.is_dir()
    for action in on_shutdown.kwargs["positional"][0].kwargs["on_shutdown"]:
        action.kwargs["function"](None)
    assert list(own_tmp.iterdir()) == []
    started = processes_of(description)
    assert sorted(started) == sorted(want)
    for key, action in started.items():
        process = want[key]
        check_started_as_planned(action, process, folder)
        assert action.kwargs["additional_env"] == {"CATANC_SOCKET": str(socket_path)}
        prefix = shlex.split(action.kwargs["prefix"])
        assert prefix[:6] == ["taskset", "-c", ",".join(map(str, process["cpus"])), "chrt", "-o", "0"]
        assert prefix[6:8] == ["sh", "-c"]


@pytest.mark.parametrize("example", EXAMPLES)
def test_static_runs_shared_core_processes_under_sched_other_and_no_enforcer(
    example: str, targets: dict[str, Target], tmp_path: Path, own_tmp: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = targets[example]
    launch_file = write(target, tmp_path / "out")
    table = json.loads(target.files["runtime.json"])
    shared = shared_processes(table)
    scheduled = {node for sub in table["plan"]["subchains"].values() for node in sub["nodes"]}
    description = describe(launch_file, monkeypatch, static="true")
    started = processes_of(description)
    assert len(started) == len(description.actions)  # no enforcer, no handlers
    want = launched(table)
    assert sorted(started) == sorted(want)
    fifo_levels: dict[int, list[int]] = {}
    for key, action in started.items():
        process = want[key]
        check_started_as_planned(action, process, launch_file.parent)
        cpus = ",".join(map(str, process["cpus"]))
        if process["key"] in shared:
            assert shlex.split(action.kwargs["prefix"]) == ["taskset", "-c", cpus, "chrt", "-o", "0"]
        else:
            want_prefix = ["taskset", "-c", cpus, "chrt", "-f", str(process["priority"])]
            assert shlex.split(action.kwargs["prefix"]) == want_prefix
            if set(process["nodes"]) & scheduled:
                for cpu in process["cpus"]:
                    fifo_levels.setdefault(cpu, []).append(process["priority"])
        assert "additional_env" not in action.kwargs
    # No two processes of subchains on a shared core at one SCHED_FIFO level.
    shared_cores = {core["core"] for core in table["plan"]["cores"]}
    for cpu in shared_cores:
        levels = fifo_levels.get(cpu, [])
        assert len(levels) == len(set(levels)), (cpu, levels)
    assert list(own_tmp.iterdir()) == []  # no socket folder without the enforcer


def test_static_without_rt_runs_everything_under_sched_other_on_its_cpus(
    robot: Target, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    launch_file = write(robot, tmp_path / "out")
    want = launched(json.loads(robot.files["runtime.json"]))
    started = processes_of(describe(launch_file, monkeypatch, static="true", no_rt="true"))
    assert sorted(started) == sorted(want)
    for key, action in started.items():
        cpus = ",".join(map(str, want[key]["cpus"]))
        assert shlex.split(action.kwargs["prefix"]) == ["taskset", "-c", cpus, "chrt", "-o", "0"]


def test_a_flag_that_is_not_true_or_false_is_an_error(
    robot: Target, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    launch_file = write(robot, tmp_path / "out")
    with pytest.raises(ValueError, match="no_rt:=yes: expected true or false"):
        describe(launch_file, monkeypatch, no_rt="yes")


def test_the_file_is_python_and_imports_only_the_launch_api(targets: dict[str, Target]) -> None:
    for target in targets.values():
        tree = ast.parse(target.files["launch.py"])
        modules = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        modules |= {alias.name for n in ast.walk(tree) if isinstance(n, ast.Import) for alias in n.names}
        assert modules <= {
            "os",
            "shutil",
            "tempfile",
            "pathlib",
            "launch",
            "launch.actions",
            "launch.event_handlers",
            "launch_ros.actions",
        }


def test_the_prefix_holds_a_process_until_the_socket_is_up(
    robot: Target, tmp_path: Path, own_tmp: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The enforced prefix's shell, run for real: it waits for the socket, then execs the process's command."""
    launch_file = write(robot, tmp_path / "out")
    node = next(iter(processes_of(describe(launch_file, monkeypatch)).values()))
    prefix = shlex.split(node.kwargs["prefix"])
    socket_path = tmp_path / "enforcer.sock"
    marker = tmp_path / "ran"
    shell = prefix[6:]  # sh -c SCRIPT NAME: without taskset and chrt, which the real-kernel tests cover
    waiting = subprocess.Popen(
        [*shell, "touch", str(marker)], env={"CATANC_SOCKET": str(socket_path), "PATH": "/usr/bin:/bin"}
    )
    try:
        time.sleep(0.3)
        assert waiting.poll() is None
        assert not marker.exists()
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.bind(str(socket_path))
            assert waiting.wait(timeout=5) == 0
        assert marker.exists()
    finally:
        waiting.kill()
        waiting.wait()


CONTAINER = ROBOT.replace(
    "  cam: {ros_node: /sensors/camera, package: cams, executable: cam_node, rate_param: fps}\n"
    "  det: {ros_node: /perception, package: percept, executable: perception, rate_param: rate}\n"
    "  map: {ros_node: /mapper, package: mapping, executable: mapper, rate_param: rate}\n",
    "  cam: {ros_node: /sensors/camera, package: robot, executable: container, rate_param: fps, process: box}\n"
    "  det: {ros_node: /perception, rate_param: rate, process: box}\n"
    "  map: {ros_node: /mapper, rate_param: rate, process: box}\n",
)


@pytest.mark.usefixtures("own_tmp")
def test_a_process_of_several_ros_nodes_is_one_node_action_without_a_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``process: box`` holds three ROS nodes: one process on the union of their CPUs at the highest level, no
    ``name=`` (rcl would give it to all three), and params.yaml sets each ROS node's own parameters."""
    spec = tmp_path / "robot.yaml"
    spec.write_text(CONTAINER)
    assert CONTAINER != ROBOT  # the premise: the replacement took
    target = compile_spec(spec, 2)
    launch_file = write(target, tmp_path / "out")
    table = json.loads(target.files["runtime.json"])
    (box,) = [p for p in table["processes"] if p["key"] == "box"]
    subchains = table["plan"]["subchains"]
    of = {node: sub for sub in subchains.values() for node in sub["nodes"]}
    assert box["nodes"] == ["cam", "det", "map"]
    assert box["ros_nodes"] == {"/sensors/camera": ["cam"], "/perception": ["det"], "/mapper": ["map"]}
    assert box["cpus"] == sorted({core for node in box["nodes"] for core in of[node]["cores"]})
    levels = {2 if not of[node]["shared"] else 1 for node in box["nodes"]}  # dedicated 2, shared 1 (model sec. 6)
    assert box["priority"] == max(levels)
    for arguments in ({}, {"static": "true"}):
        actions = describe(launch_file, monkeypatch, **arguments).actions
        (action,) = [a for a in actions if a.kind == "Node" and a.kwargs["package"] == "robot"]
        assert action.kwargs["executable"] == "container"
        assert "name" not in action.kwargs
        assert "namespace" not in action.kwargs
    params = yaml.safe_load(target.files["params.yaml"])
    for ros_node, node, param in (("/sensors/camera", "cam", "fps"), ("/perception", "det", "rate")):
        own = params[ros_node]["ros__parameters"]
        assert own["catan"]["node"] == node
        assert own[param] == pytest.approx(1000.0 / of[node]["period_ms"], rel=1e-6)
