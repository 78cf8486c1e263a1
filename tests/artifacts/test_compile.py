"""``catanc compile``: the five files, their formats and rules, determinism, ``--check``.

Oracles: rcl_yaml_param_parser's typing rules written out independently
(parse.c's ``get_value``: plain ``y``/``on``/... are booleans, ``strtol`` then
``strtod`` decide ints and doubles), Python's own parser for ``launch.py``,
hashlib for the header's digest, and fresh processes for determinism.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import py_compile
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from catanc import __version__
from catanc.artifacts.compile import Target, compile_spec
from catanc.artifacts.deploy import processes
from catanc.artifacts.emit import FILES
from catanc.artifacts.runtime_table import RUNTIME_FORMAT
from catanc.cli import app
from catanc.errors import ExitCode
from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.planning.planner import plan
from catanc.spec.language import RateConstraint, Spec

ROOT = Path(__file__).parents[2]
SPECS = sorted((ROOT / "specs").glob("*.yaml"))
runner = CliRunner()

DEPLOYED = """catan: 1
app: robot
nodes:
  cam: {compute_ms: 4}
  det: {compute_ms: 30}
  track: {compute_ms: 2}
  imu: {scheduled: false, rate_hz: 200}
  map: {compute_ms: 80}
  motor: {scheduled: false}
edges: [[cam, det], [det, track], [imu, track], [track, motor], [det, map]]
subchains:
  # /perception runs det, track and map in one thread (no callback groups): front and map share a core.
  cam: [cam]
  front: [det, track]
  map: [map]
objective:
  - {chain: [cam, det, track, motor], weight: 1.0}
  - {node: map, weight: 0.01}
constraints:
  - {node: map, max_rate_hz: 2}
deploy:
  cam: {ros_node: /sensors/camera, package: cams, executable: cam_node, rate_param: fps,
        command: "ros2 run cams cam_node --ros-args -r __node:=camera"}
  det: {ros_node: /perception, package: percept, executable: perception, rate_param: detector.rate,
        command: "ros2 run percept perception"}
  map: {ros_node: /perception, rate_param: mapper.period, rate_unit: s}
  track: {ros_node: /perception, rate_param: tracker.period_ms, rate_unit: ms}
  imu: {ros_node: /imu_driver, rate_param: rate, command: "imu_driver --port '/dev/tty USB0'"}
