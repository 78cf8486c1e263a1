"""The enforcer's cost figures (catanc.runtime.enforcer.costs) and how `catanc report` shows them, worked by hand."""

from __future__ import annotations

import io
import json
from pathlib import Path

from rich.console import Console

from catanc.control.run_summary import summarise
from catanc.model.load import parse_spec
from catanc.runtime.enforcer.costs import Costs, measured_profile, planned_hops
from catanc.runtime.logs.report import render_summary, summary_payload
from catanc.spec.machine import MeasuredOn, RtLimit

NAV_LIKE = """catan: 1
app: nav
nodes:
  scan: {compute_ms: 0.2}
  LM: {compute_ms: 0.8}
  LP: {compute_ms: 0.5}
  GL: {compute_ms: 3}
edges: [[scan, LM], [LM, LP], [scan, GL]]
hops_ms: {"scan->LM": 1.0}
dispatch_ms: {scan: 2.4}
subchains: {local: [scan, LM, LP], GL: [GL]}
objective: [{chain: [scan, LM, LP], weight: 1}]
"""
_MACHINE = MeasuredOn(host="h", cpu=None, kernel="k", cpus=2)


def test_hops_are_kept_together_and_apart_by_kind() -> None:
    costs = Costs()
    for delay in (0.1, 0.3, 0.5):  # node to node, inside a subchain
        costs.hop(delay, True)
    for delay in (0.02, 0.04):  # heads' triggers to their starts
        costs.hop(delay, False)
    summary = costs.summary(1)
    # Together (what a slot pays): 0.02 0.04 0.1 0.3 0.5, p50 the middle one; p95 at rank 3.8: 0.3 + 0.8 * 0.2.
    assert summary["hop"] == {"p50_ms": 0.1, "p95_ms": 0.46, "max_ms": 0.5, "count": 5}
    # Inside: 0.1 0.3 0.5, p95 at rank 1.9: 0.3 + 0.9 * 0.2.
    assert summary["hop_inside"] == {"p50_ms": 0.3, "p95_ms": 0.48, "max_ms": 0.5, "count": 3}
    # Heads: 0.02 0.04, p50 halfway, p95 at rank 0.95.
    assert summary["hop_head"] == {"p50_ms": 0.03, "p95_ms": 0.039, "max_ms": 0.04, "count": 2}


def test_hops_inside_are_kept_per_edge_too() -> None:
    costs = Costs()
    for delay in (1.0, 2.0, 3.0):
        costs.hop(delay, True, ("cam", "det"))
    costs.hop(0.5, True, ("det", "plan"))
    costs.hop(0.05, False)  # a head's trigger: on no edge
    by_edge = costs.summary(1)["hop_by_edge"]
    # cam -> det: 1 2 3, p95 at rank 1.9: 2 + 0.9 * 1.
    assert by_edge == {
        "cam -> det": {"p50_ms": 2.0, "p95_ms": 2.9, "max_ms": 3.0, "count": 3},
        "det -> plan": {"p50_ms": 0.5, "p95_ms": 0.5, "max_ms": 0.5, "count": 1},
    }
    assert list(by_edge) == sorted(by_edge)


def test_a_heads_trigger_to_its_start_is_kept_per_head_as_its_dispatch() -> None:
    costs = Costs()
    for delay in (0.2, 0.4, 2.4):
        costs.hop(delay, False, None, "scan")
    costs.hop(1.0, False, None, "GL")
    costs.hop(0.3, True, ("scan", "LM"), "LM")  # inside a subchain: an edge's hop, never a dispatch
    summary = costs.summary(1)
    # scan: 0.2 0.4 2.4, p50 the middle one, p95 at rank 1.9: 0.4 + 0.9 * 2.0.
    assert summary["dispatch_by_head"] == {
        "GL": {"p50_ms": 1.0, "p95_ms": 1.0, "max_ms": 1.0, "count": 1},
        "scan": {"p50_ms": 0.4, "p95_ms": 2.2, "max_ms": 2.4, "count": 3},
    }
    # All four triggers are heads' hops still, together.
    assert summary["hop_head"] == {"p50_ms": 0.7, "p95_ms": 2.19, "max_ms": 2.4, "count": 4}


def test_a_subchain_of_one_node_has_no_hop_inside() -> None:
    costs = Costs()
    costs.hop(0.05, False)
    summary = costs.summary(1)
    assert summary["hop_inside"] is None
    assert summary["hop_head"] == {"p50_ms": 0.05, "p95_ms": 0.05, "max_ms": 0.05, "count": 1}


def _log(tmp_path: Path, costs: dict[str, object]) -> Path:
    events = [
        {"t": 0.0, "event": "start", "app": "a", "cores": 1, "format": 1},
        {"t": 1.0, "event": "stop", "summary": {"subchains": [], "costs": costs}},
    ]
    path = tmp_path / "run.jsonl"
    path.write_text("".join(json.dumps(event) + "\n" for event in events))
    return path


