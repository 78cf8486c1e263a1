"""``catanc explain``: the command, and what it says binds, dominates and warns on cases worked by hand."""

from __future__ import annotations

import io
import itertools
import json
import re
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console
from typer.testing import CliRunner

from catanc.cli import app
from catanc.errors import ExitCode, InfeasibleError
from catanc.explain.analysis import Explanation, SharedCoreView, explain_plan
from catanc.explain.blocks import (
    Block,
    Bullets,
    Column,
    Heading,
    Paragraph,
    Preformatted,
    TableBlock,
    _process_table,
    report_blocks,
    timeline_bar,
)
from catanc.explain.markdown import blocks_markdown, render_markdown
from catanc.explain.terminal import render
from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.model.problem import Problem
from catanc.planning.planner import plan
from catanc.planning.types import Plan
from tests.support.strategies import spec_of

ROOT = Path(__file__).parents[2]
SPECS = ROOT / "specs"
EXAMPLES = sorted(path.stem for path in SPECS.glob("*.yaml"))
runner = CliRunner()


@cache
def planned(name: str, cores: int) -> Plan:
    return plan(load_spec(SPECS / f"{name}.yaml"), cores)


def explained(text: str, cores: int) -> Explanation:
    spec = parse_spec(text)
    return explain_plan(spec, build_problem(spec), plan(spec, cores))


def flat(text: str) -> str:
    """Table output with the box drawing and runs of spaces squeezed out (cells wrap differently by width)."""
    return re.sub(r"\s+", " ", re.sub(r"[│┃┏┓┗┛┡┩└┘┌┐━─┳┻╇╈┼┬┴]", " ", text))


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("name", EXAMPLES)
def test_explain_shows_every_subchain_with_the_plans_numbers(name: str, cores: int) -> None:
    result = runner.invoke(app, ["explain", str(SPECS / f"{name}.yaml"), "-k", str(cores), "--width", "200"])
    assert result.exit_code == ExitCode.OK, result.output
    out = result.stdout
    expected = planned(name, cores)
    assert f"objective {expected.objective:.3f} ms" in out
    table = out[out.index("2. Subchains") : out.index("3. Chains")]
    placement, timing = table.split("Rates and slices")
    places = {line.split()[1]: line for line in placement.splitlines() if line.startswith("│ ")}
    rows = {line.split()[1]: line for line in timing.splitlines() if line.startswith("│ ")}
    assert set(places) == set(rows) == set(expected.subchains)
    for sub in expected.subchains.values():
        row = flat(rows[sub.name])
        assert f" {1000 / sub.period_ms:.2f} {sub.period_ms:.3f} " in row
        assert row.endswith(f" {sub.latency_ms:.3f} ")
        # docs/explanation/model.md section 6: shared threads rest at SCHED_FIFO 1, run their slice at 2; dedicated 2.
        assert flat(places[sub.name]).endswith(" shared 1->2 " if sub.shared else " dedicated 2->2 ")
    for core in expected.shared_cores:
        assert f"core {core.core}: shared by {len(core.order)} subchain" in out
        assert f"T = {core.period_ms:.3f} ms" in out
    for chain in expected.chains[:12]:
        assert f"{chain.response_ms:.3f}" in out
    for section in ("1. Cores", "2. Subchains", "3. Chains", "4. What binds", "5. Warnings", "6. Baseline"):
        assert section in out


@pytest.mark.parametrize("name", EXAMPLES)
def test_json_has_the_runtime_tables_shape(name: str) -> None:
    result = runner.invoke(app, ["explain", str(SPECS / f"{name}.yaml"), "--cores", "1", "--json"])
    assert result.exit_code == ExitCode.OK, result.output
    payload = json.loads(result.stdout)
    assert payload["app"] == name
    assert payload["cores"] == 1
    table = payload["plan"]
    assert {"objective", "constraint_scale", "subchains", "cores", "chains"} <= set(table)
    assert set(table["subchains"]) == set(planned(name, 1).subchains)
    assert table["objective"] == pytest.approx(planned(name, 1).objective, abs=1e-5)


