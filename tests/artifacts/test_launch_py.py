"""launch.py, run against stand-ins of the ROS 2 launch API (no ROS here).

Stand-in modules for ``launch`` and ``launch_ros`` record every action the
file's ``generate_launch_description`` makes, with its condition; each test
then asks which actions run with ``static:=false`` (the default) and
``static:=true`` and compares them with the runtime table written beside it:
the processes, their CPUs and SCHED_FIFO levels, and which subchains are
shared (a shared core's process runs under SCHED_OTHER without the enforcer).
The shell prefix that holds a node until the enforcer's socket is up is run
for real.
"""

from __future__ import annotations

import ast
import json
import shlex
import socket
import subprocess
import sys
import time
import types
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from catanc.artifacts.compile import Target, compile_spec

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
  plan: {ros_node: /planner, package: planning, executable: planner, rate_param: rate}
  imu: {ros_node: /imu_driver, package: imu, executable: driver, rate_param: rate}
"""


# --------------------------------------------------------------------------- stand-ins of the launch API


@dataclass
class Action:
    kind: str
    kwargs: dict[str, Any]
    condition: Condition | None = None


@dataclass
class Condition:
    argument: str
    when: bool  # IfCondition: holds when the argument is true; UnlessCondition: when it is false

    def holds(self, arguments: dict[str, bool]) -> bool:
        return arguments[self.argument] == self.when


@dataclass
class Recorded:
    actions: list[Action] = field(default_factory=list)
    declared: dict[str, str] = field(default_factory=dict)

    def running(self, **arguments: bool) -> list[Action]:
        return [a for a in self.actions if a.condition is None or a.condition.holds(arguments)]


def stand_in_modules() -> dict[str, types.ModuleType]:
    modules = {
        name: types.ModuleType(name)
        for name in (
            "launch",
            "launch.actions",
            "launch.conditions",
            "launch.substitutions",
            "launch_ros",
            "launch_ros.actions",
        )
    }

    def action(kind: str) -> Any:
        def make(*args: Any, **kwargs: Any) -> Any:
            if kind == "DeclareLaunchArgument":
                return ("declare", args[0], kwargs.get("default_value"))
            return Action(kind, kwargs, kwargs.pop("condition", None))

        return make

    modules["launch"].LaunchDescription = lambda actions: actions  # type: ignore[attr-defined]
    modules["launch.actions"].DeclareLaunchArgument = action("DeclareLaunchArgument")  # type: ignore[attr-defined]
    modules["launch.actions"].ExecuteProcess = action("ExecuteProcess")  # type: ignore[attr-defined]
    modules["launch_ros.actions"].Node = action("Node")  # type: ignore[attr-defined]
    modules["launch.substitutions"].LaunchConfiguration = lambda name: name  # type: ignore[attr-defined]
    modules["launch.conditions"].IfCondition = lambda name: Condition(name, True)  # type: ignore[attr-defined]
    modules["launch.conditions"].UnlessCondition = lambda name: Condition(name, False)  # type: ignore[attr-defined]
    return modules


def run_launch_file(folder: Path, monkeypatch: pytest.MonkeyPatch) -> Recorded:
    """``folder/launch.py``'s description, made with the stand-ins."""
    for name, module in stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    namespace: dict[str, Any] = {"__file__": str(folder / "launch.py"), "__name__": "launch_file"}
    exec(compile((folder / "launch.py").read_text(), str(folder / "launch.py"), "exec"), namespace)
    recorded = Recorded()
    for item in namespace["generate_launch_description"]():
        if isinstance(item, tuple):
            recorded.declared[item[1]] = item[2]
        else:
            recorded.actions.append(item)
    return recorded


