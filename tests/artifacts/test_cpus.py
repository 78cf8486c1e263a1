"""``catanc compile --cpus``: the plan's cores on other CPUs, in every file.

The oracle is the same spec compiled without ``--cpus``: each file must be
that one with every CPU number ``c`` replaced by the ``c``-th CPU given (and
the command in the headers), worked out here from the files' own text.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from catanc.artifacts.compile import Options, Target, compile_spec
from catanc.artifacts.runtime_table import load_table
from catanc.cli import app
from catanc.errors import ExitCode, SpecError

runner = CliRunner()

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
  cam: {ros_node: /camera, package: cams, executable: cam_node, rate_param: fps, command: "cam_node",
        callback_group: "/camera@Timer({period_ns})"}
  det: {ros_node: /perception, package: percept, executable: perception, rate_param: rate, command: "perception"}
  map: {ros_node: /mapper, package: mapping, executable: mapper, rate_param: rate, command: "mapper",
        callback_group: "/mapper@Timer({period_ns})"}
  plan: {ros_node: /planner, package: planning, executable: planner, rate_param: rate, command: "planner"}
  imu: {ros_node: /imu_driver, package: imu, executable: driver, rate_param: rate, command: "imu_driver",
        callback_group: "/imu_driver@Timer({period_ns})"}
"""
CPUS = (5, 7)  # plan core 0 -> CPU 5, core 1 -> CPU 7


@pytest.fixture(scope="module")
def spec_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_text(ROBOT)
    return path


@pytest.fixture(scope="module")
def pair(spec_path: Path) -> tuple[Target, Target]:
    return compile_spec(spec_path, 2), compile_spec(spec_path, 2, options=Options(cpus=CPUS))


def on(cpus: list[int]) -> list[int]:
    return sorted(CPUS[cpu] for cpu in cpus)


def mapped_list(text: str) -> str:
    """``0,1`` -> ``5,7``."""
    return ",".join(map(str, on([int(cpu) for cpu in text.split(",")])))


def without_headers(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if "regenerate with" not in line)


def map_cpus_in(data: Any) -> Any:
    """Every ``cpus`` / ``affinity`` list in a parsed file, mapped."""
    if isinstance(data, dict):
        return {k: on(v) if k in ("cpus", "affinity") else map_cpus_in(v) for k, v in data.items()}
    if isinstance(data, list):
        return [map_cpus_in(item) for item in data]
    return data


def test_the_premise_every_file_names_both_cores(pair: tuple[Target, Target]) -> None:
    plain, _ = pair
    table = json.loads(plain.files["runtime.json"])
    assert {cpu for p in table["processes"] for cpu in p["cpus"]} == {0, 1}
    assert "cie_thread_configurator.yaml" in plain.files


def test_runtime_json_lists_the_cpus_and_maps_the_processes(pair: tuple[Target, Target]) -> None:
    plain, moved = pair
    want = json.loads(plain.files["runtime.json"])
    for process in want["processes"]:
        process["cpus"] = on(process["cpus"])
    want["cpus"] = list(CPUS)
    want["generated_by"]["command"] += " --cpus 5,7"
    assert json.loads(moved.files["runtime.json"]) == want  # the plan keeps its plan cores


def test_params_and_thread_configurator_name_the_cpus(pair: tuple[Target, Target]) -> None:
    plain, moved = pair
    for name in ("params.yaml", "cie_thread_configurator.yaml"):
        assert yaml.safe_load(moved.files[name]) == map_cpus_in(yaml.safe_load(plain.files[name])), name


PROCESS_CPUS = re.compile(r'"cpus": "([0-9,]+)"')  # launch.py's table of processes
START = re.compile(r"^  start (\S+) ([0-9,]+) ", re.MULTILINE)
CHECK = re.compile(r"^check_cpus ([0-9 ]+)$", re.MULTILINE)