def test_vr_timewarps_fixed_rate_binds() -> None:
    # The spec fixes Timewarp at vsync (120 Hz): whatever else the plan does, that rate binds, and
    # the schedule period is locked to it (T = 8.333 ms / k, docs/explanation/model.md section 4).
    explanation = explain_plan(load_spec(SPECS / "vr_illixr.yaml"), *_problem_and_plan("vr_illixr", 1))
    kinds = {(b.kind, b.subject) for b in explanation.bindings}
    assert ("fixed rate", "timewarp") in kinds
    result = planned("vr_illixr", 1)
    (core,) = result.shared_cores
    assert core.period_ms * result.every["timewarp"] == pytest.approx(1000 / 120, rel=1e-9)
    # Render runs whole in every period of 8.333 ms: at its 120 Hz cap, which binds.
    assert result.every["render"] == 1
    assert core.period_ms == pytest.approx(1000 / 120, rel=1e-9)
    assert ("rate cap", "render") in kinds
    # VIO (11.5 ms a run) takes one run every 4 periods: a 2.875 ms slice, above the 1 ms minimum.
    vio = result.subchains["vio"]
    assert vio.fraction == pytest.approx(1 / 4)
    assert ("minimum slice", "vio") not in kinds


def test_nav2d_one_core_gl_cap_binds() -> None:
    # nav2d on one core: GL would run faster than the simulator's 50 Hz (its weight 0.5 on its period
    # pulls it down), so its cap binds, as does GP's 1 Hz cap (GM and GP share the core with it).
    result = runner.invoke(app, ["explain", str(SPECS / "nav2d.yaml"), "-k", "1"])
    assert result.exit_code == ExitCode.OK, result.output
    text = flat(result.stdout)
    assert "rate cap GL period 20.000 ms = its cap of 50 Hz" in text
    # GP is triggered at its slot every k periods: the fewest whose length reaches its 1 Hz cap.
    nav2d = planned("nav2d", 1)
    (core,) = nav2d.shared_cores
    every = nav2d.every["GP"]
    assert every * core.period_ms >= 1000 * (1 - 1e-9) > (every - 1) * core.period_ms
    assert f"rate cap GP period {every * core.period_ms:.3f} ms = {every} periods, the fewest at or above" in text


def _problem_and_plan(name: str, cores: int) -> tuple[Problem, Plan]:
    spec = load_spec(SPECS / f"{name}.yaml")
    return build_problem(spec), planned(name, cores)


# One subchain on one core (Eq. 1: latency c, period c / (1 - slack), the slack 0 here). A chain
# bound of 15 ms cannot hold (R = 2c = 20 ms), so every bound is scaled by 20/15 and the scaled
# bound binds.
ALONE = """
catan: 1
app: alone
nodes: {a: {compute_ms: 10}, out: {scheduled: false}}
edges: [[a, out]]
subchains: {A: [a]}
objective: [{chain: [a, out], weight: 1}]
constraints: [{chain: [a, out], max_response_ms: 15}]
schedule: {slack: 0}
"""


def test_a_scaled_chain_bound_binds_and_is_warned_about() -> None:
    explanation = explained(ALONE, 1)
    assert explanation.constraint_scale == pytest.approx(20 / 15, rel=1e-5)
    assert [(b.kind, b.subject) for b in explanation.bindings] == [("chain bound", "a -> out")]
    assert any("scaled by 1.333" in note for note in explanation.warnings)