def test_report_gives_the_hop_apart_where_the_log_has_it(tmp_path: Path) -> None:
    both = {"p50_ms": 0.1, "p95_ms": 0.46, "max_ms": 0.5, "count": 5}
    inside = {"p50_ms": 0.3, "p95_ms": 0.48, "max_ms": 0.5, "count": 3}
    head = {"p50_ms": 0.03, "p95_ms": 0.039, "max_ms": 0.04, "count": 2}
    log = _log(tmp_path, {"switch": None, "hop": both, "hop_inside": inside, "hop_head": head})
    costs = summary_payload(summarise(json.loads(line) for line in log.read_text().splitlines()))["costs"]
    assert costs["hop_ms"] == {"count": 5, "p50": 0.1, "p95": 0.46, "max": 0.5}
    assert costs["hop_inside_ms"] == {"count": 3, "p50": 0.3, "p95": 0.48, "max": 0.5}
    assert costs["hop_head_ms"] == {"count": 2, "p50": 0.03, "p95": 0.039, "max": 0.04}
    assert costs["hop_by_edge_ms"] == {}  # a log of a catanc that kept no edges apart


def test_report_gives_each_edges_hop(tmp_path: Path) -> None:
    edge = {"p50_ms": 1.2, "p95_ms": 4.9, "max_ms": 7.5, "count": 40}
    log = _log(
        tmp_path,
        {
            "switch": None,
            "hop": edge,
            "hop_inside": edge,
            "hop_head": None,
            "hop_by_edge": {"LM -> LP": edge, "bad": {"p50_ms": "x"}},
        },
    )
    summary = summarise(json.loads(line) for line in log.read_text().splitlines())
    assert summary_payload(summary)["costs"]["hop_by_edge_ms"] == {
        "LM -> LP": {"count": 40, "p50": 1.2, "p95": 4.9, "max": 7.5}
    }
    out = io.StringIO()
    Console(file=out, width=160).print(*render_summary(summary))
    (row,) = [line for line in out.getvalue().splitlines() if "LM -> LP" in line]
    assert [cell.strip() for cell in row.split("│")[1:6]] == ["LM -> LP", "40", "1.200", "4.900", "7.500"]


def test_report_gives_each_heads_dispatch(tmp_path: Path) -> None:
    head = {"p50_ms": 0.36, "p95_ms": 2.4, "max_ms": 7.8, "count": 900}
    log = _log(
        tmp_path,
        {"switch": None, "hop": head, "hop_inside": None, "hop_head": head, "dispatch_by_head": {"scan": head}},
    )
    summary = summarise(json.loads(line) for line in log.read_text().splitlines())
    assert summary_payload(summary)["costs"]["dispatch_by_head_ms"] == {
        "scan": {"count": 900, "p50": 0.36, "p95": 2.4, "max": 7.8}
    }
    out = io.StringIO()
    Console(file=out, width=160).print(*render_summary(summary))
    lines = out.getvalue().splitlines()
    (row,) = [line for line in lines if "│     scan" in line]
    assert [cell.strip() for cell in row.split("│")[1:6]] == ["scan", "900", "0.360", "2.400", "7.800"]
    assert lines.index(row) == 1 + next(i for i, line in enumerate(lines) if "trigger to head" in line)


def test_an_older_log_without_the_split_still_reports(tmp_path: Path) -> None:
    both = {"p50_ms": 0.1, "p95_ms": 0.46, "max_ms": 0.5, "count": 5}
    log = _log(tmp_path, {"switch": None, "hop": both})
    costs = summary_payload(summarise(json.loads(line) for line in log.read_text().splitlines()))["costs"]
    assert costs["hop_ms"]["p50"] == 0.1
    assert costs["hop_inside_ms"] is None
    assert costs["hop_head_ms"] is None


def test_a_hop_the_spec_budgets_in_a_c_of_s_raises_no_switch() -> None:
    # nav2d's local subchain with scan's dispatch and scan -> LM in the spec; LM -> LP and GL's dispatch not.
    costs = Costs(planned=planned_hops(parse_spec(NAV_LIKE)))
    costs.switch(0, 0.1)
    for _ in range(10):
        costs.hop(2.4, False, None, "scan")  # planned: in local's c(S)
        costs.hop(1.0, True, ("scan", "LM"), "LM")  # planned
    costs.hop(0.3, True, ("LM", "LP"), "LP")  # not planned
    costs.hop(0.5, False, None, "GL")  # not planned
    summary = costs.summary(1)
    # The two unplanned hops, 0.3 and 0.5: p95 at rank 0.95, 0.3 + 0.95 * 0.2.
    assert summary["hop_unplanned"] == {"p50_ms": 0.4, "p95_ms": 0.49, "max_ms": 0.5, "count": 2}
    profile = measured_profile(
        summary, rt=RtLimit(runtime_us=950_000, period_us=1_000_000), machine=_MACHINE, minimum=1
    )
    assert profile is not None
    assert profile.hop_ms == 0.49
    # A summary of an older enforcer, without the split: every hop.
    del summary["hop_unplanned"]
    older = measured_profile(summary, rt=RtLimit(runtime_us=950_000, period_us=1_000_000), machine=_MACHINE, minimum=1)
    assert older is not None
    assert older.hop_ms == summary["hop"]["p95_ms"]