def test_launch_files_pin_to_the_cpus(pair: tuple[Target, Target]) -> None:
    plain, moved = pair
    old, new = plain.files["launch.sh"], moved.files["launch.sh"]
    assert [(key, mapped_list(cpus)) for key, cpus in START.findall(old)] == START.findall(new)
    assert len(START.findall(new)) == 5
    assert [mapped_list(",".join(found.split())).replace(",", " ") for found in CHECK.findall(old)] == CHECK.findall(
        new
    )
    old_py, new_py = plain.files["launch.py"], moved.files["launch.py"]
    assert [mapped_list(cpus) for cpus in PROCESS_CPUS.findall(old_py)] == PROCESS_CPUS.findall(new_py)
    assert len(PROCESS_CPUS.findall(new_py)) == 5  # each process, which launch.py pins as it starts it
    # Nothing else changes.
    assert without_headers(PROCESS_CPUS.sub("", old_py)) == without_headers(PROCESS_CPUS.sub("", new_py))


def test_plan_md_says_which_cpu_each_core_is(pair: tuple[Target, Target]) -> None:
    plain, moved = pair
    text = moved.files["PLAN.md"]
    assert "Plan core 0 runs on CPU 5, core 1 runs on CPU 7 (`compile --cpus`)" in text
    assert without_headers(plain.files["PLAN.md"]).split("# robot on 2 cores")[1].strip() in text


def test_a_table_read_back_keeps_its_cpus(pair: tuple[Target, Target], tmp_path: Path) -> None:
    _, moved = pair
    path = tmp_path / "runtime.json"
    path.write_text(moved.files["runtime.json"])
    assert load_table(path).cpus == CPUS


@pytest.mark.parametrize(
    ("cpus", "message"),
    [
        ([3, 2], "ascending order"),
        ([2, 2], "ascending order"),
        ([-1, 2], "a list of CPU numbers"),
        ([1.5, 2], "a list of CPU numbers"),
        ([True, 2], "a list of CPU numbers"),
        ("2,3", "a list of CPU numbers"),
        ([4], "1 CPUs for 2 cores"),
    ],
)
def test_a_table_with_bad_cpus_is_refused_naming_the_field(
    pair: tuple[Target, Target], tmp_path: Path, cpus: Any, message: str
) -> None:
    _, moved = pair
    table = json.loads(moved.files["runtime.json"])
    table["cpus"] = cpus
    path = tmp_path / "runtime.json"
    path.write_text(json.dumps(table, indent=2))
    with pytest.raises(SpecError) as error:
        load_table(path)
    assert re.search(rf"runtime.json:\d+:\d+: cpus: .*{re.escape(message)}", str(error.value)), str(error.value)


# --------------------------------------------------------------------------- the command line


@pytest.mark.parametrize(
    ("cpus", "message"),
    [
        ("2,2", "CPU 2 is given twice"),
        ("-1,2", "'-1' is not a CPU number"),
        ("a,3", "'a' is not a CPU number"),
        ("2.5,3", "'2.5' is not a CPU number"),
        ("2,,3", "an empty entry"),
        ("3", "1 CPU for 2 cores"),
        ("8192,1", "CPU 8192 cannot exist"),
    ],
)
def test_bad_cpus_are_refused_and_nothing_is_written(spec_path: Path, tmp_path: Path, cpus: str, message: str) -> None:
    out = tmp_path / "out"
    result = runner.invoke(app, ["compile", str(spec_path), "-k", "2", "--cpus", cpus, "--out", str(out)])
    assert result.exit_code == ExitCode.BAD_INPUT, result.output
    assert f"--cpus {cpus}: {message}" in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_cpus_in_any_order_are_the_same_cpus(spec_path: Path, tmp_path: Path) -> None:
    """The header's command names them ascending, as they are used: the same bytes either way."""
    folders = []
    out = tmp_path / "out"
    for cpus in ["7,5", "5,7"]:
        result = runner.invoke(app, ["compile", str(spec_path), "-k", "2", "--cpus", cpus, "--out", str(out)])
        assert result.exit_code == 0, result.output
        folders.append({path.name: path.read_bytes() for path in out.iterdir()})
        shutil.rmtree(out)
    assert folders[0] == folders[1]
    assert b"--cpus 5,7" in folders[0]["runtime.json"]


def test_more_cpus_than_cores_use_the_lowest(spec_path: Path) -> None:
    """One spec for several core counts on one CPU list: a plan for K cores runs on its K lowest CPUs."""
    target = compile_spec(spec_path, 1, options=Options(cpus=(3, 6)))
    table = json.loads(target.files["runtime.json"])
    assert {cpu for p in table["processes"] for cpu in p["cpus"]} == {3}
    assert table["cpus"] == [3, 6]
