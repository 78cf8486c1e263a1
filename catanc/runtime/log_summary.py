"""``catanc report``: a ``catanc run`` log as summary tables, JSON and a timeline plot.

The core is pure: :func:`summarise` turns the log's events (see
:mod:`catanc.runtime.log`) into a :class:`RunSummary`; :func:`render_summary`
makes rich tables of it and :func:`summary_json` its JSON (sorted keys, fixed
precision, a final newline).  :func:`plot_timeline` draws the timeline to a
PNG and is the only place that imports matplotlib, so neither the enforcer
nor the node client ever loads it.  :func:`report_command` is the whole
command: read, summarise, print, plot.

What the numbers mean:

- A run's length is the latest ``t`` in the log (the ``stop`` event's, after
  a clean end); times count from the enforcer's start.
- A subchain's measured rate is its completed runs (``run`` events) per
  second over the whole run, and over the last plan's period of validity:
  from the last ``start`` or ``resolve`` event to the end of the log.
- Planned rates are ``1000 / period_ms`` from the plan of the ``start`` event
  and of every ``resolve``; only changes are kept, so a subchain whose
  period never changed has one entry.
- Late, lost, steals and skipped are the enforcer's own counters from the
  last ``status`` or ``stop`` event (None when the log has neither).
- Percentiles are :func:`catanc.runtime.measure.percentile`'s (linear
  interpolation), the same definition the enforcer plans with.
- The enforcer's own costs (switch latency, hop delay, its CPU share) are
  its own figures from the last ``status`` or ``stop`` event.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from catanc.errors import OutputError, UsageError
from catanc.runtime.log import read_log
from catanc.runtime.measure import percentile

RATE_BIN_S = 1.0
"""Width of the plot's measured-rate bins (seconds)."""

PIPED_WIDTH = 160
"""Table width when stdout is not a terminal (as the CLI's other commands)."""


# --------------------------------------------------------------------------- the summary


@dataclass(frozen=True)
class Stats:
    """Count, mean, 95th percentile and range of some milliseconds."""

    count: int
    mean_ms: float
    p95_ms: float
    min_ms: float
    max_ms: float


@dataclass(frozen=True)
class PlannedRate:
    """From ``t_s`` on, a plan asks for one run every ``period_ms``."""

    t_s: float
    period_ms: float

    @property
    def hz(self) -> float:
        return 1000.0 / self.period_ms


@dataclass(frozen=True)
class SubchainSummary:
    name: str
    runs: int  # completed runs (``run`` events)
    measured_hz: float | None  # runs per second over the whole run; None for a run of no length
    last_plan_hz: float | None  # runs per second since the last plan; None if it came at the very end
    planned: tuple[PlannedRate, ...]  # every change of the planned period, in time order
    latency: Stats | None  # trigger to last node done, over the ``run`` events
    late: int | None  # the rest: the enforcer's counters at its last status or stop
    lost: int | None
    steals: int | None
    skipped: int | None
    run_times_s: tuple[float, ...] = field(default=(), repr=False)  # when each run completed, for the plot


@dataclass(frozen=True)
class NodeSummary:
    name: str
    compute: Stats | None  # the node's measured compute times; None when it has none
    unmeasured: int  # ``compute`` events without a usable time
    samples: tuple[tuple[float, float], ...] = field(default=(), repr=False)  # (t_s, ms), for the plot


@dataclass(frozen=True)
class ResolveSummary:
    """One re-plan: when, why, how long it took, what it made."""

    t_s: float
    reason: str
    stage1: bool  # a new allocation was asked for (Stage I and II), not only new periods
    allocation_changed: bool
    solve_ms: float | None
    objective: float | None
    error: str | None  # the re-plan failed and the last plan was kept


@dataclass(frozen=True)
class Quantiles:
    """p50, p95 and the maximum of some milliseconds the enforcer measured itself."""

    count: int
    p50_ms: float
    p95_ms: float
    max_ms: float


@dataclass(frozen=True)
class CostsSummary:
    """The enforcer's own costs, as its last ``status`` or ``stop`` event gives them."""

    switch: Quantiles | None  # a boundary's due time to its owner raised and its head triggered
    hop: Quantiles | None  # a node's end (or a trigger) to the next node's start
    share: float | None  # the enforcer's CPU share of the core its loop runs on
    cpu_per_wake_ms: float | None