"""


@pytest.fixture(scope="module")
def compiled(example_targets: Mapping[tuple[str, int], Target]) -> dict[tuple[str, int], Target]:
    """Every example spec at 1 and 2 cores, compiled in memory (once for the session: tests/artifacts/conftest.py)."""
    assert sorted(example_targets) == sorted((path.stem, cores) for path in SPECS for cores in (1, 2))
    return dict(example_targets)


def targets(compiled: dict[tuple[str, int], Target]) -> Iterator[Target]:
    yield from compiled.values()


# --------------------------------------------------------------------------- the folder and its headers


@pytest.mark.slow
def test_every_folder_has_exactly_the_five_files(compiled: dict[tuple[str, int], Target]) -> None:
    for (stem, cores), target in compiled.items():
        assert sorted(target.files) == sorted(FILES)
        app_name = load_spec(ROOT / "specs" / f"{stem}.yaml").app
        assert target.folder == Path("out") / app_name / f"cores-{cores}"


def test_files_are_plain_text_with_headers_naming_version_command_and_digest(
    compiled: dict[tuple[str, int], Target],
) -> None:
    for (stem, cores), target in compiled.items():
        spec_path = ROOT / "specs" / f"{stem}.yaml"
        digest = hashlib.sha256(spec_path.read_bytes()).hexdigest()
        command = f"catanc compile {os.path.relpath(spec_path)} --cores {cores}"
        for name, text in target.files.items():
            assert "\r" not in text, name
            assert text.endswith("\n"), name
            assert not text.endswith("\n\n"), name
            assert str(ROOT) not in text, name  # no absolute paths
            assert "/tmp/" not in text, name
            if name == "runtime.json":
                generated = json.loads(text)["generated_by"]
                assert generated == {
                    "catanc": __version__,
                    "command": command,
                    "spec": spec_path.name,
                    "spec_sha256": digest,
                }
            else:
                head = "\n".join(text.splitlines()[:4])
                assert f"catanc {__version__}" in head, name
                assert digest in head, name
                assert f"`{command}`" in head, name


# --------------------------------------------------------------------------- runtime.json


def test_runtime_table_has_every_field_of_the_interface(compiled: dict[tuple[str, int], Target]) -> None:
    for (stem, cores), target in compiled.items():
        table = json.loads(target.files["runtime.json"])
        assert table["format"] == RUNTIME_FORMAT
        assert table["cores"] == cores
        assert table["app"] == load_spec(ROOT / "specs" / f"{stem}.yaml").app
        plan_table = table["plan"]
        assert isinstance(plan_table["objective"], float)
        assert plan_table["constraint_scale"] >= 1.0
        for name, sub in plan_table["subchains"].items():
            assert {"nodes", "cores", "shared", "threads", "period_ms", "fraction", "priority"} <= set(sub), name
            assert all(0 <= core < cores for core in sub["cores"])
            assert sub["period_ms"] > 0
            assert sub["fraction"] > 0
        for core in plan_table["cores"]:
            assert set(core) >= {"core", "period_ms", "order"}
            assert sorted(core["order"]) == sorted(
                name for name, sub in plan_table["subchains"].items() if sub["shared"] and core["core"] in sub["cores"]
            )
        for chain in plan_table["chains"]:
            assert set(chain) >= {"nodes", "subchains", "latency_ms", "period_ms", "response_ms"}
            assert math.isclose(chain["response_ms"], chain["latency_ms"] + chain["period_ms"], abs_tol=2e-6)


def test_runtime_table_spec_is_enough_to_plan_again(compiled: dict[tuple[str, int], Target]) -> None:
    """The enforcer re-solves from the table's spec alone: it must give the very same plan."""
    for (stem, cores), target in compiled.items():
        original = load_spec(ROOT / "specs" / f"{stem}.yaml")
        table = json.loads(target.files["runtime.json"])
        again = Spec.model_validate(table["spec"])
        assert again.model_dump() == original.model_dump()
        assert build_problem(again) == build_problem(original)
        if cores == 1:  # one re-plan per spec is enough to show the table is complete
            from catanc.artifacts.runtime_table import plan_payload

            assert plan_payload(plan(again, cores), build_problem(again)) == table["plan"]


def test_runtime_table_processes_match_the_deploy_section(compiled: dict[tuple[str, int], Target]) -> None:
    for (stem, _), target in compiled.items():
        spec = load_spec(ROOT / "specs" / f"{stem}.yaml")
        table = json.loads(target.files["runtime.json"])
        hosted = sorted(node for process in table["processes"] for node in process["nodes"])
        assert hosted == sorted(spec.deploy)
        for process in table["processes"]:
            commands = {spec.deploy[node].command for node in process["nodes"]} - {None}
            assert [shlex.split(c) for c in commands] == ([process["argv"]] if process["argv"] else [])


# --------------------------------------------------------------------------- params.yaml


