"""``catanc report``: a ``catanc run`` log as summary tables, JSON and a timeline plot.

:func:`render_summary` makes rich tables of a
:class:`~catanc.control.run_summary.RunSummary` and :func:`summary_json` its
JSON (sorted keys, fixed precision, a final newline).  :func:`report_command`
is the whole command: read, summarise, print, plot
(:func:`catanc.runtime.logs.timeline.plot_timeline`, the only place that
imports matplotlib, so neither the enforcer nor the node client ever loads it).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from catanc.control.run_summary import (
    ChainSummary,
    CostsSummary,
    Quantiles,
    RunSummary,
    Stats,
    summarise,
    usable,
)
from catanc.errors import UsageError
from catanc.runtime.logs.timeline import plot_timeline
from catanc.runtime.logs.writer import log_events, read_log_text

PIPED_WIDTH = 160
"""Table width when stdout is not a terminal (as the CLI's other commands)."""


# --------------------------------------------------------------------------- JSON and tables


def _round(value: float | None, digits: int = 3) -> float | None:
    return None if value is None else round(value, digits)


def _stats_json(value: Stats | None) -> dict[str, Any] | None:
    if value is None:
        return None
    return {
        "count": value.count,
        "mean": _round(value.mean_ms),
        "p95": _round(value.p95_ms),
        "min": _round(value.min_ms),
        "max": _round(value.max_ms),
    }


def summary_payload(summary: RunSummary) -> dict[str, Any]:
    """The summary as plain data (floats rounded: 3 decimals, 6 for objectives); no per-event series."""
    return {
        "length_s": _round(summary.length_s),
        "cores": summary.cores,
        "complete": summary.complete,
        "last_plan_s": _round(summary.last_plan_s),
        "subchains": {
            sub.name: {
                "runs": sub.runs,
                "measured_hz": _round(sub.measured_hz),
                "last_plan_hz": _round(sub.last_plan_hz),
                "planned": [
                    {
                        "t_s": _round(p.t_s),
                        "period_ms": _round(p.period_ms),
                        "hz": _round(p.hz),
                        "as_run_hz": _round(p.as_run_hz),
                    }
                    for p in sub.planned
                ],
                "latency_ms": _stats_json(sub.latency),
                "late": sub.late,
                "lost": sub.lost,
                "steals": sub.steals,
                "skipped": sub.skipped,
            }
            for sub in summary.subchains
        },
        "nodes": {
            node.name: {"compute_ms": _stats_json(node.compute), "unmeasured": node.unmeasured}
            for node in summary.nodes
        },
        "costs": _costs_json(summary.costs),
        "chains": [_chain_json(chain) for chain in summary.chains],
        "resolves": [
            {
                "t_s": _round(r.t_s),
                "reason": r.reason,
                "stage1": r.stage1,
                "allocation_changed": r.allocation_changed,
                "solve_ms": _round(r.solve_ms),
                "objective": _round(r.objective, 6),
                "error": r.error,
            }
            for r in summary.resolves
        ],
    }


def _chain_json(chain: ChainSummary) -> dict[str, Any]:
    response = chain.response
    return {
        "nodes": list(chain.nodes),
        "planned_ms": _round(chain.planned_ms),
        "max_response_ms": _round(chain.bound_ms),
        "measured_at": chain.at,
        "whole_chain": chain.whole,
        "measured_ms": None
        if response is None
        else {
            "count": response.count,
            "p50": _round(response.p50_ms),
            "p95": _round(response.p95_ms),
            "max": _round(response.max_ms),
        },
    }


def _costs_json(costs: CostsSummary | None) -> dict[str, Any] | None:
    if costs is None:
        return None

    def quantiles(value: Quantiles | None) -> dict[str, Any] | None:
        if value is None:
            return None
        return {
            "count": value.count,
            "p50": _round(value.p50_ms, 4),
            "p95": _round(value.p95_ms, 4),
            "max": _round(value.max_ms, 4),
        }

    return {
        "switch_ms": quantiles(costs.switch),
        "hop_ms": quantiles(costs.hop),
        "hop_inside_ms": quantiles(costs.hop_inside),
        "hop_head_ms": quantiles(costs.hop_head),
        "hop_by_edge_ms": {edge: quantiles(value) for edge, value in costs.hop_by_edge},
        "dispatch_by_head_ms": {head: quantiles(value) for head, value in costs.dispatch_by_head},
        "core_share": _round(costs.share, 5),
        "cpu_per_wake_ms": _round(costs.cpu_per_wake_ms, 5),
    }


def summary_json(summary: RunSummary) -> str:
    """``--json``'s output: :func:`summary_payload` with sorted keys and a final newline."""
    return json.dumps(summary_payload(summary), indent=2, sort_keys=True, allow_nan=False) + "\n"


def _steps(rates: Sequence[float]) -> str:
    """A planned rate's cell: the first plan's, and the last one's where it differs (``-`` for no plan)."""
    if not rates:
        return "-"
    first, last = f"{rates[0]:.2f}", f"{rates[-1]:.2f}"
    return first if first == last else f"{first} -> {last}"


def _fixed(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _cells(value: Stats | None) -> dict[str, str]:
    """A table's cells for some milliseconds: mean, p95, min and max (``-`` for none)."""
    if value is None:
        return dict.fromkeys(("mean", "p95", "min", "max"), "-")
    return {
        "mean": f"{value.mean_ms:.3f}",
        "p95": f"{value.p95_ms:.3f}",
        "min": f"{value.min_ms:.3f}",
        "max": f"{value.max_ms:.3f}",
    }


def _count(value: int | None) -> str:
    return "-" if value is None else str(value)


def render_summary(summary: RunSummary) -> tuple[Table, ...]:
    """Tables for the terminal: subchains, nodes and (if any) re-plans."""
    cores = "?" if summary.cores is None else str(summary.cores)
    title = (
        f"catanc report: {summary.length_s:.1f} s on {cores} core{'' if summary.cores == 1 else 's'}, "
        f"{len(summary.resolves)} re-plan{'' if len(summary.resolves) == 1 else 's'}"
    )
    if not summary.complete:
        title += " (no stop event: the run was cut short)"
    subchains = Table(title=title, title_justify="left")
    # Where an executor's thread takes some of a planned rate, the plan promises what is left: a column says so.
    as_run = any(p.as_run_hz is not None for sub in summary.subchains for p in sub.planned)
    columns: tuple[str, ...] = ("subchain", "runs", "Hz", "Hz last plan", "planned Hz")
    if as_run:
        columns += ("as run Hz",)
    for column in (*columns, "latency mean", "p95", "max ms", "late", "lost", "steals", "skipped"):
        subchains.add_column(column, justify="left" if column == "subchain" else "right")
    for sub in summary.subchains:
        rates = [_steps([p.hz for p in sub.planned])]
        if as_run:
            rates.append(_steps([p.expected_hz for p in sub.planned]))
        latency = _cells(sub.latency)
        subchains.add_row(
            sub.name,
            str(sub.runs),
            _fixed(sub.measured_hz),
            _fixed(sub.last_plan_hz),
            *rates,
            latency["mean"],
            latency["p95"],
            latency["max"],
            _count(sub.late),
            _count(sub.lost),
            _count(sub.steals),
            _count(sub.skipped),
        )
    nodes = Table(title="compute times (ms)", title_justify="left")
    for column in ("node", "samples", "mean", "p95", "min", "max", "unmeasured"):
        nodes.add_column(column, justify="left" if column == "node" else "right")
    for node in summary.nodes:
        compute = _cells(node.compute)
        nodes.add_row(
            node.name,
            str(0 if node.compute is None else node.compute.count),
            compute["mean"],
            compute["p95"],
            compute["min"],
            compute["max"],
            str(node.unmeasured),
        )
    tables = [subchains, nodes]
    if summary.chains:
        tables.append(_chains_table(summary.chains))
    if summary.costs is not None:
        tables.append(_costs_table(summary.costs))
    if not summary.resolves:
        return tuple(tables)
    resolves = Table(title="re-plans", title_justify="left")
    for column in ("t s", "reason", "stage", "solve ms", "objective", "allocation changed", "error"):
        resolves.add_column(column, justify="left" if column in ("reason", "error") else "right")
    for r in summary.resolves:
        resolves.add_row(
            f"{r.t_s:.3f}",
            r.reason,
            "I+II" if r.stage1 else "II",
            _fixed(r.solve_ms, 3),
            _fixed(r.objective, 6),
            "yes" if r.allocation_changed else "no",
            r.error or "",
        )
    return (*tables, resolves)


def _chains_table(chains: Sequence[ChainSummary]) -> Table:
    """Each chain's response measured from origins beside the plan's and its bound (``<=`` a lower bound)."""
    table = Table(title="chains: response from origins (ms)", title_justify="left")
    for column in ("chain", "measured at", "runs", "p50", "p95", "max", "planned", "bound"):
        table.add_column(column, justify="left" if column in ("chain", "measured at") else "right")
    for chain in chains:
        response = chain.response
        at = "-" if chain.at is None else chain.at if chain.whole else f"{chain.at} (part of it)"
        cells = (
            ["-"] * 4
            if response is None
            else [
                str(response.count),
                f"{response.p50_ms:.3f}",
                f"{response.p95_ms:.3f}",
                f"{response.max_ms:.3f}",
            ]
        )
        over = response is not None and chain.bound_ms is not None and response.p95_ms > chain.bound_ms
        bound = _fixed(chain.bound_ms, 3) + (" exceeded" if over else "")
        table.add_row(" -> ".join(chain.nodes), at, *cells, _fixed(chain.planned_ms, 3), bound)
    return table


def _costs_table(costs: CostsSummary) -> Table:
    """The enforcer's own costs: switch latency, hop delay (a node's end, or a head's trigger, to the next start;
    then the two apart where the log has them, per edge and per head: a head's dispatch), its CPU."""
    share = "-" if costs.share is None else f"{costs.share:.2%} of its core"
    per_wake = "-" if costs.cpu_per_wake_ms is None else f"{1000 * costs.cpu_per_wake_ms:.0f} us per wake-up"
    table = Table(title=f"the enforcer's own costs: {share}, {per_wake}", title_justify="left")
    for column in ("ms", "samples", "p50", "p95", "max"):
        table.add_column(column, justify="left" if column == "ms" else "right")
    rows = [("switch latency", costs.switch), ("hop delay", costs.hop)]
    if costs.hop_inside is not None or costs.hop_head is not None:  # a log of a catanc that tells them apart
        rows += [("  node to node", costs.hop_inside)]
        rows += [(f"    {edge}", value) for edge, value in costs.hop_by_edge]
        rows += [("  trigger to head", costs.hop_head)]
        rows += [(f"    {head}", value) for head, value in costs.dispatch_by_head]
    for label, value in rows:
        if value is None:
            table.add_row(label, "0", "-", "-", "-")
        else:
            table.add_row(label, str(value.count), f"{value.p50_ms:.3f}", f"{value.p95_ms:.3f}", f"{value.max_ms:.3f}")
    return table


# --------------------------------------------------------------------------- the command


def load_events(log: Path) -> list[dict[str, Any]]:
    """The log's usable events; :class:`UsageError` naming the file if it is missing, unreadable or empty."""
    good = [event for event in log_events(read_log_text(log)) if usable(event)]
    if not good:
        raise UsageError(f"{log}: no events (an empty log, or not a catanc run log)")
    return good


def report_command(log: Path, plot: Path | None, as_json: bool) -> None:
    """``catanc report LOG [--plot FILE.png] [--json]``: summary tables (or JSON) on stdout, the plot to a file."""
    summary = summarise(load_events(log))
    if plot is not None:
        plot_timeline(summary, plot)
    if as_json:
        sys.stdout.write(summary_json(summary))
        if plot is not None:
            Console(stderr=True, highlight=False, soft_wrap=True).print(f"plot: {plot}", markup=False)
        return
    console = Console(highlight=False, soft_wrap=True, width=None if sys.stdout.isatty() else PIPED_WIDTH)
    for table in render_summary(summary):
        console.print(table)
    if plot is not None:
        console.print(f"plot: {plot}", markup=False)
