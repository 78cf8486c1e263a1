"""The nav2d example (examples/ros/nav2d) run each of the three ways its README gives, for real.

Real rclpy processes on real topics, from a scratch copy of the example's folder: the robot
(odometry and the base) and the app as ``bash plain.sh``, ``catanc run --launch`` and ``bash
out/cores-1/launch.sh`` (the last two on the real kernel, SCHED_FIFO).  The chain must flow end to
end: the base receives commands whose origin is the stamp of a scan the scan shim really sent.
Under catanc the enforcer must also have scheduled the nodes (each registered, the local
subchain's runs in its log), not merely watched them run on their own timers.  Ctrl-C (a real
SIGINT to the launcher's and the robot's process groups) must end every process cleanly within 2 s.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
import yaml

from benchmarks.ros_nav2d import EXAMPLE, all_records, read_records, running
from catanc.model.load import load_spec
from catanc.runtime.logs.writer import read_log
from tests.support.linux import require_fifo

REPO = Path(__file__).resolve().parents[2]
RUN_AFTER_READY_S = 3.0
LAUNCHER_STATUS = {"plain": 0, "catanc": 0, "launch.sh": 130}  # launch.sh exits 128 + SIGINT
NODE_SCRIPTS = ("scan_shim.py", "nav_operator.py", "nav_mapper.py", "nav_navigator.py")
PROCESSES = ("scan_shim", "Operator", "Mapper", "Navigator", "robot")
EXIT_BOUND_S = 2.0  # issue 46: Ctrl-C ends every process, exit 0, within 2 s


def test_the_example_spec_is_the_papers_nav2d_but_for_its_deploy_section_hops_and_dispatch() -> None:
    example = load_spec(EXAMPLE / "nav2d.yaml").model_dump(exclude={"deploy", "hops_ms", "dispatch_ms"})
    paper = load_spec(REPO / "specs" / "nav2d.yaml").model_dump(exclude={"deploy", "hops_ms", "dispatch_ms"})
    assert example == paper


def test_the_baseline_parameters_are_the_specs_baseline_rates() -> None:
    spec = load_spec(EXAMPLE / "nav2d.yaml")
    params = yaml.safe_load((EXAMPLE / "baseline.params.yaml").read_text())
    rates = {}
    for node, deploy in spec.deploy.items():
        assert deploy.ros_node is not None
        assert deploy.rate_param is not None
        value = params[deploy.ros_node]["ros__parameters"]
        for part in deploy.rate_param.split("."):
            value = value[part]
        rates[node] = {"hz": value, "s": 1 / value, "ms": 1000 / value}[deploy.rate_unit.lower()]
    assert rates == pytest.approx(spec.baseline.rates_hz)


def test_catanc_takes_one_line_per_callback() -> None:
    """Every line of the nodes that uses catanc.ros makes one callback of one scheduled node, each node once."""
    spec = load_spec(EXAMPLE / "nav2d.yaml")
    scheduled = sorted(name for name, node in spec.nodes.items() if node.scheduled)
    named: list[str] = []
    for script in NODE_SCRIPTS:
        lines = [line.strip() for line in (EXAMPLE / script).read_text().splitlines() if "catanc_ros" in line]
        imports = [line for line in lines if line == "from catanc import ros as catanc_ros"]
        calls = [line for line in lines if line not in imports]
        assert len(imports) == 1, script
        for line in calls:
            assert line.count("catanc_ros.") == 1, line
            assert re.search(r"catanc_ros\.(create_timer|reported)\(self, ", line), line
            named += re.findall(r'name="(\w+)"', line)
    assert sorted(named) == scheduled


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["plain", "catanc", "launch.sh"])
def test_commands_reach_the_base_with_the_stamp_of_a_scan_that_was_sent(mode: str, tmp_path: Path) -> None:
    if mode != "plain":
        require_fifo(4)
    with running(mode, 1, tmp_path) as app:
        app.wait_ready()
        time.sleep(RUN_AFTER_READY_S)
        ctrl_c_ns = time.time_ns()
        stopped = app.stop()
    output = app.output_text()
    assert stopped["launcher"] == LAUNCHER_STATUS[mode], output
    assert stopped["robot"] == 0, output
    # Ctrl-C: every process shut down cleanly within 2 s (its own last words), none was killed or failed
    # (catanc run and launch.sh say so: "SIGKILL", "exited with status"), and none printed a traceback.
    for process in PROCESSES:
        exit_file = app.records / f"{process}.exit"
        assert exit_file.exists(), f"{process} did not shut down cleanly\n{output}"
        took_s = (json.loads(exit_file.read_text())["exit_ns"] - ctrl_c_ns) / 1e9
        assert took_s <= EXIT_BOUND_S, f"{process} took {took_s:.2f} s to exit\n{output}"
    for sign in ("Traceback", "Exception ignored", "SIGKILL", "exited with status"):
        assert sign not in output, output
    sent = {row["origin_ns"] for row in read_records(app.records, "scan_shim")}
    commands = app.commands()
    assert len(commands) >= 5
    for command in commands:
        assert command["origin_ns"] in sent
        assert command["origin_ns"] < command["start_ns"]
    ran = {row["node"] for row in all_records(app.records)}
    assert ran >= {"scan", "LM", "LP", "GL", "GM", "GP", "NC", "base"}
    if mode != "plain":
        events = read_log(app.log)
        registered = {event["node"] for event in events if event.get("event") == "register"}
        assert registered >= {"scan", "LM", "LP", "GL", "GM", "GP", "NC"}, app.output_text()
        assert any(event.get("event") == "run" and event.get("subchain") == "local" for event in events)