@dataclass(frozen=True)
class RunSummary:
    length_s: float
    cores: int | None  # from the ``start`` event
    complete: bool  # the log ends with the enforcer's ``stop`` (not a killed run)
    last_plan_s: float  # when the last plan (start or re-plan) took effect
    subchains: tuple[SubchainSummary, ...]  # sorted by name
    nodes: tuple[NodeSummary, ...]  # sorted by name
    resolves: tuple[ResolveSummary, ...]  # in time order
    costs: CostsSummary | None = None  # None: a log of a catanc that did not measure them


def stats(samples: Sequence[float]) -> Stats | None:
    """Count, mean, p95, min and max of ``samples``; None for none."""
    if not samples:
        return None
    return Stats(
        count=len(samples),
        mean_ms=math.fsum(samples) / len(samples),
        p95_ms=percentile(samples, 95.0),
        min_ms=min(samples),
        max_ms=max(samples),
    )


def usable(event: object) -> bool:
    """Whether ``event`` looks like a log event: an object with a finite ``t`` and a string ``event``."""
    if not isinstance(event, Mapping):
        return False
    return _number(event.get("t")) is not None and isinstance(event.get("event"), str)


def summarise(events: Iterable[Mapping[str, Any]]) -> RunSummary:
    """The summary of a run's log events (in log order); events that are not objects with ``t`` are ignored."""
    good = [event for event in events if usable(event)]
    length = max((float(event["t"]) for event in good), default=0.0)
    cores: int | None = None
    complete = False
    plans: list[tuple[float, Mapping[str, Any]]] = []  # (t, plan) from start and resolve events
    runs: dict[str, list[tuple[float, float | None]]] = {}  # subchain -> (t, latency_ms)
    samples: dict[str, list[tuple[float, float]]] = {}
    unmeasured: dict[str, int] = {}
    counters: Mapping[str, Any] = {}  # subchain -> row of the last status or stop
    named: set[str] = set()
    resolves: list[ResolveSummary] = []
    costs: CostsSummary | None = None
    for event in good:
        kind, t = event["event"], float(event["t"])
        if kind == "start":
            cores = _integer(event.get("cores"))
            plans.append((t, _mapping(event.get("plan"))))
        elif kind == "resolve":
            plan = _mapping(event.get("plan"))
            plans.append((t, plan))
            resolves.append(
                ResolveSummary(
                    t_s=t,
                    reason=str(event.get("reason", "")),
                    stage1=event.get("stage1") is True,
                    allocation_changed=event.get("allocation_changed") is True,
                    solve_ms=_number(event.get("solve_ms")),
                    objective=_number(plan.get("objective")),
                    error=None if event.get("error") is None else str(event["error"]),
                )
            )
        elif kind == "run" and isinstance(event.get("subchain"), str):
            runs.setdefault(event["subchain"], []).append((t, _number(event.get("latency_ms"))))
        elif kind == "lost" and isinstance(event.get("subchain"), str):
            named.add(event["subchain"])
        elif kind == "compute" and isinstance(event.get("node"), str):
            node, ms = event["node"], _number(event.get("ms"))
            samples.setdefault(node, [])
            if ms is not None and ms >= 0:  # as measure.valid_sample
                samples[node].append((t, ms))
            else:
                unmeasured[node] = unmeasured.get(node, 0) + 1
        elif kind == "register" and isinstance(event.get("node"), str):
            samples.setdefault(event["node"], [])
        elif kind in ("status", "stop"):
            row = event if kind == "status" else _mapping(event.get("summary"))
            counters = _mapping(row.get("subchains"))
            complete = complete or kind == "stop"
            costs = _costs(_mapping(row.get("costs"))) or costs
    planned = _planned_rates(plans)
    last_plan = plans[-1][0] if plans else 0.0
    names = sorted(named | set(runs) | set(planned) | {str(name) for name in counters})
    return RunSummary(
        length_s=length,
        cores=cores,
        complete=complete,
        last_plan_s=last_plan,
        subchains=tuple(
            _subchain(
                name,
                runs.get(name, []),
                planned=planned.get(name, []),
                counters=_mapping(counters.get(name)),
                length=length,
                last_plan=last_plan,
            )
            for name in names
        ),
        nodes=tuple(
            NodeSummary(
                name=node,
                compute=stats([ms for _, ms in samples[node]]),
                unmeasured=unmeasured.get(node, 0),
                samples=tuple(samples[node]),
            )
            for node in sorted(samples)
        ),
        resolves=tuple(resolves),
        costs=costs,
    )


def _costs(row: Mapping[str, Any]) -> CostsSummary | None:
    if not row:
        return None
    overhead = row.get("overhead")
    shares = [share for share in overhead if _number(share) is not None] if isinstance(overhead, list) else []
    return CostsSummary(
        switch=_quantiles(_mapping(row.get("switch"))),
        hop=_quantiles(_mapping(row.get("hop"))),
        share=max(shares) if shares else None,
        cpu_per_wake_ms=_number(row.get("cpu_per_wake_ms")),
    )


