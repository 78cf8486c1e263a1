"""``catanc explain > plan.txt``: a file that reads well in an 80-column editor (no line wider, no word cut
short to fit) and says every warning."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]
EXAMPLES = sorted((ROOT / "specs").glob("*.yaml"))
MAX_COLUMNS = 80

# A spec warning (an empty objective) and a planner warning (bounds that cannot all be met: a chain of
# 30 ms of compute bounded to 20 ms), so the warnings check below has warnings to find.
WARNED = """catan: 1
app: warned
nodes:
  a: {compute_ms: 10}
  b: {compute_ms: 20}
edges: [[a, b]]
subchains: {A: [a], B: [b]}
constraints:
  - {chain: [a, b], max_response_ms: 20}
"""


def explain_to_file(spec: Path, cores: int, tmp_path: Path, *extra: str) -> tuple[str, str]:
    """``catanc explain SPEC -k K > report.txt`` in a fresh process: the file's text and stderr."""
    report = tmp_path / f"{spec.stem}-{cores}.txt"
    with report.open("wb") as stdout:
        finished = subprocess.run(
            [sys.executable, "-m", "catanc", "explain", str(spec), "-k", str(cores), *extra],
            stdout=stdout,
            stderr=subprocess.PIPE,
            text=False,
            check=False,
        )
    assert finished.returncode == 0, finished.stderr.decode()
    return report.read_text(encoding="utf-8"), finished.stderr.decode()


def squeezed(text: str) -> str:
    """Words in order, whatever the wrapping (a long warning wraps over several lines)."""
    return re.sub(r"\s+", " ", text)


def warnings_on(stderr: str) -> list[str]:
    """What each ``warning:`` line on stderr says, after its place."""
    return [line.split("warning: ", 1)[1] for line in stderr.splitlines() if "warning: " in line]


def check_report(text: str, stderr: str) -> None:
    wide = [line for line in text.splitlines() if len(line) > MAX_COLUMNS]
    assert wide == [], f"{len(wide)} lines over {MAX_COLUMNS} columns, the first: {wide[0]!r}" if wide else ""
    cut = [line for line in text.splitlines() if "\u2026" in line]  # rich's ellipsis: a word cut to fit
    assert cut == [], f"{len(cut)} lines with a word cut short, the first: {cut[0]!r}" if cut else ""
    section = squeezed(text[text.index("5. Warnings") : text.index("6. Baseline")])
    for warning in warnings_on(stderr):
        assert squeezed(warning) in section, warning


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("spec", EXAMPLES, ids=lambda path: path.stem)
def test_every_example_fits_80_columns_and_reports_every_warning(spec: Path, cores: int, tmp_path: Path) -> None:
    text, stderr = explain_to_file(spec, cores, tmp_path)
    assert text.startswith(spec.stem)
    check_report(text, stderr)


@pytest.mark.parametrize("cores", [1, 2])
def test_spec_and_planner_warnings_are_on_stderr_and_in_the_report(tmp_path: Path, cores: int) -> None:
    spec = tmp_path / "warned.yaml"
    spec.write_text(WARNED)
    text, stderr = explain_to_file(spec, cores, tmp_path)
    found = warnings_on(stderr)
    assert any(w.startswith("objective: the objective is empty") for w in found), stderr
    assert any("the bounds cannot all be met" in w for w in found), stderr
    check_report(text, stderr)
    assert "(spec line " in text  # the spec's warning says where, without the spec's path


def test_width_sets_the_layout(tmp_path: Path) -> None:
    spec = ROOT / "specs" / "nav2d.yaml"
    narrow, _ = explain_to_file(spec, 1, tmp_path, "--width", "60")
    wide, _ = explain_to_file(spec, 1, tmp_path, "--width", "180")
    assert max(len(line) for line in narrow.splitlines()) <= 60
    assert max(len(line) for line in wide.splitlines()) > 100  # the tables spread out when there is room
    assert squeezed(re.sub(r"[^\w.%>-]+", " ", narrow)).count("135.75") == squeezed(
        re.sub(r"[^\w.%>-]+", " ", wide)
    ).count("135.75")


def test_plural_words_are_right(tmp_path: Path) -> None:
    text, _ = explain_to_file(ROOT / "specs" / "face_tracking.yaml", 1, tmp_path)
    assert "3. Chains (1)" in text
    assert not re.search(r"\b1 (subchains|chains|cores|threads|terms|nodes)\b", text)


def test_compile_prints_the_specs_warnings_and_plan_md_holds_them(tmp_path: Path) -> None:
    spec = tmp_path / "warned.yaml"
    spec.write_text(WARNED)
    finished = subprocess.run(
        [sys.executable, "-m", "catanc", "compile", str(spec), "-k", "1", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert finished.returncode == 0, finished.stderr
    plan_md = squeezed((tmp_path / "o" / "PLAN.md").read_text())
    found = warnings_on(finished.stderr)
    assert any(w.startswith("objective: the objective is empty") for w in found), finished.stderr
    for warning in found:
        assert squeezed(warning) in plan_md, warning
