"""Units and enumerations the ecosystem spells several ways are read in any case and stored lower-case."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from catanc.errors import ExitCode
from catanc.model.load import parse_spec
from catanc.spec.language import JITTER_DISTS, RATE_UNITS, json_schema

# One dedicated node of 5 ms on one core with the default 5% slack (docs/explanation/model.md section 4):
# its period is 5 / 0.95 = 5.2632 ms, so its rate parameter is 190 in hz, 0.0052632 in s and
# 5.2632 in ms (worked by hand).
SPEC = """catan: 1
app: units
nodes:
  cam: {{compute_ms: 5, workload: {{jitter: {{cv: 0.1, dist: {dist}}}}}}}
subchains: {{main: [cam]}}
objective: [{{node: cam, weight: 1}}]
deploy:
  cam: {{ros_node: /cam, rate_param: rate, rate_unit: {unit}}}
"""
BY_HAND = {"hz": 190.0, "s": 5.0 / 0.95 / 1000.0, "ms": 5.0 / 0.95}

SPELLINGS = [("Hz", "hz"), ("HZ", "hz"), ("hz", "hz"), ("S", "s"), ("s", "s"), ("ms", "ms"), ("MS", "ms"), ("Ms", "ms")]


@pytest.mark.parametrize(("written", "canonical"), SPELLINGS)
def test_rate_unit_is_read_in_any_case_and_stored_lower_case(written: str, canonical: str) -> None:
    spec = parse_spec(SPEC.format(unit=written, dist="lognormal"))
    assert spec.deploy["cam"].rate_unit == canonical


@pytest.mark.parametrize(
    ("written", "canonical"), [("LogNormal", "lognormal"), ("Uniform", "uniform"), ("NORMAL", "normal")]
)
def test_jitter_dist_is_read_in_any_case(written: str, canonical: str) -> None:
    spec = parse_spec(SPEC.format(unit="hz", dist=written))
    node = spec.nodes["cam"]
    assert node.workload is not None
    assert node.workload.jitter is not None
    assert node.workload.jitter.dist == canonical


@pytest.mark.parametrize(("written", "canonical"), [("Hz", "hz"), ("S", "s"), ("MS", "ms")])
def test_compiled_deployment_has_the_canonical_unit_and_the_value_in_it(
    tmp_path: Path, written: str, canonical: str
) -> None:
    path = tmp_path / "units.yaml"
    path.write_text(SPEC.format(unit=written, dist="Uniform"))
    out = tmp_path / "out"
    finished = subprocess.run(
        [sys.executable, "-m", "catanc", "compile", str(path), "-k", "1", "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert finished.returncode == 0, finished.stderr
    table = json.loads((out / "runtime.json").read_text())
    assert table["spec"]["deploy"]["cam"]["rate_unit"] == canonical
    assert table["spec"]["nodes"]["cam"]["workload"]["jitter"]["dist"] == "uniform"
    params = (out / "params.yaml").read_text()
    value = float(re.search(r"^\s+rate: (\S+)$", params, re.MULTILINE).group(1))  # type: ignore[union-attr]
    assert value == pytest.approx(BY_HAND[canonical])


def test_a_wrong_unit_names_file_line_field_and_the_accepted_units(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(SPEC.format(unit="kHz", dist="lognormal"))
    finished = subprocess.run(
        [sys.executable, "-m", "catanc", "validate", str(path)], capture_output=True, text=True, check=False
    )
    assert finished.returncode == ExitCode.BAD_INPUT
    assert finished.stdout == ""
    (line,) = finished.stderr.splitlines()
    assert line.startswith(f"{path}:8:")
    assert "deploy.cam.rate_unit" in line
    assert all(f"'{unit}'" in line for unit in RATE_UNITS)
    assert "'kHz'" in line  # as the user wrote it


def _schema_of(model: str, field: str) -> dict[str, object]:
    prop: dict[str, object] = json_schema()["$defs"][model]["properties"][field]
    return prop


@pytest.mark.parametrize(
    ("model", "field", "choices", "accepted", "rejected"),
    [
        ("Deploy", "rate_unit", RATE_UNITS, ["Hz", "HZ", "hz", "S", "ms", "mS"], ["kHz", "sec", "hz ", "m", ""]),
        ("Jitter", "dist", JITTER_DISTS, ["LogNormal", "UNIFORM", "normal"], ["gamma", "log normal", "norm"]),
    ],
)
def test_schema_offers_the_canonical_words_and_accepts_any_case(
    model: str, field: str, choices: tuple[str, ...], accepted: list[str], rejected: list[str]
) -> None:
    prop = _schema_of(model, field)
    options = prop["anyOf"]
    assert isinstance(options, list)
    enums = [option["enum"] for option in options if "enum" in option]
    assert enums == [list(choices)]
    (pattern,) = [re.compile(option["pattern"]) for option in options if "pattern" in option]
    for word in accepted:
        assert pattern.fullmatch(word), word
    for word in rejected:
        assert not pattern.fullmatch(word), word