def _quantiles(row: Mapping[str, Any]) -> Quantiles | None:
    p50, p95, top, count = (row.get(key) for key in ("p50_ms", "p95_ms", "max_ms", "count"))
    numbers = [_number(p50), _number(p95), _number(top)]
    if any(value is None for value in numbers) or _integer(count) is None:
        return None
    return Quantiles(int(count), *numbers)  # type: ignore[arg-type]


def _subchain(
    name: str,
    runs: Sequence[tuple[float, float | None]],
    *,
    planned: Sequence[PlannedRate],
    counters: Mapping[str, Any],
    length: float,
    last_plan: float,
) -> SubchainSummary:
    since = length - last_plan
    return SubchainSummary(
        name=name,
        runs=len(runs),
        measured_hz=len(runs) / length if length > 0 else None,
        last_plan_hz=sum(t > last_plan for t, _ in runs) / since if since > 0 else None,
        planned=tuple(planned),
        latency=stats([ms for _, ms in runs if ms is not None]),
        late=_integer(counters.get("late")),
        lost=_integer(counters.get("lost")),
        steals=_integer(counters.get("steals")),
        skipped=_integer(counters.get("skipped")),
        run_times_s=tuple(t for t, _ in runs),
    )


def _planned_rates(plans: Sequence[tuple[float, Mapping[str, Any]]]) -> dict[str, list[PlannedRate]]:
    """Per subchain, each plan's period where it differs from the one before."""
    planned: dict[str, list[PlannedRate]] = {}
    for t, plan in plans:
        for name, sub in _mapping(plan.get("subchains")).items():
            period = _number(_mapping(sub).get("period_ms"))
            if period is None or period <= 0:
                continue
            steps = planned.setdefault(str(name), [])
            if not steps or steps[-1].period_ms != period:
                steps.append(PlannedRate(t_s=t, period_ms=period))
    return planned