RCL_TRUE = {"Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
RCL_FALSE = {"N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}
STRTOL = re.compile(r"\s*[+-]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
STRTOD = re.compile(
    r"\s*[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|0[xX]([0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)([pP][+-]?\d+)?"
    r"|inf(inity)?|nan(\([0-9A-Za-z_]*\))?)",
    re.IGNORECASE,
)
RCL_SPECIAL_DOUBLES = {f"{sign}.{word}" for sign in ("", "+", "-") for word in ("inf", "Inf", "INF")} | {
    ".nan",
    ".NaN",
    ".NAN",
}


def rcl_type(node: yaml.ScalarNode) -> type:
    """The type rcl_yaml_param_parser gives a scalar (written from parse.c's rules, not from catanc)."""
    if node.style in ("'", '"'):
        return str
    text = node.value
    if text in RCL_TRUE or text in RCL_FALSE:
        return bool
    if STRTOL.fullmatch(text):
        return int
    if text in RCL_SPECIAL_DOUBLES or STRTOD.fullmatch(text):
        return float
    return str


def check_ros_params(text: str) -> dict[str, dict[str, Any]]:
    """Every rule of a params file rcl accepts; returns {node: {dotted parameter: python value}}."""
    document = yaml.compose(text)
    if document is None:
        return {}
    assert isinstance(document, yaml.MappingNode)
    found: dict[str, dict[str, Any]] = {}
    for key, value in document.value:
        assert isinstance(key, yaml.ScalarNode)
        assert re.fullmatch(r"(/[A-Za-z_][A-Za-z0-9_]*)+", key.value), key.value
        assert isinstance(value, yaml.MappingNode)
        assert [k.value for k, _ in value.value] == ["ros__parameters"]
        params: dict[str, Any] = {}
        walk_params(value.value[0][1], "", params)
        found[key.value] = params
    return found


def walk_params(node: yaml.Node, prefix: str, out: dict[str, Any]) -> None:
    assert isinstance(node, yaml.MappingNode), prefix
    for key, value in node.value:
        name = f"{prefix}{key.value}"
        if isinstance(value, yaml.MappingNode):
            walk_params(value, name + ".", out)
        elif isinstance(value, yaml.SequenceNode):
            assert value.value, f"{name}: an empty array has no type"
            kinds = {rcl_type(item) for item in value.value if isinstance(item, yaml.ScalarNode)}
            assert len(kinds) == 1
            assert len(value.value) == sum(isinstance(i, yaml.ScalarNode) for i in value.value)
            out[name] = [typed(item) for item in value.value]
        else:
            assert isinstance(value, yaml.ScalarNode), name
            out[name] = typed(value)


def typed(node: yaml.ScalarNode) -> Any:
    kind = rcl_type(node)
    if kind is bool:
        return node.value in RCL_TRUE
    return kind(node.value)


def test_rcl_typing_oracle_on_known_values() -> None:
    """The oracle itself, on cases parse.c settles."""
    cases = {"y": bool, "Off": bool, "12": int, "0x1f": int, "010": int, "1.0": float, "1e-05": float}
    cases |= {"1.0e-05": float, ".inf": float, "GL": str, "0.5.1": str, "inf": float, "12abc": str}
    for text, kind in cases.items():
        assert rcl_type(yaml.ScalarNode("tag:yaml.org,2002:str", text)) is kind, text
    assert rcl_type(yaml.ScalarNode("tag:yaml.org,2002:str", "12", style='"')) is str


def test_params_follow_rcl_rules_with_the_planned_rates(compiled: dict[tuple[str, int], Target]) -> None:
    for (stem, cores), target in compiled.items():
        spec = load_spec(ROOT / "specs" / f"{stem}.yaml")
        table = json.loads(target.files["runtime.json"])
        params = check_ros_params(target.files["params.yaml"])
        ros_nodes = {entry.ros_node for entry in spec.deploy.values() if entry.ros_node is not None}
        assert set(params) == ros_nodes
        periods = {node: sub["period_ms"] for sub in table["plan"]["subchains"].values() for node in sub["nodes"]}
        for node, entry in spec.deploy.items():
            if entry.ros_node is None:
                continue
            values = params[entry.ros_node]
            offered = [
                constraint.rate_hz
                for constraint in spec.constraints
                if isinstance(constraint, RateConstraint)
                and constraint.node == node
                and isinstance(constraint.rate_hz, list)
            ]
            if entry.rate_param is not None and offered:  # its driver takes one of these, however slow the plan
                assert entry.rate_unit == "hz"
                planned_hz = 1000.0 / periods[node]
                given = values[entry.rate_param]
                assert given in offered[0], (node, cores)
                assert given >= planned_hz * (1 - 1e-6), (node, cores)
                if any(math.isclose(rate, planned_hz, rel_tol=1e-6) for rate in offered[0]):
                    assert math.isclose(given, planned_hz, rel_tol=1e-6), (node, cores)
            elif entry.rate_param is not None:
                expected = {"hz": 1000.0 / periods[node], "s": periods[node] / 1000.0, "ms": periods[node]}
                assert isinstance(values[entry.rate_param], float)
                assert math.isclose(values[entry.rate_param], expected[entry.rate_unit], rel_tol=1e-6), (node, cores)
            assert isinstance(values["catan.priority"], int)
            assert all(isinstance(cpu, int) and 0 <= cpu < cores for cpu in values["catan.cpus"])
            if not spec.nodes[node].scheduled:  # FIFO 3 on every core, its own clock's period if any
                single = "catan.period_ms" in values or not any(k.startswith("catan.nodes.") for k in values)
                prefix = "catan." if single else f"catan.nodes.{node}."
                assert values[prefix + "priority"] == 3
                assert values[prefix + "cpus"] == list(range(cores))
                assert (prefix + "subchain") not in values
                continue
            subchain_key = "catan.subchain" if "catan.subchain" in values else f"catan.nodes.{node}.subchain"
            period_key = subchain_key.replace("subchain", "period_ms")
            assert node in table["plan"]["subchains"][values[subchain_key]]["nodes"]
            assert isinstance(values[period_key], float)
            assert values[period_key] == periods[node]


def test_params_quote_every_string_rcl_would_misread(tmp_path: Path) -> None:
    spec_text = DEPLOYED.replace("front:", "y:").replace("map: [map]", "inf: [map]")
    path = tmp_path / "robot.yaml"
    path.write_text(spec_text)
    target = compile_spec(path, 2)
    params = check_ros_params(target.files["params.yaml"])
    subchains = {values.get("catan.subchain") for values in params.values()}
    subchains |= {v for values in params.values() for k, v in values.items() if k.endswith(".subchain")}
    assert {"y", "inf"} <= subchains


@pytest.mark.parametrize("isolated", [False, True])
def test_params_of_a_process_hosting_several_subchains(isolated: bool) -> None:
    text = DEPLOYED
    if isolated:  # each node's callbacks in a group of their own: threads that may run on other cores
        for node, topic in (("det", "image"), ("track", "detections"), ("map", "map_in")):
            text = text.replace(
                f"  {node}: {{ros_node: /perception, ",
                f"  {node}: {{ros_node: /perception, callback_group: '/perception@Subscription(/{topic})', ",
            )
    spec = Spec.model_validate(yaml.safe_load(text))
    result = plan(spec, 3)
    by_key = {process.key: process for process in processes(spec, result)}
    perception = by_key["/perception"]
    assert perception.nodes == ("det", "track", "map")
    front, mapping = result.subchains["front"].cores, result.subchains["map"].cores
    assert perception.cpus == tuple(sorted({*front, *mapping}))
    assert (front == mapping) != isolated  # one thread: one core; apart, each subchain a core of its own
    imu = by_key["/imu_driver"]
    assert imu.cpus == (0, 1, 2)  # on its own clock: every core
    assert imu.priority == 3
    assert imu.argv == ("imu_driver", "--port", "/dev/tty USB0")
    assert imu.ros_nodes[0].params["rate"] == 200.0


# --------------------------------------------------------------------------- PLAN.md


def test_plan_md_is_the_explain_report(compiled: dict[tuple[str, int], Target]) -> None:
    for (_, cores), target in compiled.items():
        text = target.files["PLAN.md"]
        table = json.loads(target.files["runtime.json"])
        assert f"objective {table['plan']['objective']:.3f} ms" in text
        for heading in ("## 1. Cores", "## 2. Subchains", "## 3. Chains", "## 6. Baseline"):
            assert heading in text
        title = next(line for line in text.splitlines() if line.startswith("# "))
        assert title.endswith(f" on {cores} core{'s' if cores > 1 else ''}")


# --------------------------------------------------------------------------- determinism


@pytest.mark.slow
def test_fresh_processes_write_the_same_bytes(tmp_path: Path) -> None:
    """Every example spec at 1 and 2 cores, compiled twice in fresh processes with different hash seeds."""
    work = tmp_path / "work"
    (work / "specs").mkdir(parents=True)
    for spec in SPECS:
        (work / "specs" / spec.name).write_bytes(spec.read_bytes())
    trees = []
    for seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": seed}
        command = [sys.executable, "-m", "catanc", "compile", *(f"specs/{s.name}" for s in SPECS), "-k", "1", "-k", "2"]
        done = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True, timeout=300, check=False)
        assert done.returncode == 0, done.stderr
        files = sorted(p for p in (work / "out").rglob("*") if p.is_file())
        trees.append({p.relative_to(work / "out"): p.read_bytes() for p in files})
        (work / "out").rename(work / f"out-{seed}")
    assert len(trees[0]) == len(SPECS) * 2 * len(FILES)
    assert trees[0] == trees[1]


# --------------------------------------------------------------------------- the command


@pytest.fixture
def robot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "robot.yaml"
    path.write_text(DEPLOYED)
    return path


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_compile_then_check_is_current(robot: Path) -> None:
    result = runner.invoke(app, ["compile", "robot.yaml", "-k", "2"])
    assert result.exit_code == ExitCode.OK, result.output
    folder = Path("out/robot/cores-2")
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)
    assert "catanc compile robot.yaml --cores 2`" in (folder / "launch.sh").read_text()
    check = runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check"])
    assert check.exit_code == ExitCode.OK, check.output
    assert "out/robot/cores-2: up to date" in check.stdout


def test_the_bytecode_cache_python_writes_beside_launch_py_is_not_a_change(robot: Path) -> None:
    assert runner.invoke(app, ["compile", "robot.yaml", "-k", "2"]).exit_code == ExitCode.OK
    folder = Path("out/robot/cores-2")
    # What ros2 launch's SourceFileLoader leaves: __pycache__/launch.cpython-XY.pyc, written by Python itself.
    written = py_compile.compile(str(folder / "launch.py"), doraise=True)
    assert written is not None
    cached = Path(written)
    assert cached.parent == folder / "__pycache__"
    check = runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check"])
    assert check.exit_code == ExitCode.OK, check.output
    assert "out/robot/cores-2: up to date" in check.stdout
    robot.write_text(DEPLOYED.replace("compute_ms: 30", "compute_ms: 35"))
    result = runner.invoke(app, ["compile", "robot.yaml", "-k", "2"])
    assert result.exit_code == ExitCode.OK, result.output
    assert "updated: changed PLAN.md" in result.stdout
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)  # the stale cache went with the old folder


