"""``catanc run``'s status: per subchain rates, compute, late and lost runs (the log's ``status`` lines), and the
live view of it (rich), refreshed once a second."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

if TYPE_CHECKING:
    from catanc.control.measure import Measurements
    from catanc.control.schedule import RuntimeSchedule
    from catanc.runtime.enforcer.runs import RunBook
    from catanc.runtime.protocol.endpoints import Registry


def status_rows(
    schedule: RuntimeSchedule, book: RunBook, measurements: Measurements, registry: Registry, now_ms: float
) -> dict[str, dict[str, Any]]:
    """Per subchain: planned and measured rate (0 soon after it stops), p95 compute, late, lost, steals."""
    estimates = measurements.estimates()
    rows = {}
    for name, run in sorted(schedule.subchains.items()):
        state = book.state(name)
        measured = book.measured_hz(name, run.period_ms, now_ms)
        rows[name] = {
            "planned_hz": round(1000.0 / run.period_ms, 3),
            "measured_hz": None if measured is None else round(measured, 3),
            "compute_p95_ms": round(sum(estimates.get(node, 0.0) for node in run.nodes), 3),
            "late": state.late,
            "lost": state.lost,
            "steals": state.steals,
            "skipped": state.skipped,
            "unmatched": state.unmatched,
            "registered": all(registry.of(node) for node in run.nodes),
        }
    return rows


def status_view(app: str, cores: int, status: dict[str, Any], events: list[str], elapsed_s: float) -> RenderableType:
    """Per subchain: planned and measured rate, p95 compute, late and lost runs, steals; the costs; recent events."""
    resolved = status.get("last_resolve_s")
    title = f"catanc run: {app} on {cores} core{'s' if cores != 1 else ''}, {elapsed_s:.0f} s"
    if resolved is not None:
        title += f", last re-plan {status.get('since_resolve_s', 0.0):.1f} s ago"
    table = Table(title=title, title_justify="left")
    for column in ("subchain", "planned Hz", "measured Hz", "p95 compute ms", "late", "lost", "steals", "skipped"):
        table.add_column(column, justify="left" if column == "subchain" else "right")
    for name, row in status["subchains"].items():
        measured = row["measured_hz"]
        table.add_row(
            name + ("" if row["registered"] else " (waiting for nodes)"),
            f"{row['planned_hz']:.2f}",
            "-" if measured is None else f"{measured:.2f}",
            f"{row['compute_p95_ms']:.3f}",
            str(row["late"]),
            str(row["lost"]),
            str(row["steals"]),
            str(row["skipped"]),
        )
    lines: list[RenderableType] = [table]
    costs = status.get("costs") or {}
    parts = []
    for label, key in (("switch", "switch"), ("hop", "hop")):
        stats = costs.get(key)
        if stats:
            parts.append(f"{label} p50 {stats['p50_ms']:.3f} ms, p95 {stats['p95_ms']:.3f} ms")
    if costs.get("cpu_per_wake_ms") is not None:
        share = max(costs.get("overhead") or [0.0])
        parts.append(f"enforcer {share:.1%} of a core, {1000 * costs['cpu_per_wake_ms']:.0f} us per wake-up")
    if parts:
        lines.append(Text("costs: " + "; ".join(parts)))
    return Group(*lines, *(Text(f"- {event}") for event in events[-5:]))
