"""params.yaml options for real nodes: integer rate parameters, keys under any namespace.

``rate_type: int`` is checked against the same spec written with floats (the
rounding rule applied here: a rate in hz down, a period up) and against a node
on its own clock, worked by hand.  ``any_namespace`` against rcl's wildcard
key ``/**/<node>``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from catanc.artifacts.compile import compile_spec
from catanc.artifacts.deploy import rate_value
from catanc.cli import app
from catanc.errors import ExitCode

runner = CliRunner()

SPEC = """catan: 1
app: robot
nodes:
  cam: {compute_ms: 4}
  det: {compute_ms: 30}
  imu: {scheduled: false, rate_hz: 45.5}
  map: {compute_ms: 80}
  motor: {scheduled: false}
edges: [[cam, det], [det, motor], [imu, det], [det, map]]
subchains:
  # /perception runs det and map in one thread (no callback groups): front and map share a core.
  cam: [cam]
  front: [det]
  map: [map]
objective:
  - {chain: [cam, det, motor], weight: 1.0}
  - {node: map, weight: 0.01}
constraints:
  - {node: map, max_rate_hz: 0.4}
deploy:
  cam: {ros_node: /camera, rate_param: fps RATE_TYPE}
  det: {ros_node: /perception, rate_param: period_ms, rate_unit: ms RATE_TYPE}
  map: {ros_node: /perception, rate_param: map.period, rate_unit: s RATE_TYPE}
  imu: {ros_node: /imu/driver, rate_param: rate RATE_TYPE NAMESPACE}
"""


def write_spec(folder: Path, rate_type: str = "", namespace: str = "", text: str = SPEC) -> Path:
    """SPEC with ``, <rate_type>`` on every deploy entry and ``namespace`` on imu's."""
    path = folder / "robot.yaml"
    path.write_text(text.replace(" RATE_TYPE", f", {rate_type}" if rate_type else "").replace(" NAMESPACE", namespace))
    return path


def params(path: Path) -> dict[str, Any]:
    loaded: dict[str, Any] = yaml.safe_load(compile_spec(path, 2).files["params.yaml"])
    return loaded


def test_integer_rates_round_towards_the_slower_rate(tmp_path: Path) -> None:
    floats = params(write_spec(tmp_path, "rate_type: float"))
    ints = params(write_spec(tmp_path, "rate_type: int"))
    camera, perception = floats["/camera"]["ros__parameters"], floats["/perception"]["ros__parameters"]
    assert ints["/camera"]["ros__parameters"]["fps"] == math.floor(camera["fps"])
    assert ints["/perception"]["ros__parameters"]["period_ms"] == math.ceil(perception["period_ms"])
    assert ints["/perception"]["ros__parameters"]["map"]["period"] == math.ceil(perception["map"]["period"])
    assert ints["/imu/driver"]["ros__parameters"]["rate"] == 45  # by hand: its own clock, 45.5 Hz, down
    assert floats["/imu/driver"]["ros__parameters"]["rate"] == 45.5
    for tree in (ints["/camera"], ints["/perception"], ints["/imu/driver"]):
        numbers = [tree["ros__parameters"].get(k) for k in ("fps", "period_ms", "rate")]
        assert all(isinstance(n, int) and not isinstance(n, bool) for n in numbers if n is not None)
    # The premise: the float values are not whole already.
    assert camera["fps"] != math.floor(camera["fps"])
    # catan.period_ms stays the plan's.
    assert ints["/camera"]["ros__parameters"]["catan"] == camera["catan"]


def test_the_default_is_a_float_and_the_table_is_as_before(tmp_path: Path) -> None:
    plain = compile_spec(write_spec(tmp_path), 2).files
    explicit = compile_spec(write_spec(tmp_path, "rate_type: float, any_namespace: false"), 2).files
    assert yaml.safe_load(plain["params.yaml"]) == yaml.safe_load(explicit["params.yaml"])
    deploy = json.loads(plain["runtime.json"])["spec"]["deploy"]
    assert not [entry for entry in deploy.values() if {"rate_type", "any_namespace"} & set(entry)]
    assert json.loads(explicit["runtime.json"])["spec"] == json.loads(plain["runtime.json"])["spec"]