def test_a_batch_rate_floor_binds(tmp_path: Path) -> None:
    # One core: A (2 ms) carries the weight; B (10 ms, batch) must run at >= 50 Hz. With whole runs
    # for A (f = 1) and switches 2 x 0.12 ms, T = (2 + 10 f + 0.24) / 0.95 and B's period T / f <= 20:
    # the smallest T takes f = 2.24 / 9, where B's period is exactly 20 ms: the floor binds.
    text = """
catan: 1
app: floor
nodes: {a: {compute_ms: 2}, b: {compute_ms: 10, batch: true}, out: {scheduled: false}}
edges: [[a, out], [b, out]]
subchains: {A: [a], B: [b]}
objective: [{chain: [a, out], weight: 1}]
constraints: [{node: b, min_rate_hz: 50}]
"""
    explanation = explained(text, 1)
    kinds = {(b.kind, b.subject) for b in explanation.bindings}
    assert ("rate floor", "B") in kinds
    assert ("f <= 1", "A") in kinds
    b = next(s for s in explanation.subchains if s.name == "B")
    assert b.fraction == pytest.approx(2.24 / 9, rel=1e-5)
    # At its floor, B has no headroom: any growth of compute on core 0 misses it.
    assert any(note.startswith("core near saturation: B's rate floor") for note in explanation.warnings)
    path = tmp_path / "floor.yaml"
    path.write_text(text)
    result = runner.invoke(app, ["explain", str(path), "-k", "1"])
    assert result.exit_code == ExitCode.OK, result.output
    assert "rate floor B period 20.000 ms = its floor of 50 Hz" in flat(result.stdout)


# One core, A (4 ms) -> B (4.5 ms), A at >= 100 Hz. Whole runs each period are best (R = 4T), so
# T = (4 + 4.5 + 2 x 0.12) / 0.95 = 9.2 ms: 10 / 9.2 - 1 = 8.7% headroom on A's floor, and compute
# may grow by g with (8.5 g + 0.24) / 0.95 = 10, g = 9.26 / 8.5: 8.9%.
NEAR = """
catan: 1
app: near
nodes: {a: {compute_ms: 4}, b: {compute_ms: 4.5}, out: {scheduled: false}}
edges: [[a, b], [b, out]]
subchains: {A: [a], B: [b]}
objective: [{chain: [a, b, out], weight: 1}]
constraints: [{node: a, min_rate_hz: 100}]
"""


def test_near_saturation_names_the_core_and_the_growth(tmp_path: Path) -> None:
    explanation = explained(NEAR, 1)
    (item,) = explanation.headrooms
    assert item.value == pytest.approx(8.74 / 0.95)
    assert item.headroom == pytest.approx(10 / (8.74 / 0.95) - 1)
    assert item.growth == pytest.approx(9.26 / 8.5 - 1, rel=1e-6)
    assert item.cores == (0,)
    path = tmp_path / "near.yaml"
    path.write_text(NEAR)
    result = runner.invoke(app, ["explain", str(path), "-k", "1"])
    assert result.exit_code == ExitCode.OK, result.output
    assert (
        "core near saturation: A's rate floor (>= 100 Hz) has 8.7% headroom on core 0 "
        "(9.200 ms against 10.000 ms); compute times on core 0 may grow 8.9% before it is missed"
    ) in flat(result.stdout)
    # With a slower floor there is room enough: no warning.
    relaxed = explained(NEAR.replace("min_rate_hz: 100", "min_rate_hz: 90"), 1)
    assert not any("near saturation" in note for note in relaxed.warnings)


def test_dedicated_chain_bound_headroom() -> None:
    # A alone on its core: R = 2 x 9.5 = 19 ms against 20 ms: 5.3% headroom, and compute may grow 20/19.
    explanation = explained(ALONE.replace("compute_ms: 10", "compute_ms: 9.5").replace("15}", "20}"), 1)
    (item,) = explanation.headrooms
    assert item.value == pytest.approx(19)
    assert item.growth == pytest.approx(20 / 19 - 1, rel=1e-6)
    assert any("5.3% headroom on core 0" in note for note in explanation.warnings)


def test_timeline_segments_add_up_to_the_period() -> None:
    explanation = explain_plan(load_spec(SPECS / "nav2d.yaml"), *_problem_and_plan("nav2d", 1))
    (core,) = explanation.shared
    assert sum(segment.length_ms for segment in core.segments) == pytest.approx(core.period_ms)
    idle = core.segments[-1]
    assert idle.kind == "idle"
    assert idle.length_ms == pytest.approx(0.05 * core.period_ms)  # the 5% slack
    for before, after in itertools.pairwise(core.segments):
        assert after.offset_ms == pytest.approx(before.offset_ms + before.length_ms)
    bar = timeline_bar(core)
    assert len(bar) == 64
    assert [mark for mark in "ABCDE" if mark in bar] == list("ABCDE")  # every slice shows, even 1 ms in 7


