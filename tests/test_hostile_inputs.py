"""Inputs made to break catanc (issue 31, item 6): each is a compiler-style error or a no-op, never a crash.

Specs and runtime tables that are huge, nested a thousand levels deep, not files at all (a FIFO,
/dev/zero, a folder), or hold absurd numbers; and the staging folder a compile killed mid-write
leaves behind, which the next compile of the same folder removes.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

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
