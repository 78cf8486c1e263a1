"""Inputs made to break catanc (issue 31, item 6): each is a compiler-style error or a no-op, never a crash.

Specs and runtime tables that are huge, nested a thousand levels deep, not files at all (a FIFO,
/dev/zero, a folder), or hold absurd numbers; and the staging folder a compile killed mid-write
leaves behind, which the next compile of the same folder removes.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from catanc.artifacts.output import write
from catanc.cli import app
from catanc.errors import ExitCode

runner = CliRunner()

SMALL = """\
catan: 1
app: tiny
nodes:
  a: {compute_ms: COMPUTE}
  b: {compute_ms: COMPUTE}
edges: [[a, b]]
subchains: {s: [a, b]}
objective: [{chain: [a, b], weight: 1}]
"""


def run(*argv: str) -> tuple[int, str]:
    result = runner.invoke(app, list(argv))
    return result.exit_code, result.output


@pytest.mark.parametrize("compute", ["1e308", "1.0e+308", "1.0e+300", "{modes: [{share: 1, ms: 1.0e+308}]}"])
def test_an_absurd_compute_time_is_a_compiler_style_error(tmp_path: Path, compute: str) -> None:
    spec = tmp_path / "spec.yaml"
    spec.write_text(SMALL.replace("COMPUTE", compute))
    for command in (["validate", str(spec)], ["compile", str(spec), "-k", "1", "--out", str(tmp_path / "out")]):
        code, output = run(*command)
        assert code == ExitCode.BAD_INPUT, output
        assert f"{spec}:4:" in output
        assert "internal error" not in output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("nesting", "line"),
    [
        ("nodes: " + "[" * 1000 + "]" * 1000, 3),
        ("nodes:\n" + "".join("  " * (i + 1) + f"k{i}:\n" for i in range(400)), 3 + 64),  # where level 65 opens
        ("nodes: " + "{a: " * 1000 + "1" + "}" * 1000, 3),
    ],
)
def test_yaml_nested_a_thousand_levels_is_a_compiler_style_error(tmp_path: Path, nesting: str, line: int) -> None:
    spec = tmp_path / "deep.yaml"
    spec.write_text("catan: 1\napp: deep\n" + nesting + "\n")
    code, output = run("validate", str(spec))
    assert code == ExitCode.BAD_INPUT, output
    assert "nested deeper than 64 levels" in output
    assert output.startswith(f"{spec}:{line}:")


def test_a_runtime_table_nested_a_thousand_levels_is_an_error(tmp_path: Path) -> None:
    table = tmp_path / "runtime.json"
    table.write_text("[" * 100_000 + "]" * 100_000)
    code, output = run("run", str(table), "--no-rt", "--duration", "1")
    assert code == ExitCode.BAD_INPUT, output
    assert "internal error" not in output


def test_a_spec_or_table_bigger_than_the_limit_is_refused_unread(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    with big.open("wb") as out:
        out.truncate(64 * 1024 * 1024)  # sparse: 64 MiB of nothing, read by no one
    code, output = run("validate", str(big))
    assert code == ExitCode.BAD_INPUT
    assert "67108864 bytes; at most 4194304 are read" in output
    code, output = run("run", str(big), "--no-rt", "--duration", "1")
    assert code == ExitCode.BAD_INPUT
    assert "at most 16777216 are read" in output


def test_a_fifo_a_device_or_a_folder_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "spec.fifo"
    os.mkfifo(fifo)
    for path, what in ((fifo, "not a regular file"), (Path("/dev/zero"), "not a regular file"), (tmp_path, "a folder")):
        for command in (["validate", str(path)], ["run", str(path), "--no-rt", "--duration", "1"]):
            # A subprocess with a timeout: reading a FIFO nobody writes would block for ever.
            finished = subprocess.run(
                [sys.executable, "-m", "catanc", *command], capture_output=True, text=True, timeout=60, check=False
            )
            assert finished.returncode == ExitCode.BAD_INPUT, finished.stderr
            assert what in finished.stderr
            assert "Traceback" not in finished.stderr


def test_a_compile_killed_mid_write_leaves_no_staging_folder_after_the_next(tmp_path: Path) -> None:
    out = tmp_path / "cores-1"
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True
    )
    dead_pid = int(dead.stdout)  # exited: its pid names no process (reuse within the test is unlikely)
    killed = tmp_path / f".cores-1.{dead_pid}.abc123.partial"
    killed.mkdir()
    (killed / "runtime.json").write_text("{half")
    swapping = tmp_path / f".cores-1.{dead_pid}.def456.partial.old"
    swapping.mkdir()
    running = tmp_path / f".cores-1.{os.getpid()}.ghi789.partial"  # a compile still going on: left alone
    running.mkdir()
    older = tmp_path / ".cores-1.zzz.partial"  # not named by a catanc that says its pid: left alone
    older.mkdir()
    other = tmp_path / f".cores-2.{dead_pid}.abc123.partial"  # another folder's: left alone
    other.mkdir()
    write(out, {"PLAN.md": "a plan\n"})
    assert (out / "PLAN.md").read_text() == "a plan\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["cores-1", running.name, older.name, other.name])
