"""``catanc run``'s live status: one table, refreshed a few times a second (rich)."""

from __future__ import annotations

from typing import Any

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text


def status_view(app: str, cores: int, status: dict[str, Any], events: list[str], elapsed_s: float) -> RenderableType:
    """Per subchain: planned and measured rate, p95 compute, late and lost runs, steals; then recent events."""
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
    return Group(table, *(Text(f"- {event}") for event in events[-5:]))
