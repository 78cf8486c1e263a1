"""``catanc init``: a starter spec that is commented field by field, validates and compiles as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel

from catanc.errors import ExitCode
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.spec import language
from catanc.spec.starter import starter_spec


def catanc(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """The installed command line, in a fresh process, as a user would run it."""
    return subprocess.run([sys.executable, "-m", "catanc", *args], cwd=cwd, capture_output=True, text=True, check=False)


@pytest.mark.slow
def test_init_then_compile_succeeds_through_the_real_cli(tmp_path: Path) -> None:
    made = catanc("init", "--out", "x.yaml", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    assert (tmp_path / "x.yaml").is_file()
    compiled = catanc("compile", "x.yaml", "-k", "1", "--out", "o", cwd=tmp_path)
    assert compiled.returncode == 0, compiled.stderr
    assert compiled.stderr == ""  # no warnings either
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [
        "PLAN.md",
        "launch.py",
        "launch.sh",
        "params.yaml",
        "runtime.json",
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "x.yaml"]  # no staging file left behind


def test_init_names_the_file_after_the_app_by_default(tmp_path: Path) -> None:
    made = catanc("init", "--app", "rover", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    spec = parse_spec((tmp_path / "rover.yaml").read_text())
    assert spec.app == "rover"
    assert "catanc validate rover.yaml" in (tmp_path / "rover.yaml").read_text()


def test_init_refuses_to_overwrite_a_file(tmp_path: Path) -> None:
    target = tmp_path / "mine.yaml"
    target.write_text("my own work\n")
    refused = catanc("init", "--out", "mine.yaml", cwd=tmp_path)
    assert refused.returncode == ExitCode.BAD_INPUT
    assert "mine.yaml: already exists" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert target.read_text() == "my own work\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.yaml"]


def test_init_refuses_a_bad_app_name(tmp_path: Path) -> None:
    refused = catanc("init", "--app", "9 lives", "--out", "x.yaml", cwd=tmp_path)
    assert refused.returncode == ExitCode.BAD_INPUT
    assert "--app" in refused.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("app", ["my_app", "true", "null", "yes", "a-b.c", "_x", "a_rather_long_app_name_for_a_robot"])
def test_starter_validates_without_warnings_for_any_app_name(app: str) -> None:
    spec = parse_spec(starter_spec(app))
    assert spec.app == app
    assert not build_problem(spec).warnings


@pytest.mark.parametrize("cores", [1, 2])
def test_starter_has_what_the_issue_asks_for_and_plans(cores: int) -> None:
    from catanc.planning.planner import plan

    spec = parse_spec(starter_spec())
    scheduled = [name for name, node in spec.nodes.items() if node.scheduled]
    assert 2 <= len(scheduled) <= 3
    assert sorted(len(members) for members in spec.subchains.values()) == [1] * len(scheduled)
    assert [type(term).__name__ for term in spec.objective] == ["ChainTerm"]
    assert any(isinstance(c, language.RateConstraint) and c.max_rate_hz for c in spec.constraints)
    assert spec.baseline.rates_hz
    assert spec.deploy
    assert not plan(spec, cores).warnings


def _field_names() -> set[str]:
    """Every field name of the spec language (by alias), from the models themselves."""
    names: set[str] = set()
    for value in vars(language).values():
        if isinstance(value, type) and issubclass(value, BaseModel) and value.__module__ == language.__name__:
            names |= {field.alias or name for name, field in value.model_fields.items()}
    return names


def test_every_field_carries_a_comment_and_every_time_or_rate_its_unit() -> None:
    fields = _field_names()
    text = starter_spec()
    keyed = 0
    for line in text.splitlines():
        match = re.match(r"^\s*(?:- )?([A-Za-z_]+):", line)
        if match is None or match.group(1) not in fields:
            continue
        keyed += 1
        assert "#" in line, f"no comment: {line!r}"
        key = match.group(1)
        comment = line.split("#", 1)[1]
        if key.endswith("_ms"):
            assert "(ms)" in comment or "ms" in comment.split(), line
        if key.endswith("_hz"):
            assert "Hz" in comment, line
    assert keyed >= 15


def test_starter_points_editors_at_the_schema() -> None:
    lines = starter_spec().splitlines()
    assert lines[0] == "# yaml-language-server: $schema=catanc.schema.json"
    assert any("catanc schema > catanc.schema.json" in line for line in lines)


def test_starter_is_plain_yaml_a_user_can_read() -> None:
    text = starter_spec()
    assert text.endswith("\n")
    assert not text.endswith("\n\n")
    assert "{{" not in text
    assert "{%" not in text
    assert isinstance(yaml.safe_load(text), dict)
    assert max(len(line) for line in text.splitlines()) <= 110


def test_a_missing_folder_is_an_output_error(tmp_path: Path) -> None:
    refused = catanc("init", "--out", os.fspath(tmp_path / "no" / "x.yaml"), cwd=tmp_path)
    assert refused.returncode == ExitCode.OUTPUT
    assert "no such folder" in refused.stderr