def test_check_reports_drift_and_never_writes(robot: Path) -> None:
    assert runner.invoke(app, ["compile", "robot.yaml", "-k", "2"]).exit_code == ExitCode.OK
    folder = Path("out/robot/cores-2")
    robot.write_text(DEPLOYED.replace("compute_ms: 30", "compute_ms: 35"))
    (folder / "launch.py").unlink()
    (folder / "notes.txt").write_text("mine\n")
    before = folder_bytes(folder)
    result = runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check", "--diff"])
    assert result.exit_code == ExitCode.DRIFT, result.output
    assert "stale: changed PLAN.md, launch.sh, params.yaml, runtime.json; missing launch.py; extra notes.txt" in (
        result.stdout
    )
    assert "--- out/robot/cores-2/params.yaml (on disk)" in result.stdout
    assert "+++ out/robot/cores-2/params.yaml (generated)" in result.stdout
    assert "1 of 1 output folder is stale" in result.stderr
    assert folder_bytes(folder) == before
    assert sorted(p.name for p in folder.parent.iterdir()) == ["cores-2"]


def test_dry_run_says_what_would_change_and_writes_nothing(robot: Path) -> None:
    result = runner.invoke(app, ["compile", "robot.yaml", "-k", "1", "--dry-run"])
    assert result.exit_code == ExitCode.OK, result.output
    assert "out/robot/cores-1: would be created (5 files)" in result.stdout
    assert not Path("out").exists()


