"""The plan's parameters reach real rclpy nodes under every launcher.

A spec with three ROS processes (``vision``, one rclpy process hosting two ROS nodes: a
camera at a rate in hertz and a detector whose rate parameter is a period in seconds; a
Mapper-like ``/mapper`` hosting two DAG nodes; an unscheduled IMU on its own clock read as
an integer) is compiled with ``-k 1 -k 2`` from
a folder of its own; each output folder is then deployed from a third folder by
``launch.sh``, ``launch.sh --static`` and ``catanc run --launch``.  Every process is
:mod:`tests.ros.rate_node`: its nodes declare their rate parameters with a code default
of 20 and record what they got.  The oracle is the runtime table's plan (each subchain's
``period_ms``) and the spec's clock, converted to each parameter's unit here, never
params.yaml.  The nodes never register with the enforcer.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from tests.support.linux import missing_tools, poll, require_fifo

NODE_SCRIPT = Path(__file__).with_name("rate_node.py")
CATANC = str(Path(sys.executable).with_name("catanc"))
WAIT_S = 60.0  # rclpy processes start slowly on a loaded machine
TOKEN_ENV = "CATANC_DEPLOY_TEST"

GRAPH = """\
catan: 1
app: {app}
nodes:
  cam: {{compute_ms: 2}}
  det: {{compute_ms: 8}}
  gl: {{compute_ms: 5}}
  gm: {{compute_ms: 20}}
  imu: {{scheduled: false, rate_hz: 100}}
edges: [[cam, det], [imu, gl], [gl, gm]]
subchains: {{front: [cam, det], gl: [gl], gm: [gm]}}
objective:
  - {{chain: [cam, det], weight: 1.0}}
  - {{chain: [imu, gl, gm], weight: 0.1}}
constraints:
  - {{node: gm, max_rate_hz: 5}}
"""
"""The graph of the ROS tests' specs (``str.format`` fields: ``app``, and ``node`` in their deploy sections)."""
SPEC = (
    GRAPH
    + """\
deploy:
  cam: {{ros_node: /sensors/camera, rate_param: fps, process: vision,
        command: "{node} /sensors/camera=fps /detector=period"}}
  det: {{ros_node: /detector, rate_param: period, rate_unit: s, process: vision}}
  gl: {{ros_node: /mapper, rate_param: scan_period, rate_unit: ms, command: "{node} /mapper=scan_period,map_rate"}}
  gm: {{ros_node: /mapper, rate_param: map_rate}}
  imu: {{ros_node: /imu, rate_param: rate, rate_type: int, command: "{node} /imu=rate"}}
"""
)
PROCESSES = 3  # vision (/sensors/camera and /detector), /mapper, /imu
LAUNCHERS = ("launch.sh", "launch.sh --static", "catanc run --launch")


def expected_parameters(folder: Path) -> dict[str, dict[str, Any]]:
    """Each ROS node's parameters as the plan in ``folder/runtime.json`` gives them, converted here."""
    table = json.loads((folder / "runtime.json").read_text())
    spec = table["spec"]
    period_of = {node: sub["period_ms"] for sub in table["plan"]["subchains"].values() for node in sub["nodes"]}
    for name, node in spec["nodes"].items():
        if name not in period_of:
            period_of[name] = 1000.0 / node["rate_hz"]
    found: dict[str, dict[str, Any]] = {}
    for ros_node, nodes in ros_nodes(table).items():
        params = found.setdefault(ros_node, {})
        for node in nodes:
            deploy = spec["deploy"][node]
            period_ms = period_of[node]
            unit = deploy.get("rate_unit", "hz").lower()
            value = {"hz": 1000.0 / period_ms, "s": period_ms / 1000.0, "ms": period_ms}[unit]
            if deploy.get("rate_type") == "int":
                value = math.floor(value + 1e-9)
            params[deploy["rate_param"]] = value
        params["catan.node"] = nodes[0] if len(nodes) == 1 else ""
    return found


def ros_nodes(table: dict[str, Any]) -> dict[str, list[str]]:
    """Every ROS node of the table's processes, with its DAG nodes (from the spec in the table)."""
    found: dict[str, list[str]] = {}
    for name, deploy in table["spec"]["deploy"].items():
        ros_node = deploy.get("ros_node")
        if ros_node is not None:
            found.setdefault(ros_node if ros_node.startswith("/") else "/" + ros_node, []).append(name)
    return found


@dataclass
class Deployment:
    """One launcher's run: its process (leading a session of its own) and the records its nodes write."""

    proc: subprocess.Popen[bytes]
    records: Path
    token: str
    log: Path
    pids: set[int] = field(default_factory=set)

    def read_records(self) -> list[dict[str, Any]] | None:
        found = [json.loads(path.read_text()) for path in sorted(self.records.glob("*.json"))]
        self.pids.update(record["pid"] for record in found)
        return found if len(found) == PROCESSES else None

    def output(self) -> str:
        return self.log.read_text(errors="replace")