def test_bar_gives_tiny_slices_a_character() -> None:
    from catanc.explain.analysis import Segment

    view = SharedCoreView(
        0,
        1000.0,
        ("big", "tiny"),
        (
            Segment("switch", "big", 0.0, 0.1),
            Segment("slice", "big", 0.1, 949.0),
            Segment("switch", "tiny", 949.1, 0.1),
            Segment("slice", "tiny", 949.2, 0.8),
            Segment("idle", None, 950.0, 50.0),
        ),
    )
    bar = timeline_bar(view, width=20)
    assert len(bar) == 20
    assert bar.count("B") == 1
    assert bar.endswith(".")


def test_no_baseline_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "near.yaml"
    path.write_text(NEAR)
    result = runner.invoke(app, ["explain", str(path), "-k", "1"])
    assert "Baseline: the spec has no baseline (baseline.rates_hz); nothing to compare with." in result.stdout


def test_overloaded_baseline_is_said_so() -> None:
    result = runner.invoke(app, ["explain", str(SPECS / "face_tracking.yaml"), "-k", "1"])
    assert result.exit_code == ExitCode.OK, result.output
    out = flat(result.stdout)
    assert "The baseline is overloaded" in out
    assert "utilisation 252.0%" in out  # 84 ms at 30 Hz on one core
    assert "objective (weighted sum)" in out