def test_check_without_a_folder_is_its_own_error(robot: Path) -> None:
    result = runner.invoke(app, ["compile", "robot.yaml", "-k", "1", "--check"])
    assert result.exit_code == ExitCode.NOT_COMPILED
    assert "out/robot/cores-1: no output folder to check" in result.stderr
    assert not Path("out").exists()


def test_a_file_in_the_way_and_an_unwritable_out_are_distinct_errors(robot: Path) -> None:
    Path("blocker").write_text("x\n")
    blocked = runner.invoke(app, ["compile", "robot.yaml", "-k", "1", "--out", "blocker"])
    assert blocked.exit_code == ExitCode.OUTPUT_BLOCKED
    assert "blocker: a file is in the way of the output folder" in blocked.stderr
    assert Path("blocker").read_text() == "x\n"
    unwritable = runner.invoke(app, ["compile", "robot.yaml", "-k", "1", "--out", "/sys/catanc/out"])
    assert unwritable.exit_code == ExitCode.OUTPUT
    assert "cannot" in unwritable.stderr
    assert "Traceback" not in blocked.output + unwritable.output


def test_a_bad_spec_writes_nothing_for_any_spec(robot: Path) -> None:
    bad = robot.with_name("bad.yaml")
    bad.write_text(DEPLOYED.replace("app: robot", "app: other").replace("[det, map]", "[det, mapp]"))
    result = runner.invoke(app, ["compile", "robot.yaml", "bad.yaml", "-k", "1"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "bad.yaml:10:" in result.stderr
    assert "unknown node 'mapp'" in result.stderr
    assert not Path("out").exists()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["robot.yaml", "-k", "1", "-k", "2", "--out", "x"], "--out names one folder"),
        (["robot.yaml", "-k", "1", "--check", "--dry-run"], "pick one"),
        (["robot.yaml", "copy.yaml", "-k", "1"], "would both write"),
    ],
)
def test_usage_errors(robot: Path, arguments: list[str], message: str) -> None:
    robot.with_name("copy.yaml").write_text(DEPLOYED)
    result = runner.invoke(app, ["compile", *arguments])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert message in result.stderr
    assert not Path("out").exists()
    assert not Path("x").exists()


