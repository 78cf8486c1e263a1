"""``catanc report`` (catanc.control.run_summary, log_report, log_timeline) on hand-made logs, hand-worked numbers.

The main log: subchain ``a`` planned at 5 Hz (200 ms) completes 10 runs in
the first 2 s; a re-plan at t = 3 s sets it to 10 Hz (100 ms) and it
completes 10 more runs in [3, 4); the run stops at t = 4 s.  So ``a`` ran
20 times in 4 s (5 Hz) and 10 times in the 1 s since the last plan (10 Hz).
Its latencies are 1, 2, ..., 20 ms: mean 10.5, p95 at rank h = 19 * 0.95 =
18.05, i.e. 19 + 0.05 * (20 - 19) = 19.05.  Node ``n`` measured 1..5 ms and
once nothing: p95 at h = 4 * 0.95 = 3.8, i.e. 4 + 0.8 * (5 - 4) = 4.8.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from catanc.control.run_summary import PlannedRate, ResolveSummary, Stats, rate_bins, stats, summarise
from catanc.errors import OutputError, UsageError
from catanc.runtime.logs.report import load_events, render_summary, report_command, summary_json
from catanc.runtime.logs.timeline import plot_timeline
from catanc.runtime.logs.writer import RunLog

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def plan(objective: float, periods: dict[str, float], cores: int = 1) -> dict[str, Any]:
    return {
        "objective": objective,
        "cores": cores,
        "subchains": {name: {"cores": [0], "shared": True, "period_ms": p} for name, p in periods.items()},
    }


def counters(late: int, lost: int, steals: int, skipped: int) -> dict[str, Any]:
    return {
        "subchains": {
            "a": {
                "planned_hz": 5.0,
                "measured_hz": 5.0,
                "compute_p95_ms": 1.0,
                "late": late,
                "lost": lost,
                "steals": steals,
                "skipped": skipped,
                "registered": True,
            }
        },
        "last_resolve_s": None,
        "since_resolve_s": None,
    }


def main_log(*, stopped: bool = True) -> list[dict[str, Any]]:
    events: list[dict[str, Any]] = [
        {"t": 0.0, "event": "start", "cores": 1, "plan": plan(10.0, {"a": 200.0, "b": 1000.0})},
        {"t": 0.01, "event": "register", "node": "n", "pid": 10, "tid": 11},
        {"t": 0.02, "event": "register", "node": "quiet", "pid": 12, "tid": 13},
    ]
    latencies = iter(range(1, 21))
    for i in range(10):  # 0.1, 0.3, ..., 1.9
        events.append({"t": round(0.1 + 0.2 * i, 6), "event": "run", "subchain": "a", "seq": i, "latency_ms": 0})
    for ms in (3.0, 1.0, 5.0, None, 2.0, 4.0):
        events.append({"t": 1.0, "event": "compute", "node": "n", "ms": ms, "reported_ms": ms, "kernel_ms": None})
    events.append({"t": 2.0, "event": "status", **counters(1, 0, 0, 0)})
    events.append(
        {
            "t": 3.0,
            "event": "resolve",
            "reason": "stage2",
            "stage1": False,
            "allocation_changed": False,
            "solve_ms": 1.5,
            "error": None,
            "compute_ms": {"n": 4.8},
            "plan": plan(8.0, {"a": 100.0, "b": 1000.0}),
        }
    )
    for i in range(10):  # 3.05, 3.15, ..., 3.95
        events.append({"t": round(3.05 + 0.1 * i, 6), "event": "run", "subchain": "a", "seq": 10 + i, "latency_ms": 0})
    events.append({"t": 3.5, "event": "lost", "subchain": "b", "seq": 1, "node": "n"})
    for event in events:
        if event["event"] == "run":
            event["latency_ms"] = float(next(latencies))
    if stopped:
        events.append({"t": 4.0, "event": "stop", "summary": counters(3, 2, 4, 5)})
    return events


def write_log(path: Path, events: list[dict[str, Any]]) -> Path:
    with RunLog(path) as log:  # the enforcer's own writer
        for event in events:
            fields = {k: v for k, v in event.items() if k not in ("t", "event")}
            log.write(event["event"], event["t"], fields)
    return path


# --------------------------------------------------------------------------- the numbers


def test_stats_worked_example() -> None:
    assert stats([3.0, 1.0, 5.0, 2.0, 4.0]) == Stats(count=5, mean_ms=3.0, p95_ms=4.8, min_ms=1.0, max_ms=5.0)
    assert stats([7.0]) == Stats(count=1, mean_ms=7.0, p95_ms=7.0, min_ms=7.0, max_ms=7.0)
    assert stats([]) is None


def test_subchain_rates_planned_rates_and_latency() -> None:
    summary = summarise(main_log())
    assert summary.length_s == 4.0
    assert summary.cores == 1
    assert summary.complete
    assert summary.last_plan_s == 3.0
    a, b = summary.subchains
    assert a.name == "a"
    assert a.runs == 20
    assert a.measured_hz == pytest.approx(5.0)  # 20 runs in 4 s
    assert a.last_plan_hz == pytest.approx(10.0)  # 10 runs in the 1 s since the re-plan at t = 3
    assert a.planned == (PlannedRate(0.0, 200.0), PlannedRate(3.0, 100.0))
    assert [p.hz for p in a.planned] == [5.0, 10.0]
    assert a.latency is not None
    assert a.latency.count == 20
    assert a.latency.mean_ms == pytest.approx(10.5)
    assert a.latency.p95_ms == pytest.approx(19.05)
    assert (a.latency.min_ms, a.latency.max_ms) == (1.0, 20.0)
    assert (a.late, a.lost, a.steals, a.skipped) == (3, 2, 4, 5)  # the stop's counters, not the earlier status's
    assert len(a.run_times_s) == 20
    # b never ran, kept its 1 Hz through the re-plan (one entry), and is not in the status rows
    assert b.name == "b"
    assert (b.runs, b.measured_hz, b.last_plan_hz, b.latency) == (0, 0.0, 0.0, None)
    assert b.planned == (PlannedRate(0.0, 1000.0),)
    assert (b.late, b.lost, b.steals, b.skipped) == (None, None, None, None)


def test_nodes_and_resolves() -> None:
    summary = summarise(main_log())
    n, quiet = summary.nodes
    assert n.name == "n"
    assert n.compute == Stats(count=5, mean_ms=3.0, p95_ms=4.8, min_ms=1.0, max_ms=5.0)
    assert n.unmeasured == 1
    assert len(n.samples) == 5
    assert quiet.name == "quiet"  # registered, never measured
    assert (quiet.compute, quiet.unmeasured) == (None, 0)
    assert summary.resolves == (
        ResolveSummary(
            t_s=3.0,
            reason="stage2",
            stage1=False,
            allocation_changed=False,
            solve_ms=1.5,
            objective=8.0,
            error=None,
        ),
    )


def test_killed_run_uses_last_event_and_last_status() -> None:
    summary = summarise(main_log(stopped=False))
    assert not summary.complete
    assert summary.length_s == 3.95  # the last run
    a = summary.subchains[0]
    assert a.measured_hz == pytest.approx(20 / 3.95)
    assert a.last_plan_hz == pytest.approx(10 / 0.95)
    assert (a.late, a.lost, a.steals, a.skipped) == (1, 0, 0, 0)  # the status at t = 2


def test_allocation_change_failed_replan_and_junk_events() -> None:
    events: list[Any] = [
        {"t": 0.0, "event": "start", "cores": 2, "plan": plan(1.0, {"x": 50.0}, cores=2)},
        {
            "t": 1.0,
            "event": "resolve",
            "reason": "reallocate",
            "stage1": True,
            "allocation_changed": True,
            "solve_ms": 40.0,
            "error": None,
            "compute_ms": {},
            "plan": plan(2.0, {"x": 25.0}, cores=2),
        },
        {
            "t": 2.0,
            "event": "resolve",
            "reason": "stage2",
            "stage1": False,
            "allocation_changed": False,
            "solve_ms": 3.0,
            "error": "ValueError: bad",
            "compute_ms": {},
            "plan": plan(2.0, {"x": 25.0}, cores=2),
        },
        5,
        {"event": "run", "subchain": "x"},  # no time
        {"t": "soon", "event": "run", "subchain": "x"},
        {"t": 2.5, "event": "run", "subchain": "x", "seq": 1, "latency_ms": None},
        {"t": 2.5, "event": "compute", "node": "m", "ms": float("nan")},
    ]
    summary = summarise(events)
    assert summary.cores == 2
    assert summary.length_s == 2.5
    (x,) = summary.subchains
    assert x.runs == 1
    assert x.latency is None
    assert [p.hz for p in x.planned] == [20.0, 40.0]  # the failed re-plan kept 25 ms: no new step
    assert x.last_plan_hz == pytest.approx(1 / 0.5)
    assert [(r.stage1, r.allocation_changed, r.error) for r in summary.resolves] == [
        (True, True, None),
        (False, False, "ValueError: bad"),
    ]
    assert summary.nodes[0].unmeasured == 1


def test_rate_bins() -> None:
    times = [e["t"] for e in main_log() if e["event"] == "run"]
    assert rate_bins(times, 4.0) == ((0.0, 5.0), (1.0, 5.0), (2.0, 0.0), (3.0, 10.0))
    # a shorter last bin counts over its own width; the end time falls in it; outside times do not count
    assert rate_bins([0.5, 1.2, 1.5, 1.5, -1.0, 9.0], 1.5) == ((0.0, 1.0), (1.0, 6.0))
    assert rate_bins([0.1], 0.0) == ()


# --------------------------------------------------------------------------- output


def test_json_is_deterministic_and_rounded() -> None:
    text = summary_json(summarise(main_log()))
    assert text == summary_json(summarise(main_log()))
    assert text.endswith("}\n")
    data = json.loads(text)
    assert text == json.dumps(data, indent=2, sort_keys=True) + "\n"
    a = data["subchains"]["a"]
    assert a["runs"] == 20
    assert a["measured_hz"] == 5.0
    assert a["last_plan_hz"] == 10.0
    assert a["planned"] == [
        {"t_s": 0.0, "period_ms": 200.0, "hz": 5.0, "as_run_hz": None},
        {"t_s": 3.0, "period_ms": 100.0, "hz": 10.0, "as_run_hz": None},
    ]
    assert a["latency_ms"] == {"count": 20, "mean": 10.5, "p95": 19.05, "min": 1.0, "max": 20.0}
    assert (a["late"], a["lost"], a["steals"], a["skipped"]) == (3, 2, 4, 5)
    assert data["nodes"]["n"] == {
        "compute_ms": {"count": 5, "mean": 3.0, "p95": 4.8, "min": 1.0, "max": 5.0},
        "unmeasured": 1,
    }
    assert data["nodes"]["quiet"] == {"compute_ms": None, "unmeasured": 0}
    assert data["resolves"] == [
        {
            "t_s": 3.0,
            "reason": "stage2",
            "stage1": False,
            "allocation_changed": False,
            "solve_ms": 1.5,
            "objective": 8.0,
            "error": None,
        }
    ]
    assert (data["length_s"], data["cores"], data["complete"], data["last_plan_s"]) == (4.0, 1, True, 3.0)
    assert "run_times_s" not in text
    assert "samples" not in text


def render(tables: tuple[Any, ...]) -> str:
    console = Console(file=io.StringIO(), width=200, highlight=False)
    for table in tables:
        console.print(table)
    output = console.file
    assert isinstance(output, io.StringIO)
    return output.getvalue()


def test_tables() -> None:
    tables = render_summary(summarise(main_log()))
    assert len(tables) == 3
    text = render(tables)
    assert "catanc report: 4.0 s on 1 core, 1 re-plan" in text
    assert "cut short" not in text
    row_a = next(line for line in text.splitlines() if line.startswith("│ a "))
    for cell in ("20", "5.00", "10.00", "5.00 -> 10.00", "10.500", "19.050", "20.000"):
        assert f" {cell} " in row_a
    row_n = next(line for line in text.splitlines() if line.startswith("│ n "))
    for cell in ("5", "3.000", "4.800", "1.000", "5.000", "1"):
        assert f" {cell} " in row_n
    assert "stage2" in text


def test_tables_without_an_executor_have_no_as_run_column() -> None:
    assert "as run Hz" not in render(render_summary(summarise(main_log())))


def with_rates_as_run(events: list[dict[str, Any]], rates: list[dict[str, float]]) -> list[dict[str, Any]]:
    """``events`` with each plan's subchains given the rates as run in ``rates`` (one mapping per plan, in order)."""
    plans = iter(rates)
    for event in events:
        if "plan" in event:
            for name, hz in next(plans).items():
                event["plan"]["subchains"][name]["rate_as_run_hz"] = hz
    return events