def write(target: Target, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in target.files.items():
        (folder / name).write_text(text)
    return folder


# --------------------------------------------------------------------------- what the table says


def shared_processes(table: dict[str, Any]) -> set[str]:
    """Keys of the processes with a node in a shared subchain, from the table's plan."""
    shared_nodes = {node for sub in table["plan"]["subchains"].values() if sub["shared"] for node in sub["nodes"]}
    return {p["key"] for p in table["processes"] if shared_nodes & set(p["nodes"])}


def node_name(action: Action) -> str:
    namespace = action.kwargs.get("namespace", "")
    return f"{namespace}/{action.kwargs['name']}"


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Target:
    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_text(ROBOT)
    return compile_spec(path, 2)


@pytest.fixture(scope="module")
def examples() -> Iterator[Target]:
    return iter([compile_spec(path, cores) for path in SPECS for cores in (1, 2)])


# --------------------------------------------------------------------------- the tests


def test_the_robot_has_shared_and_dedicated_ros_processes(robot: Target) -> None:
    """The premise: the static tests below see both policies."""
    table = json.loads(robot.files["runtime.json"])
    ros = {p["key"] for p in table["processes"] if p["package"]}
    assert shared_processes(table) & ros
    assert ros - shared_processes(table)


@pytest.mark.parametrize("example", ["robot", *[f"{p.stem}-{k}" for p in SPECS for k in (1, 2)]])
def test_by_default_the_enforcer_runs_and_every_node_waits_for_its_socket(
    example: str, robot: Target, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = robot if example == "robot" else compile_spec(ROOT / "specs" / f"{example[:-2]}.yaml", int(example[-1]))
    folder = write(target, tmp_path / "out")
    recorded = run_launch_file(folder, monkeypatch)
    table = json.loads(target.files["runtime.json"])
    ros = [p for p in table["processes"] if p["package"] is not None]
    if not ros:  # nothing for ROS to launch (launch.sh starts the commands, with the enforcer)
        assert recorded.actions == []
        return
    assert recorded.declared == {"static": "false"}
    running = recorded.running(static=False)
    enforcers = [a for a in running if a.kind == "ExecuteProcess"]
    assert len(enforcers) == 1
    cmd = enforcers[0].kwargs["cmd"]
    assert cmd[1:3] == ["run", str(folder / "runtime.json")]
    socket_path = cmd[cmd.index("--socket") + 1]
    assert cmd[cmd.index("--start") + 1] == "spec"
    nodes = [a for a in running if a.kind == "Node"]
    assert sorted(map(node_name, nodes)) == sorted(p["ros_node"] for p in ros)
    by_name = {p["ros_node"]: p for p in ros}
    for node in nodes:
        process = by_name[node_name(node)]
        assert node.kwargs["package"] == process["package"]
        assert node.kwargs["executable"] == process["executable"]
        assert node.kwargs["parameters"] == [str(folder / "params.yaml")]
        assert node.kwargs["additional_env"] == {"CATANC_SOCKET": socket_path}
        prefix = shlex.split(node.kwargs["prefix"])
        assert prefix[:6] == ["taskset", "-c", ",".join(map(str, process["cpus"])), "chrt", "-o", "0"]
        assert prefix[6:8] == ["sh", "-c"]


@pytest.mark.parametrize("example", ["robot", *[f"{p.stem}-{k}" for p in SPECS for k in (1, 2)]])
def test_static_runs_shared_core_nodes_under_sched_other_and_no_enforcer(
    example: str, robot: Target, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = robot if example == "robot" else compile_spec(ROOT / "specs" / f"{example[:-2]}.yaml", int(example[-1]))
    folder = write(target, tmp_path / "out")
    table = json.loads(target.files["runtime.json"])
    shared = shared_processes(table)
    running = run_launch_file(folder, monkeypatch).running(static=True)
    assert [a for a in running if a.kind != "Node"] == []
    by_name = {p["ros_node"]: p for p in table["processes"] if p["package"] is not None}
    assert sorted(map(node_name, running)) == sorted(by_name)
    fifo_levels: dict[int, list[int]] = {}
    for node in running:
        process = by_name[node_name(node)]
        cpus = ",".join(map(str, process["cpus"]))
        if process["key"] in shared:
            assert shlex.split(node.kwargs["prefix"]) == ["taskset", "-c", cpus, "chrt", "-o", "0"]
        else:
            want = ["taskset", "-c", cpus, "chrt", "-f", str(process["priority"])]
            assert shlex.split(node.kwargs["prefix"]) == want
            for cpu in process["cpus"]:
                fifo_levels.setdefault(cpu, []).append(process["priority"])
        assert "additional_env" not in node.kwargs
    # No two processes on a shared core at one SCHED_FIFO level.
    shared_cores = {core["core"] for core in table["plan"]["cores"]}
    for cpu in shared_cores:
        levels = fifo_levels.get(cpu, [])
        assert len(levels) == len(set(levels)), (cpu, levels)


def test_the_file_is_python_and_imports_only_the_launch_api(examples: Iterator[Target]) -> None:
    for target in examples:
        tree = ast.parse(target.files["launch.py"])
        modules = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        modules |= {alias.name for n in ast.walk(tree) if isinstance(n, ast.Import) for alias in n.names}
        assert modules <= {
            "os",
            "tempfile",
            "pathlib",
            "launch",
            "launch.actions",
            "launch.conditions",
            "launch.substitutions",
            "launch_ros.actions",
        }


def test_the_prefix_holds_a_node_until_the_socket_is_up(
    robot: Target, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The enforced prefix's shell, run for real: it waits for the socket, then execs the node's command."""
    folder = write(robot, tmp_path / "out")
    node = next(a for a in run_launch_file(folder, monkeypatch).running(static=False) if a.kind == "Node")
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