# --------------------------------------------------------------------------- the documented CI check


@pytest.mark.slow
def test_committed_output_passes_the_documented_check_and_hook(monkeypatch: pytest.MonkeyPatch) -> None:
    """The CI guide's command and the pre-commit hook's entry, run on this repository's own out/."""
    monkeypatch.chdir(ROOT)
    guide = (ROOT / "docs" / "guide" / "ci.md").read_text()
    documented = re.search(r"- run: (catanc compile --check[^\n]*)", guide)
    assert documented is not None
    words = shlex.split(documented.group(1))
    specs = [str(p.relative_to(ROOT)) for p in SPECS]
    arguments = [w for word in words[1:] for w in (specs if word == "specs/*.yaml" else [word])]
    result = runner.invoke(app, arguments)
    assert result.exit_code == ExitCode.OK, result.output
    assert result.stdout.count(": up to date") == len(SPECS) * 2
    hooks = yaml.safe_load((ROOT / ".pre-commit-hooks.yaml").read_text())
    (hook,) = (h for h in hooks if h["id"] == "catanc-check")
    assert hook["pass_filenames"] is False
    entry = shlex.split(hook["entry"])
    assert entry[:3] == ["catanc", "compile", "--check"]
    result = runner.invoke(app, [*entry[1:], "specs/nav2d.yaml", "--cores", "1", "--cores", "2"])
    assert result.exit_code == ExitCode.OK, result.output