def rate_bins(
    times_s: Iterable[float], length_s: float, width_s: float = RATE_BIN_S
) -> tuple[tuple[float, float], ...]:
    """Runs per second in consecutive bins of ``width_s`` from 0 to ``length_s``: ``(bin start, Hz)``.

    The last bin may be shorter (its rate is over its own width); a time of
    exactly ``length_s`` counts in the last bin; times outside ``[0, length_s]`` are ignored.
    """
    if length_s <= 0:
        return ()
    count = max(1, math.ceil(length_s / width_s))
    tallies = [0] * count
    for t in times_s:
        if 0 <= t <= length_s:
            tallies[min(int(t // width_s), count - 1)] += 1
    return tuple(
        (i * width_s, tally / (min((i + 1) * width_s, length_s) - i * width_s)) for i, tally in enumerate(tallies)
    )


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def _integer(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _mapping(value: object) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


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
                    {"t_s": _round(p.t_s), "period_ms": _round(p.period_ms), "hz": _round(p.hz)} for p in sub.planned
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
        "core_share": _round(costs.share, 5),
        "cpu_per_wake_ms": _round(costs.cpu_per_wake_ms, 5),
    }


def summary_json(summary: RunSummary) -> str:
    """``--json``'s output: :func:`summary_payload` with sorted keys and a final newline."""
    return json.dumps(summary_payload(summary), indent=2, sort_keys=True, allow_nan=False) + "\n"


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
    columns = ("subchain", "runs", "Hz", "Hz last plan", "planned Hz", "latency mean", "p95", "max ms")
    for column in (*columns, "late", "lost", "steals", "skipped"):
        subchains.add_column(column, justify="left" if column == "subchain" else "right")
    for sub in summary.subchains:
        planned = "-"
        if sub.planned:
            first, last = sub.planned[0].hz, sub.planned[-1].hz
            planned = f"{first:.2f}" if len(sub.planned) == 1 else f"{first:.2f} -> {last:.2f}"
        latency = _cells(sub.latency)
        subchains.add_row(
            sub.name,
            str(sub.runs),
            _fixed(sub.measured_hz),
            _fixed(sub.last_plan_hz),
            planned,
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


def _costs_table(costs: CostsSummary) -> Table:
    """The enforcer's own costs: switch latency, hop delay (a node's end to the next's start), its CPU."""
    share = "-" if costs.share is None else f"{costs.share:.2%} of its core"
    per_wake = "-" if costs.cpu_per_wake_ms is None else f"{1000 * costs.cpu_per_wake_ms:.0f} us per wake-up"
    table = Table(title=f"the enforcer's own costs: {share}, {per_wake}", title_justify="left")
    for column in ("ms", "samples", "p50", "p95", "max"):
        table.add_column(column, justify="left" if column == "ms" else "right")
    for label, value in (("switch latency", costs.switch), ("hop delay", costs.hop)):
        if value is None:
            table.add_row(label, "0", "-", "-", "-")
        else:
            table.add_row(label, str(value.count), f"{value.p50_ms:.3f}", f"{value.p95_ms:.3f}", f"{value.max_ms:.3f}")
    return table


# --------------------------------------------------------------------------- the plot


def plot_timeline(summary: RunSummary, path: Path) -> None:
    """Draw the run's timeline as a PNG: planned and measured rates, compute times, re-plans.

    One row per subchain: its planned rate (dashed steps) and its measured
    rate (runs per :data:`RATE_BIN_S` bin, solid steps); a last, taller row
    with every node's compute samples (log scale); in every row a vertical
    line at each re-plan (solid red where the allocation changed, dotted grey
    where only periods did).  Matplotlib is imported here only, with the Agg
    canvas: no display and no pyplot state.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    rows = len(summary.subchains) + 1
    figure = Figure(figsize=(12, 1.6 * (rows - 1) + 4.0), dpi=100, layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(rows, 1, sharex=True, squeeze=False, height_ratios=[1.0] * (rows - 1) + [2.5])[:, 0]
    end = max(summary.length_s, 1e-3)
    for sub, ax in zip(summary.subchains, axes, strict=False):
        if sub.planned:
            xs = [p.t_s for p in sub.planned] + [end]
            ys = [p.hz for p in sub.planned] + [sub.planned[-1].hz]
            ax.step(xs, ys, where="post", color="black", linestyle="--", linewidth=1.0, label="planned")
        bins = rate_bins(sub.run_times_s, summary.length_s)
        if bins:
            edges = [start for start, _ in bins] + [summary.length_s]
            ax.stairs([hz for _, hz in bins], edges, baseline=None, color="C0", linewidth=1.6, label="measured")
        ax.set_ylim(bottom=0)
        ax.set_ylabel(f"{sub.name}\n(Hz)")
    if summary.subchains:
        axes[0].set_title(
            f"subchain rates: planned and measured (runs per {RATE_BIN_S:g} s)", loc="left", fontsize="medium"
        )
    compute = axes[-1]
    measured = False
    for i, node in enumerate(summary.nodes):
        if node.samples:
            compute.scatter(
                [t for t, _ in node.samples],
                [ms for _, ms in node.samples],
                s=4,
                color=f"C{i % 10}",
                alpha=0.6,
                linewidths=0,
                label=node.name,
            )
            measured = measured or any(ms > 0 for _, ms in node.samples)
    compute.set_ylabel("compute (ms)")
    compute.set_xlabel("time since start (s)")
    compute.set_title("node compute times", loc="left", fontsize="medium")
    if measured:
        compute.set_yscale("log")
    compute.set_xlim(0, end)
    for n, ax in enumerate(axes):
        for r in summary.resolves:
            if r.allocation_changed:
                ax.axvline(r.t_s, color="red", linewidth=1.0, label="re-plan, new allocation")
            else:
                ax.axvline(r.t_s, color="grey", linestyle=":", linewidth=1.0, label="re-plan")
        if n == 0 or ax is compute:
            handles, labels = ax.get_legend_handles_labels()
            unique = dict(zip(labels, handles, strict=True))
            if unique:
                ax.legend(
                    unique.values(),
                    unique.keys(),
                    loc="upper left",
                    bbox_to_anchor=(1.01, 1.0),
                    fontsize="small",
                    markerscale=3,
                )
    try:
        figure.savefig(path, format="png", metadata={"Software": None})
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the plot: {exc.strerror or exc}") from None


# --------------------------------------------------------------------------- the command


def load_events(log: Path) -> list[dict[str, Any]]:
    """The log's usable events; :class:`UsageError` naming the file if it is missing, unreadable or empty."""
    try:
        events = read_log(log)
    except FileNotFoundError:
        raise UsageError(f"{log}: no such log file") from None
    except IsADirectoryError:
        raise UsageError(f"{log}: is a folder, not a log file") from None
    except UnicodeDecodeError:
        raise UsageError(f"{log}: cannot read the log: not UTF-8 text") from None
    except OSError as exc:
        raise UsageError(f"{log}: cannot read the log: {exc.strerror or exc}") from None
    good = [event for event in events if usable(event)]
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