def test_rates_as_run_are_the_plans_promises(tmp_path: Path) -> None:
    # a: 5 Hz planned of which an executor's thread leaves 4, then 10 Hz leaving 8; b: 1 Hz planned, then
    # (its period unchanged) 0.9 Hz as run, a step of its own; an unreadable rate as run counts as none.
    events = with_rates_as_run(main_log(), [{"a": 4.0}, {"a": 8.0, "b": 0.9}])
    events[0]["plan"]["subchains"]["b"]["rate_as_run_hz"] = "fast"
    summary = summarise(events)
    a, b = (next(sub for sub in summary.subchains if sub.name == name) for name in ("a", "b"))
    assert a.planned == (PlannedRate(0.0, 200.0, 4.0), PlannedRate(3.0, 100.0, 8.0))
    assert [p.expected_hz for p in a.planned] == [4.0, 8.0]
    assert b.planned == (PlannedRate(0.0, 1000.0), PlannedRate(3.0, 1000.0, 0.9))
    assert [p.expected_hz for p in b.planned] == [1.0, 0.9]
    assert json.loads(summary_json(summary))["subchains"]["a"]["planned"][1]["as_run_hz"] == 8.0
    text = render(render_summary(summary))
    assert " as run Hz " in text
    row_a = next(line for line in text.splitlines() if line.startswith("│ a "))
    assert " 5.00 -> 10.00 │ 4.00 -> 8.00 " in row_a
    row_b = next(line for line in text.splitlines() if line.startswith("│ b "))
    assert " 1.00 │ 1.00 -> 0.90 " in row_b
    plot_timeline(summary, tmp_path / "timeline.png")  # with the promised rates' own line
    assert (tmp_path / "timeline.png").read_bytes().startswith(PNG_SIGNATURE)