def kill_everything(run: Deployment) -> None:
    """SIGKILL the launcher's group and every process that carries this run's token (checked first)."""
    if run.proc.poll() is None:
        os.killpg(run.proc.pid, signal.SIGKILL)
    candidates = set(run.pids)
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            candidates.add(int(entry.name))
    for pid in candidates:
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
        if run.token.encode() in environ:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                continue
    run.proc.wait(timeout=WAIT_S)


@pytest.fixture
def deploy(tmp_path: Path) -> Iterator[Any]:
    """``deploy(folder, launcher)``: starts ``launcher`` on the output folder from a folder of its own."""
    runs: list[Deployment] = []

    def start(folder: Path, launcher: str) -> Deployment:
        index = len(runs)
        records = tmp_path / f"records-{index}"
        records.mkdir()
        elsewhere = tmp_path / f"cwd-{index}"
        elsewhere.mkdir()
        if launcher.startswith("launch.sh"):
            argv = ["bash", str(folder / "launch.sh"), *launcher.split()[1:]]
        else:
            socket = tmp_path / f"enforcer-{index}.sock"
            log = tmp_path / f"run-{index}.jsonl"
            argv = [CATANC, "run", str(folder / "runtime.json"), "--launch", "--start", "spec", "--quiet"]
            argv += ["--socket", str(socket), "--log", str(log)]
        mark = f"{tmp_path}/{index}"
        env = {**os.environ, "RATE_NODE_RECORDS": str(records), "CATANC": CATANC, TOKEN_ENV: mark}
        output = tmp_path / f"output-{index}.txt"
        with output.open("wb") as out:
            proc = subprocess.Popen(
                argv, cwd=elsewhere, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=out, start_new_session=True
            )
        run = Deployment(proc, records, f"{TOKEN_ENV}={mark}", output)
        runs.append(run)
        return run

    yield start
    for run in runs:
        kill_everything(run)


@pytest.fixture(scope="module")
def compiled(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The spec compiled with ``-k 1 -k 2`` by ``catanc compile``, run in a folder other than the spec's."""
    if missing := missing_tools("bash", "taskset", "chrt"):
        pytest.skip(f"needs {', '.join(missing)}")
    require_fifo(3)
    specs = tmp_path_factory.mktemp("specs")
    spec = specs / "rosdeploy.yaml"
    spec.write_text(SPEC.format(app="rosdeploy", node=f"{sys.executable} {NODE_SCRIPT}"))
    elsewhere = tmp_path_factory.mktemp("compiled-here")
    subprocess.run([CATANC, "compile", str(spec), "-k", "1", "-k", "2"], cwd=elsewhere, check=True, timeout=300)
    return elsewhere / "out" / "rosdeploy"


def stop(run: Deployment, launcher: str) -> None:
    """Stop a launcher as a user would (Ctrl-C for catanc run, SIGTERM for launch.sh) and wait for it."""
    run.proc.send_signal(signal.SIGINT if launcher.startswith("catanc") else signal.SIGTERM)
    try:
        run.proc.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{launcher} did not stop:\n{run.output()}")


def received(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {name: params for record in records for name, params in record["nodes"].items()}


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("launcher", LAUNCHERS)
def test_every_node_reads_the_planned_rate(compiled: Path, deploy: Any, launcher: str, cores: int) -> None:
    folder = compiled / f"cores-{cores}"
    want = expected_parameters(folder)
    assert all(value != 20.0 for params in want.values() for value in params.values())  # the premise
    run = deploy(folder, launcher)
    records = poll(run.read_records, f"{PROCESSES} nodes' records from {launcher}", timeout=WAIT_S, step=0.1)
    got = received(records)
    assert set(got) == set(want), run.output()
    for name, params in want.items():
        assert got[name].pop("catan.node") == params.pop("catan.node"), name
        assert got[name] == pytest.approx(params, rel=1e-6), name
    for record in records:
        assert record["argv"][-3:] == ["--ros-args", "--params-file", str(folder / "params.yaml")]
    stop(run, launcher)


def test_a_copied_folder_gives_its_own_parameters(compiled: Path, deploy: Any, tmp_path: Path) -> None:
    """launch.sh finds params.yaml beside itself wherever the folder is: a copy with another rate gives that rate."""
    copy = tmp_path / "copied" / "cores-2"
    shutil.copytree(compiled / "cores-2", copy)
    params = copy / "params.yaml"
    params.write_text(params.read_text().replace("    fps: ", "    fps: 7.0 # was "))
    run = deploy(copy, "launch.sh --static")
    records = poll(run.read_records, "the copy's records", timeout=WAIT_S, step=0.1)
    assert received(records)["/sensors/camera"]["fps"] == 7.0
    for record in records:
        assert record["argv"][-1] == str(params)
    stop(run, "launch.sh --static")
