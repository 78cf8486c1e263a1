"""``catanc profile``'s command line: the diff on stdout, ``--write`` in place or not at all, ``--check`` for CI."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from catanc.cli import app
from catanc.errors import ExitCode
from tests.support.run_logs import SPEC, every_node, log_text

runner = CliRunner()


@pytest.fixture
def spec(tmp_path: Path) -> Path:
    path = tmp_path / "demo.yaml"
    path.write_text(SPEC)
    path.chmod(0o640)
    return path


def write_log(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "run.jsonl"
    path.write_text(text)
    return path


def test_write_then_check_round_trips(spec: Path, tmp_path: Path) -> None:
    log = write_log(tmp_path, log_text(*every_node(cam=[6.5] * 20)))
    check = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--check"])
    assert check.exit_code == ExitCode.DRIFT, check.output
    assert "nodes.cam.compute_ms: 5 ms planned, 6.5 ms measured (+30%, more than 15% off)" in check.stderr
    assert spec.read_text() == SPEC  # --check never writes
    assert check.stdout.startswith(f"--- a/{spec}\n+++ b/{spec}\n")
    assert "-  cam: {compute_ms: 5}          # camera shim\n+  cam: {compute_ms: 6.5}        # camera shim\n" in (
        check.stdout
    )
    written = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--write"])
    assert written.exit_code == ExitCode.OK, written.output
    assert spec.read_text() == SPEC.replace("{compute_ms: 5}          #", "{compute_ms: 6.5}        #")
    assert spec.stat().st_mode & 0o777 == 0o640
    again = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--check"])
    assert again.exit_code == ExitCode.OK, again.output
    assert again.stdout == ""


def test_tolerance_decides_the_check(spec: Path, tmp_path: Path) -> None:
    log = write_log(tmp_path, log_text(*every_node(cam=[5.5] * 20)))  # +10%
    loose = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--check"])
    assert loose.exit_code == ExitCode.OK, loose.output
    tight = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--check", "--tolerance", "0.05"])
    assert tight.exit_code == ExitCode.DRIFT


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (log_text(*every_node(), stop=False), "run.jsonl:4: truncated"),
        (log_text(*every_node(), fmt=None), "run.jsonl:1: log format missing"),
        (log_text(*every_node()[:2]), "demo.yaml:7:3: nodes.plan: no compute samples in"),
    ],
)
def test_a_bad_log_changes_nothing(spec: Path, tmp_path: Path, text: str, message: str) -> None:
    log = write_log(tmp_path, text)
    result = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--write"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert message in result.stderr
    assert "Traceback" not in result.output
    assert spec.read_text() == SPEC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.yaml", "run.jsonl"]  # no temporary left behind


def test_a_missing_log_is_named(spec: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["profile", str(tmp_path / "nope.jsonl"), "--spec", str(spec)])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert f"{tmp_path / 'nope.jsonl'}: no such log file" in result.stderr


def test_write_and_check_together_is_a_usage_error(spec: Path, tmp_path: Path) -> None:
    log = write_log(tmp_path, log_text(*every_node()))
    result = runner.invoke(app, ["profile", str(log), "--spec", str(spec), "--write", "--check"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "pick one" in result.stderr