def test_bad_spec_exits_2_with_the_place(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(NEAR.replace("edges: [[a, b]", "edges: [[a, bb]"))
    result = runner.invoke(app, ["explain", str(path), "-k", "1"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert f"{path}:5:13: edges[0][1]: unknown node 'bb'" in result.stderr
    assert "Traceback" not in result.output
    assert runner.invoke(app, ["explain", str(path), "-k", "0"]).exit_code == ExitCode.BAD_INPUT
    assert runner.invoke(app, ["explain", str(path)]).exit_code == ExitCode.BAD_INPUT  # --cores is required


def test_infeasible_exits_with_its_code(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import catanc.planning.planner

    def infeasible(*args: object, **kwargs: object) -> Plan:
        raise InfeasibleError("near: no schedule exists for the shared cores, whatever the bounds")

    monkeypatch.setattr(catanc.planning.planner, "plan_problem", infeasible)
    path = tmp_path / "near.yaml"
    path.write_text(NEAR)
    for extra in ([], ["--json"]):
        result = runner.invoke(app, ["explain", str(path), "-k", "1", *extra])
        assert result.exit_code == ExitCode.INFEASIBLE
        assert "no schedule exists" in result.stderr


def test_stage1_options_pass_through() -> None:
    nav2d = str(SPECS / "nav2d.yaml")
    result = runner.invoke(app, ["explain", nav2d, "-k", "2", "--stage1", "milp", "--solver", "cbc", "--json"])
    assert result.exit_code == ExitCode.OK, result.output
    bad = runner.invoke(app, ["explain", nav2d, "-k", "2", "--stage1", "greedy"])
    assert bad.exit_code == ExitCode.BAD_INPUT
    assert "unknown Stage I method 'greedy'" in bad.stderr


def test_the_explain_modules_load_no_solver() -> None:
    code = (
        "import sys, catanc.explain.analysis, catanc.artifacts.runtime_table, catanc.planning.baseline\n"
        "heavy = sorted(m for m in ('cvxpy', 'pulp') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_many_chains_heaviest_first_then_a_count(tmp_path: Path) -> None:
    # 2 x 2 x 2 x 2 = 16 paths to `out`, each weighted 0.01; one of them also 1.0: it leads, 12 rows show.
    layers = [[f"{letter}{i}" for i in range(2)] for letter in "abcd"]
    nodes = "\n".join(f"  {n}: {{compute_ms: {1 + int(n[1])}}}" for layer in layers for n in layer)
    edges = ", ".join(f"[{a}, {b}]" for up, low in itertools.pairwise(layers) for a in up for b in low)
    subchains = ", ".join(f"{n.upper()}: [{n}]" for layer in layers for n in layer)
    path = tmp_path / "dense.yaml"
    path.write_text(
        f"catan: 1\napp: dense\nnodes:\n{nodes}\n  out: {{scheduled: false}}\n"
        f"edges: [{edges}, [d0, out], [d1, out]]\nsubchains: {{{subchains}}}\n"
        "objective: [{chain: [a1, b1, c1, d1, out], weight: 1}, {chains: {to: out}, weight: 0.01}]\n"
    )
    result = runner.invoke(app, ["explain", str(path), "-k", "1", "--width", "200"])
    assert result.exit_code == ExitCode.OK, result.output
    table = result.stdout[result.stdout.index("3. Chains (16") : result.stdout.index("4. What binds")]
    rows = [line for line in table.splitlines() if line.startswith("│ ")]
    assert len(rows) == 12
    assert flat(rows[0]).startswith(" a1 -> b1 -> c1 -> d1 -> out A1 -> B1 -> C1 -> D1 1.01 ")
    assert "... 4 more chains" in table


def test_the_allocation_note_compares_with_stage_ones_choice(tmp_path: Path) -> None:
    # nav2d on 2 cores without its deploy section (whose Navigator process keeps GP and NC on one core):
    # exact Stage II prefers another allocation than Stage I's estimate; the note gives both objectives and
    # the gain, which must match the plain two-stage plan planned alone.
    text = (SPECS / "nav2d.yaml").read_text()
    path = tmp_path / "nav2d.yaml"
    path.write_text(text[: text.index("\ndeploy:")] + "\n")
    spec = load_spec(path)
    assert [executor.name for executor in build_problem(spec).executors] == ["mapper"]
    paper = plan(spec, 2, runners_up=False)
    ours = plan(spec, 2)
    result = runner.invoke(app, ["explain", str(path), "-k", "2"])
    assert result.exit_code == 0, result.output
    text = flat(result.output)
    # GL and GM share a thread: plans are ranked, and compared here, by their objective as run.
    assert ours.objective_as_run is not None
    assert paper.objective_as_run is not None
    now, before = ours.objective_as_run, paper.objective_as_run
    lower = (before - now) / before
    assert f"objective as run {now:.3f} ms against {before:.3f} ms, {lower:.1%} lower" in text
    assert "Stage I's estimate chose" in text
    same = flat(runner.invoke(app, ["explain", str(SPECS / "vr_illixr.yaml"), "-k", "1"]).output)
    assert "no other allocation was planned" in same


def test_a_k_spaced_out_for_an_executor_is_not_called_a_rate_cap() -> None:
    # nav2d on 2 cores: Stage II triggers GM every k periods, more than its runs need, to free the thread
    # it shares with GL; GM has no rate cap (explain divided by its zero cap before, 2026-11-28).
    spec = load_spec(SPECS / "nav2d.yaml")
    result = plan(spec, 2)
    gm = result.subchains["GM"]
    assert gm.every is not None
    assert gm.every > round(1.0 / gm.fraction)  # spaced out beyond its runs: the trade
    text = flat(runner.invoke(app, ["explain", str(SPECS / "nav2d.yaml"), "-k", "2"]).output)
    assert f"GM period {gm.period_ms:.3f} ms = {gm.every} periods, more than its run needs" in text
    assert f"every {gm.every} periods ({gm.period_ms:.3f} ms, to free its executor's thread)" in text
    assert f"every {gm.every} periods ({gm.period_ms:.3f} ms, rate cap)" not in text


# --------------------------------------------------------------------------- Markdown (PLAN.md)

SECTIONS = ("1. Cores", "2. Subchains", "3. Chains", "4. What binds", "5. Warnings", "6. Baseline")


@dataclass(frozen=True)
class Report:
    name: str
    cores: int
    explanation: Explanation
    markdown: str
    terminal: str  # what `render` prints on a 200-column console


@pytest.fixture(scope="module", params=[(n, k) for n in EXAMPLES for k in (1, 2)], ids=lambda p: f"{p[0]}-{p[1]}")
def report(request: pytest.FixtureRequest) -> Report:
    name, cores = request.param
    explanation = explain_plan(load_spec(SPECS / f"{name}.yaml"), *_problem_and_plan(name, cores))
    console = Console(record=True, width=200, file=io.StringIO())
    for part in render(explanation):
        console.print(part)
    return Report(name, cores, explanation, render_markdown(explanation), console.export_text())


def unescape(text: str) -> str:
    """CommonMark's backslash escapes undone: the text a reader sees."""
    return re.sub(r"\\([!-/:-@\[-`{-~])", r"\1", text)


def cells(line: str) -> list[str]:
    """A pipe-table row's cells, split where GitHub splits them (at every unescaped ``|``)."""
    assert line.startswith("| ")
    assert line.endswith(" |")
    return [cell.strip() for cell in re.split(r"(?<!\\)\|", line[1:-1])]


def markdown_tables(markdown: str) -> list[list[list[str]]]:
    """Every table: its rows (header, alignment, body), each a list of cells."""
    tables: list[list[list[str]]] = []
    previous = ""
    fenced = False
    for line in markdown.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif line.startswith("|") and not fenced:
            if not previous.startswith("|"):
                tables.append([])
            tables[-1].append(cells(line))
        previous = line
    return tables


def sections(text: str, headings: list[str]) -> list[str]:
    """``text`` cut before each line that is one of ``headings``: the preamble, then one part per heading."""
    parts: list[list[str]] = [[]]
    for line in text.splitlines():
        if line in headings:
            parts.append([])
        parts[-1].append(line)
    assert len(parts) == len(headings) + 1, f"missing headings: {headings}"
    return ["\n".join(part) for part in parts]


NUMERIC = re.compile(r"-|\d[\d.,/]*[%x]?")


def test_markdown_is_a_well_formed_reproducible_document(report: Report) -> None:
    markdown = report.markdown
    # Byte for byte the same from a fresh plan: `--check` compares it.
    spec = load_spec(SPECS / f"{report.name}.yaml")
    assert render_markdown(explain_plan(spec, build_problem(spec), plan(spec, report.cores))) == markdown
    assert render_markdown(report.explanation) == markdown
    assert "\r" not in markdown
    assert markdown.endswith("\n")
    assert not markdown.endswith("\n\n")
    assert "\n\n\n" not in markdown
    lines = markdown.splitlines()
    assert lines[0].startswith(f"**{report.name} on {report.cores} core")
    assert [line for line in lines if line != line.rstrip()] == []
    headings = [line for line in lines if line.startswith("#")]
    expected = SECTIONS + (("7. Processes",) if report.explanation.processes else ())  # with a deploy section
    assert len(headings) == len(expected)
    assert all(h.startswith(f"## {s}") for h, s in zip(headings, expected, strict=True))
    # Each shared core's timeline bar sits in a fenced block with its legend (it is made of `|`, `.` and letters).
    fenced = [lines[i + 1] for i, line in enumerate(lines) if line == "```" and lines[i + 3] == "```"]
    assert fenced == [timeline_bar(view) for view in report.explanation.shared]
    assert lines.count("```") == 2 * len(report.explanation.shared)
    tables = markdown_tables(markdown)
    assert len(tables) >= 4  # subchains, chains, objective terms, baseline (or binding constraints)
    for header, alignment, *body in tables:
        assert len(alignment) == len(header)
        assert all(len(row) == len(header) for row in body), header
        assert set(alignment) <= {"---", "---:"}
        for index, align in enumerate(alignment):
            column = [row[index] for row in body if row[index]]
            numeric = bool(column) and all(NUMERIC.fullmatch(cell) for cell in column)
            assert (align == "---:") == numeric, (header[index], column)
    # The subchain table holds each subchain's numbers, in its row.
    (subchains,) = [table for table in tables if table[0][:2] == ["subchain", "nodes"]]
    (timing,) = [table for table in tables if table[0][:2] == ["subchain", "rate Hz"]]
    places = {row[0]: row for row in subchains[2:]}
    rows = {row[0]: row for row in timing[2:]}
    chosen = planned(report.name, report.cores).subchains
    assert set(places) == set(rows) == set(chosen)
    for name, sub in chosen.items():
        place, row = places[name], rows[name]
        assert unescape(place[1]) == " -> ".join(sub.nodes)
        assert place[3:] == (["shared", "1->2"] if sub.shared else ["dedicated", "2->2"])
        assert row[1:3] == [f"{1000 / sub.period_ms:.2f}", f"{sub.period_ms:.3f}"]
        assert row[4] == ("-" if sub.every is None else str(sub.every))
        assert row[6:] == [f"{sub.latency_ms:.3f}"]


def test_markdown_says_what_the_terminal_says(report: Report) -> None:
    # Section by section, the same numbers (with repeats): nothing dropped, added or moved.
    headings = [line.removeprefix("## ") for line in report.markdown.splitlines() if line.startswith("## ")]
    number = re.compile(r"\d+(?:\.\d+)?")
    pairs = zip(
        sections(report.markdown, [f"## {h}" for h in headings]), sections(report.terminal, headings), strict=True
    )
    for markdown, terminal in pairs:
        assert Counter(number.findall(markdown)) == Counter(number.findall(terminal)), markdown.splitlines()[0]
    # Every warning, whole, as a list item.
    warnings = sections(report.markdown, [f"## {h}" for h in headings])[5].splitlines()[2:]
    if report.explanation.warnings:
        assert [unescape(line) for line in warnings] == [f"- {note}" for note in report.explanation.warnings]
    else:
        assert warnings == ["none"]


def test_markdown_escapes_what_would_become_markup() -> None:
    blocks: list[Block] = [
        Paragraph("2. _a_ b_c, 2*3 [x](y)", strong=True),
        Heading("1. Cores"),
        TableBlock(
            (Column("a|b"), Column("n", "right")),
            (("x | y", ""), ("<= 1", "2")),
            title="t",
            footer="- more",
        ),
        Preformatted("|AA..  (A a; | switch)  "),
        Bullets(("# not a heading", "two\nlines")),
    ]
    assert blocks_markdown(blocks) == (
        "**2\\. \\_a\\_ b_c, 2\\*3 [x\\](y)**\n"
        "\n"
        "## 1. Cores\n"
        "\n"
        "**t**\n"
        "\n"
        "| a\\|b | n |\n"
        "| --- | ---: |\n"
        "| x \\| y |  |\n"
        "| <= 1 | 2 |\n"
        "\n"
        "\\- more\n"
        "\n"
        "```\n"
        "|AA..  (A a; | switch)\n"
        "```\n"
        "\n"
        "- \\# not a heading\n"
        "- two lines\n"
    )
    with pytest.raises(ValueError, match="a row of 1 cells in a table of 2 columns"):
        TableBlock((Column("a"), Column("b")), (("x",),))


def test_explain_says_where_a_spec_turns_stealing_off() -> None:
    text = (SPECS / "vr_illixr.yaml").read_text()
    on = blocks_markdown(report_blocks(explained(text, 1)))
    off_text = text.replace("  priorities: {timewarp: 1", "  stealing: false\n  priorities: {timewarp: 1")
    off = blocks_markdown(report_blocks(explained(off_text, 1)))
    assert "Stealing order: timewarp > " in on
    assert "Stealing order" not in off
    assert "No stealing (schedule.stealing: false)" in off


# --------------------------------------------------------------------------- rates a driver offers

# The face tracking pipeline (c = 84 ms) on 2 dedicated cores: its free period is 58 / 0.95 = 61.053 ms
# (16.38 Hz, R = 145.053 ms); of the camera's 15 and 30 fps only 15 fits: R = 84 + 66.667 = 150.667 ms.
OFFERED_CAMERA = """\
catan: 1
app: offered
nodes: {camera: {compute_ms: 25}, detection: {compute_ms: 58}, planning: {compute_ms: 1}, motor: {scheduled: false}}
edges: [[camera, detection], [detection, planning], [planning, motor]]
subchains: {tracking: [camera, detection, planning]}
objective: [{chain: [camera, detection, planning, motor], weight: 1}]
constraints: [{node: camera, rate_hz: [15, 30]}]
"""


def test_explain_says_which_offered_rate_was_picked_and_what_a_free_rate_gives() -> None:
    explanation = explained(OFFERED_CAMERA, 2)
    (note,) = explanation.offered
    assert note == (
        "camera's driver offers 15, 30 Hz: the plan picked 15 Hz for subchain tracking, objective 150.667 ms; "
        "a free rate would plan 16.38 Hz, objective 145.053 ms (3.7% lower)."
    )
    assert note in render_markdown(explanation)
    # The picked rate is a fixed rate to the rest of the report: it binds as one.
    binding = [(b.kind, b.subject) for b in explanation.bindings if b.subject == "tracking"]
    assert binding == [("fixed rate", "tracking")]


def test_explain_says_when_no_offered_rate_fits() -> None:
    explanation = explained(OFFERED_CAMERA, 1)  # 84 / 0.95 = 88.421 ms a frame: slower than 15 Hz
    (note,) = explanation.offered
    assert "picked 15 Hz (none fits: planned at 11.31 Hz, the bounds scaled by 1.326)" in note
    assert any("none of the rates its driver offers (15, 30 Hz) can be met" in w for w in explanation.warnings)


# --------------------------------------------------------------------------- processes


def test_processes_are_shown_with_their_cores_level_and_threads() -> None:
    spec = load_spec(SPECS / "nav2d.yaml")
    problem = build_problem(spec)
    result = plan(spec, 3)
    explanation = explain_plan(spec, problem, result)
    rows = {row[0]: row for row in _process_table(explanation).rows}
    assert list(rows) == ["/Mapper", "/Navigator", "/Operator", "/scan_shim"]  # as runtime.json lists them
    for key, nodes in (("/Mapper", ["GL", "GM"]), ("/Navigator", ["GP", "NC"]), ("/Operator", ["LM", "LP"])):
        # By hand from the plan: the union of the nodes' subchains' cores, the highest resting level.
        subs = [result.subchains[problem.subchain_of(node).name] for node in nodes]
        cores = sorted({core for sub in subs for core in sub.cores})
        level = max(1 if sub.shared else 2 for sub in subs)
        assert rows[key][1:4] == (", ".join(nodes), ",".join(map(str, cores)), str(level))
    assert rows["/Mapper"][4].startswith("one executor (executors.mapper): no node names a callback group")
    assert rows["/Navigator"][4].startswith("one executor: no node names a callback group")
    assert rows["/scan_shim"][4] == "one scheduled node"
    text = flat(runner.invoke(app, ["explain", str(SPECS / "nav2d.yaml"), "-k", "3", "--width", "200"]).output)
    assert "7. Processes" in text
    assert "Process /Navigator runs GP, NC in one thread (never at once; no node names a callback group" in text
    assert "Executor mapper runs GL, GM, the nodes of process /Mapper in one thread" in text


@pytest.mark.parametrize(
    ("extra", "threads"),
    [
        ({"a": {"command": "python3 app.py"}}, "one executor: a Python process (python3): the interpreter lock"),
        (
            {
                "a": {"ros_node": "/a", "callback_group": "/a@Timer(1000)"},
                "b": {"ros_node": "/b", "callback_group": "/b@Timer(1000)"},
            },
            "may run at once: a, b name callback groups: a callback-isolated executor runs each group in a thread",
        ),
    ],
)
def test_a_process_says_why_its_nodes_are_one_executor_or_not(extra: dict[str, Any], threads: str) -> None:
    deploy: dict[str, Any] = {"a": {"process": "app", "command": "ros2 run demo app"}, "b": {"process": "app"}}
    for node, fields in extra.items():
        deploy[node] = deploy[node] | fields
    spec = spec_of(
        {
            "catan": 1,
            "app": "two",
            "nodes": {"a": {"compute_ms": 1.0}, "b": {"compute_ms": 2.0}},
            "subchains": {"A": ["a"], "B": ["b"]},
            "objective": [{"node": "a", "weight": 1.0}],
            "deploy": deploy,
        }
    )
    problem = build_problem(spec)
    (view,) = explain_plan(spec, problem, plan(spec, 1)).processes
    assert (view.key, view.nodes, view.cores) == ("app", ("a", "b"), (0,))
    assert view.threads.startswith(threads)
    assert (view.executor is not None) == threads.startswith("one executor")