def test_tables_of_a_killed_run_without_replans() -> None:
    events = [e for e in main_log(stopped=False) if e["event"] != "resolve"]
    tables = render_summary(summarise(events))
    assert len(tables) == 2  # no re-plan table
    assert "(no stop event: the run was cut short)" in render(tables)


# --------------------------------------------------------------------------- the plot


def test_plot_is_a_png(tmp_path: Path) -> None:
    path = tmp_path / "timeline.png"
    plot_timeline(summarise(main_log()), path)
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    assert len(data) > 10_000
    from PIL import Image

    with Image.open(path) as image:
        image.verify()
        assert image.format == "PNG"
        assert image.size[0] >= 800
        assert image.size[1] >= 600


def test_plot_of_a_log_with_no_runs_or_samples(tmp_path: Path) -> None:
    path = tmp_path / "empty.png"
    plot_timeline(summarise([{"t": 0.0, "event": "start", "cores": 1, "plan": plan(0.0, {})}]), path)
    assert path.read_bytes().startswith(PNG_SIGNATURE)


def test_plot_to_a_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="cannot write the plot"):
        plot_timeline(summarise(main_log()), tmp_path / "no" / "such" / "plot.png")


def test_matplotlib_is_imported_only_to_plot() -> None:
    code = (
        "import sys, catanc.runtime.logs.report, catanc.runtime.enforcer.run, catanc.client, catanc.cli\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib was imported'\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr


# --------------------------------------------------------------------------- the command


def test_command_json_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_log(tmp_path / "run.jsonl", main_log())
    plot = tmp_path / "run.png"
    report_command(log, plot, as_json=True)
    out, err = capsys.readouterr()
    assert out == summary_json(summarise(main_log()))
    assert f"plot: {plot}" in err
    assert plot.read_bytes().startswith(PNG_SIGNATURE)


def test_command_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_log(tmp_path / "run.jsonl", main_log())
    report_command(log, None, as_json=False)
    out, _ = capsys.readouterr()
    assert "catanc report: 4.0 s on 1 core" in out
    assert "compute times (ms)" in out


def test_torn_last_line_is_skipped(tmp_path: Path) -> None:
    log = write_log(tmp_path / "run.jsonl", main_log(stopped=False))
    with log.open("a", encoding="utf-8") as file:
        file.write('{"event": "run", "latency_ms": 1.0, "seq": 99, "subch')  # a killed enforcer's last write
    events = load_events(log)
    assert len(events) == len(main_log(stopped=False))
    assert summarise(events).subchains[0].runs == 20


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "no events"),
        ("\n\n", "no events"),
        ('{"event": "run", "subch\n', "no events"),  # only a torn line
        ("[1, 2]\n5\n", "no events"),  # JSON, but not events
        (None, "no such log file"),
        (b"\xff\xfe\x00", "not UTF-8"),
    ],
)
def test_unusable_logs(tmp_path: Path, content: str | bytes | None, message: str) -> None:
    log = tmp_path / "run.jsonl"
    if isinstance(content, str):
        log.write_text(content, encoding="utf-8")
    elif isinstance(content, bytes):
        log.write_bytes(content)
    with pytest.raises(UsageError) as info:
        report_command(log, None, as_json=False)
    text = str(info.value)
    assert text.startswith(f"{log}: ")
    assert message in text
    assert "\n" not in text


def test_folder_is_not_a_log(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="is a folder"):
        load_events(tmp_path)