def test_an_integer_that_cannot_say_the_rate_is_a_compile_error(tmp_path: Path) -> None:
    text = SPEC.replace("imu: {scheduled: false, rate_hz: 45.5}", "imu: {scheduled: false, rate_hz: 0.5}")
    path = write_spec(tmp_path, "rate_type: int", text=text)
    out = tmp_path / "out"
    result = runner.invoke(app, ["compile", str(path), "-k", "2", "--out", str(out)])
    assert result.exit_code == ExitCode.BAD_INPUT, result.output
    line = next(number for number, text in enumerate(path.read_text().splitlines(), 1) if "imu: {ros_node" in text)
    assert f"robot.yaml:{line}:" in result.output
    assert "deploy.imu.rate_type: the plan runs imu at 0.5 Hz" in result.output
    assert "0.5 hz rounds down to 0" in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_rate_type_without_rate_param_is_a_spec_error(tmp_path: Path) -> None:
    text = SPEC.replace("rate_param: fps RATE_TYPE", "rate_type: int")
    result = runner.invoke(app, ["validate", str(write_spec(tmp_path, text=text))])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "deploy.cam.rate_type: rate_type is the type of rate_param's value, and there is no rate_param" in (
        result.output
    )


def test_any_namespace_keys_the_node_with_rcls_wildcard(tmp_path: Path) -> None:
    found = params(write_spec(tmp_path, namespace=", any_namespace: true"))
    assert set(found) == {"/camera", "/perception", "/**/imu/driver"}
    assert found["/**/imu/driver"]["ros__parameters"]["rate"] == 45.5
    table = json.loads(compile_spec(write_spec(tmp_path, namespace=", any_namespace: true"), 2).files["runtime.json"])
    assert table["spec"]["deploy"]["imu"]["any_namespace"] is True
    assert [p["ros_node"] for p in table["processes"] if p["key"] == "/imu/driver"] == ["/imu/driver"]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            ("imu: {ros_node: /imu/driver", "imu: {ros_node: /driver"),
            "deploy.imu.any_namespace: /**/driver would also match /imu/driver",
        ),
        (("cam: {ros_node: /camera, rate_param: fps RATE_TYPE}", "cam: {any_namespace: true}"), "needs ros_node"),
    ],
)
def test_any_namespace_that_would_reach_another_node_is_an_error(
    tmp_path: Path, edit: tuple[str, str], message: str
) -> None:
    text = SPEC.replace(*edit)
    if "/driver" in edit[1]:  # a second node named /imu/driver, so /**/driver reaches two
        text = text.replace("cam: {ros_node: /camera", "cam: {ros_node: /imu/driver")
    path = write_spec(tmp_path, namespace=", any_namespace: true", text=text)
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == ExitCode.BAD_INPUT, result.output
    assert message in result.output, result.output


@pytest.mark.parametrize(
    ("period_ms", "unit", "whole"),
    [
        (1000 / 45.5, "hz", 45),
        (1000 / 45, "hz", 45),  # 1000 / (1000 / 45) is 45 give or take float noise: still 45
        (1000 / 1.99, "hz", 1),
        (2500.0, "s", 3),
        (2000.0, "s", 2),
        (21.978, "ms", 22),
        (22.0, "ms", 22),
        (0.6, "ms", 1),
    ],
)
def test_the_rounding_rule_by_hand(period_ms: float, unit: str, whole: int) -> None:
    assert rate_value(period_ms, unit, "int") == whole


@pytest.mark.parametrize(("period_ms", "unit"), [(2000.0, "hz"), (333.3, "s"), (0.4, "ms")])
def test_rounding_that_would_more_than_halve_the_rate_is_refused(period_ms: float, unit: str) -> None:
    with pytest.raises(ValueError, match="rounds"):
        rate_value(period_ms, unit, "int")


OFFERED = """catan: 1
app: slow_camera
nodes:
  cam: {compute_ms: 10}
  det: {compute_ms: 90}
  motor: {scheduled: false}
edges: [[cam, det], [det, motor]]
subchains: {front: [cam, det]}
objective: [{chain: [cam, det, motor], weight: 1.0}]
constraints: [{node: cam, rate_hz: [15, 30]}]
deploy:
  cam: {ros_node: /camera, rate_param: fps}
"""


def test_a_driver_that_offers_rates_is_given_the_one_picked_even_where_none_fits(tmp_path: Path) -> None:
    # By hand: cam and det take 100 ms a run on one core, so the subchain runs below 10 Hz; neither 15 nor
    # 30 Hz fits, the plan picks 15 (the slowest) and scales the bounds. The camera's driver takes only
    # 15 or 30: it is given 15, while catanc's own period for the subchain is the plan's, above 100 ms.
    path = tmp_path / "slow_camera.yaml"
    path.write_text(OFFERED)
    camera = yaml.safe_load(compile_spec(path, 1).files["params.yaml"])["/camera"]["ros__parameters"]
    assert camera["fps"] == 15.0
    assert camera["catan"]["period_ms"] > 100.0
