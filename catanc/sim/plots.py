"""Plots of a policy comparison: ``catanc simulate --plot DIR`` (and ``catanc bench``, from measured runs).

Three PNGs, always all three (so a folder never holds one run's CDFs beside
another's timeline):

- ``responses-cdf.png``: per named chain, each policy's response times as a
  CDF, with the model's ``R`` where the policy has a plan;
- ``timeline.png``: one schedule period per core for each policy with a slot
  schedule (slots, switches, slack; dedicated cores as one bar); when no
  policy has one, a figure that says so;
- ``rates.png``: per node, each policy's runs per :data:`RATE_BIN_S` bin.

:func:`render_plots` is pure: it draws into memory (matplotlib's object API
on an Agg canvas: no pyplot, no display; matplotlib is imported only here,
so ``catanc simulate`` without ``--plot`` never loads it) and returns
``{file name: PNG bytes}``; the same results give the same bytes (no date or
version in the PNG).  :func:`write_plots` draws all three before touching the
folder, then writes each to a temporary file beside its target and renames it
over the target: a failure leaves each file old or new, never half-written.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from catanc.control.run_summary import RATE_BIN_S, rate_bins
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, SubchainRun
from catanc.files import write_files
from catanc.sim.metrics import ChainResult, PolicyResult

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

RESPONSES = "responses-cdf.png"
TIMELINE = "timeline.png"
RATES = "rates.png"
FILES = (RESPONSES, TIMELINE, RATES)

MAX_PANELS = 24
"""Chains or nodes drawn at most (the first ones; the title says how many were left out)."""
DPI = 100
LOG_SPAN = 20.0
"""A CDF panel's time axis is logarithmic when its largest time is this many times its smallest."""
TITLE_WIDTH = 64
"""Characters per line of a chain's panel title (broken between nodes)."""
MAX_PERIOD_TICKS = 100
"""A dedicated core's bar marks each of its subchain's periods, when there are at most this many."""


# --------------------------------------------------------------------------- writing


def write_plots(
    results: Sequence[PolicyResult], out_dir: Path, *, title: str, nodes: Sequence[str] | None = None
) -> list[Path]:
    """Draw the three plots and write them into ``out_dir`` (created if missing); returns the paths written.

    ``title`` heads every figure (e.g. ``"nav2d, 2 cores, 60 s simulated"``); ``nodes`` picks the nodes of
    the rates plot (default: every node any result has completion times of, by name).
    """
    return write_files(out_dir, render_plots(results, title=title, nodes=nodes))


# --------------------------------------------------------------------------- drawing


def render_plots(
    results: Sequence[PolicyResult], *, title: str, nodes: Sequence[str] | None = None
) -> dict[str, bytes]:
    """``{file name: PNG bytes}`` of the three plots (see the module's docstring)."""
    return {name: png_bytes(figure) for name, figure in draw_figures(results, title=title, nodes=nodes).items()}


def draw_figures(
    results: Sequence[PolicyResult], *, title: str, nodes: Sequence[str] | None = None
) -> dict[str, Figure]:
    """``{file name: figure}`` of the three plots, drawn but not encoded."""
    colors = {result.policy: f"C{i % 10}" for i, result in enumerate(results)}
    # Earlier policies drawn wider, so a later one that coincides (fifo-static often does baseline's) shows
    # as a line inside a line instead of hiding it.
    widths = {result.policy: max(0.8, 3.6 * 0.7**i) for i, result in enumerate(results)}
    return {
        RESPONSES: _responses_figure(results, _Styles(colors, widths), title),
        TIMELINE: _timeline_figure(results, title),
        RATES: _rates_figure(results, _Styles(colors, widths), title, nodes),
    }


@dataclass(frozen=True)
class _Styles:
    colors: Mapping[str, str]  # per policy
    widths: Mapping[str, float]


def new_figure(width_in: float, height_in: float) -> Figure:
    """An empty figure drawn off-screen (Agg), laid out by matplotlib's constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    figure = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def png_bytes(figure: Figure) -> bytes:
    """The figure as PNG, the same bytes for the same drawing."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", metadata={"Software": None})  # no matplotlib version in the bytes
    return buffer.getvalue()


def _grid(figure: Figure, panels: int) -> list[Axes]:
    columns = 1 if panels == 1 else 2
    rows = math.ceil(panels / columns)
    axes = list(figure.subplots(rows, columns, squeeze=False).flat)
    for spare in axes[panels:]:
        spare.set_visible(False)
    return axes[:panels]


def panel_figure(panels: int, width_in: float, height_in: float, title: str) -> tuple[Figure, list[Axes]]:
    """A titled figure of ``panels`` axes, two per row when there are several (a spare one hidden)."""
    figure = new_figure(width_in, height_in)
    figure.suptitle(title)
    return figure, _grid(figure, panels)


def _panels(panels: int, row_in: float, title: str) -> tuple[Figure, list[Axes]]:
    """:func:`panel_figure` sized as responses-cdf.png and rates.png are: ``row_in`` per row of panels."""
    rows = math.ceil(panels / (1 if panels == 1 else 2))
    return panel_figure(panels, 13.0 if panels > 1 else 10.0, row_in * rows + 1.0, title)


def _first(items: Sequence[str], what: str) -> tuple[list[str], str]:
    """The first :data:`MAX_PANELS` items, and a note of how many were left out (empty if none were)."""
    if len(items) <= MAX_PANELS:
        return list(items), ""
    return list(items[:MAX_PANELS]), f" (the first {MAX_PANELS} of {len(items)} {what})"


def _note(ax: Axes, text: str) -> None:
    """An empty panel that says why."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="dimgrey", wrap=True)
    ax.set_xticks([])
    ax.set_yticks([])


def _log_scale(ax: Axes, axis: str, values: Iterable[float]) -> bool:
    """Make ``axis`` logarithmic (plain-number labels) if the positive ``values`` span :data:`LOG_SPAN` or more."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: PLC0415

    positive = [value for value in values if value > 0]
    if not positive or max(positive) < LOG_SPAN * min(positive):
        return False
    scale = ax.xaxis if axis == "x" else ax.yaxis
    (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    scale.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    scale.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    scale.set_minor_formatter(NullFormatter())
    return True


def _outside_legend(figure: Figure, axes: Iterable[Axes]) -> None:
    """One legend for the figure, right of the panels, each label once (in order of first appearance)."""
    unique: dict[str, Artist] = {}
    for ax in axes:
        handles, labels = ax.get_legend_handles_labels()
        for handle, label in zip(handles, labels, strict=True):
            unique.setdefault(label, handle)
    if unique:
        figure.legend(list(unique.values()), list(unique.keys()), loc="outside right upper", fontsize="small")


# --------------------------------------------------------------------------- responses-cdf.png


def chain_label(nodes: Sequence[str], width: int = TITLE_WIDTH) -> str:
    """``a -> b -> c``, broken into lines of at most ``width`` characters between nodes (where it can be)."""
    lines: list[str] = []
    line = ""
    for node in nodes:
        if not line:
            line = node
        elif len(line) + 4 + len(node) <= width:
            line += f" -> {node}"
        else:
            lines.append(line + " ->")
            line = node
    lines.append(line)
    return "\n".join(lines)


def _named_chains(results: Sequence[PolicyResult]) -> list[tuple[str, ...]]:
    order: dict[tuple[str, ...], None] = {}
    for result in results:
        for chain in result.chains:
            if chain.named:
                order.setdefault(chain.nodes)
    return list(order)


def _responses_figure(results: Sequence[PolicyResult], styles: _Styles, title: str) -> Figure:
    chains = _named_chains(results)
    keys = [chain_label(chain) for chain in chains]
    shown, left_out = _first(keys, "named chains")
    suptitle = f"{title}: chain response times, CDF over outputs; dotted: the model's R{left_out}"
    figure, axes = _panels(max(1, len(shown)), 3.4, suptitle)
    if not chains:
        _note(axes[0], "no named chains (the objective and constraints name none)")
        return figure
    by_policy = [(result.policy, {chain.nodes: chain for chain in result.chains}) for result in results]
    for ax, nodes in zip(axes, chains, strict=False):
        _cdf_panel(ax, nodes, [(policy, found.get(nodes)) for policy, found in by_policy], styles)
    _outside_legend(figure, axes)
    return figure


def _cdf_panel(
    ax: Axes, nodes: tuple[str, ...], chains: Sequence[tuple[str, ChainResult | None]], styles: _Styles
) -> None:
    ax.set_title(chain_label(nodes), fontsize="medium")
    drawn: list[float] = []
    silent = []
    for policy, chain in chains:
        values = np.sort(chain.samples[:, 1]).tolist() if chain is not None else []
        if not values:
            silent.append(policy)
        else:
            n = len(values)
            ax.step(
                [values[0], *values],
                [0.0, *((i + 1) / n for i in range(n))],
                where="post",
                color=styles.colors[policy],
                linewidth=styles.widths[policy],
                label=policy,
            )
            drawn.extend((values[0], values[-1]))
        if chain is not None and chain.model_ms is not None:
            ax.axvline(chain.model_ms, color=styles.colors[policy], linestyle=":", linewidth=1.6, label=f"{policy}: R")
            drawn.append(chain.model_ms)
    if not drawn:
        _note(ax, "no output reached the end of this chain")
        return
    if silent:
        ax.text(
            0.98,
            0.04,
            "no outputs: " + ", ".join(silent),
            ha="right",
            va="bottom",
            transform=ax.transAxes,
            fontsize="small",
            color="dimgrey",
        )
    _log_scale(ax, "x", drawn)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("response time (ms)")
    ax.set_ylabel("fraction of outputs")
    ax.grid(True, alpha=0.3)


# --------------------------------------------------------------------------- timeline.png


def _subchain_colors(schedules: Iterable[RuntimeSchedule]) -> dict[str, tuple[float, float, float, float]]:
    from matplotlib import colormaps  # noqa: PLC0415

    palette = colormaps["tab20"]
    names = sorted({name for schedule in schedules for name in schedule.subchains})
    return {name: palette(i % 20) for i, name in enumerate(names)}


def _timeline_figure(results: Sequence[PolicyResult], title: str) -> Figure:
    planned = [(result.policy, result.schedule) for result in results if result.schedule is not None]
    unplanned = [result.policy for result in results if result.schedule is None]
    if not planned:
        figure = new_figure(10.0, 2.2)
        figure.suptitle(f"{title}: one schedule period per core")
        listed = ", ".join(unplanned) or "no policies"
        _note(figure.subplots(), f"no slot schedule to draw: {listed} (timers or measured runs, no plan)")
        return figure
    heights = [schedule.cores for _, schedule in planned]
    figure = new_figure(13.0, sum(0.55 * h + 1.1 for h in heights) + 0.8)
    note = f"\n(no slot schedule: {', '.join(unplanned)})" if unplanned else ""
    figure.suptitle(f"{title}: one schedule period per core{note}")
    axes = figure.subplots(len(planned), 1, squeeze=False, height_ratios=[h + 1.0 for h in heights])[:, 0]
    colors = _subchain_colors(schedule for _, schedule in planned)
    for ax, (policy, schedule) in zip(axes, planned, strict=True):
        _timeline_panel(ax, policy, schedule, colors)
    _outside_legend(figure, axes)
    return figure


def _timeline_panel(
    ax: Axes, policy: str, schedule: RuntimeSchedule, colors: Mapping[str, tuple[float, float, float, float]]
) -> None:
    shared = {core.core: core for core in schedule.shared}
    dedicated: dict[int, list[SubchainRun]] = {}
    for run in schedule.subchains.values():
        if not run.shared:
            for core in run.cores:
                dedicated.setdefault(core, []).append(run)
    if shared:
        span = max(core.period_ms for core in shared.values())
    else:
        span = max((run.period_ms for runs in dedicated.values() for run in runs), default=1.0)
    periods = ", ".join(f"core {c}: T = {core.period_ms:.2f} ms" for c, core in sorted(shared.items()))
    switch = f", switch {schedule.shared[0].switch_ms:g} ms" if schedule.shared else ""
    ax.set_title(f"{policy}" + (f" ({periods}{switch})" if periods else ""), loc="left", fontsize="medium")
    for core in range(schedule.cores):
        if core in shared:
            _shared_row(ax, core, shared[core], span, colors)
        elif core in dedicated:
            _dedicated_row(ax, core, dedicated[core], span, colors)
        else:
            ax.text(span / 2, core, "unused", ha="center", va="center", color="dimgrey", fontsize="small")
    ax.set_yticks(range(schedule.cores), [f"core {core}" for core in range(schedule.cores)])
    ax.set_ylim(schedule.cores - 0.5, -0.5)  # core 0 on top
    ax.set_xlim(0.0, span)
    ax.set_xlabel("time since the period's start (ms)")


def _fits(label: str, width_ms: float, span_ms: float) -> bool:
    """Whether ``label`` fits inside a bar ``width_ms`` wide on an axis ``span_ms`` wide (about 10 inches)."""
    return width_ms / span_ms * 10.0 * 72.0 >= 5.0 * len(label) + 6.0


def _shared_row(
    ax: Axes, row: int, core: CoreSchedule, span: float, colors: Mapping[str, tuple[float, float, float, float]]
) -> None:
    for slot in core.slots:
        ax.barh(row, core.switch_ms, left=slot.start_ms - core.switch_ms, height=0.6, color="black", label="switch")
        ax.barh(row, slot.length_ms, left=slot.start_ms, height=0.6, color=colors[slot.subchain], label=slot.subchain)
        if _fits(slot.subchain, slot.length_ms, span):
            ax.text(slot.start_ms + slot.length_ms / 2, row, slot.subchain, ha="center", va="center", fontsize="small")
    end = max((slot.start_ms + slot.length_ms for slot in core.slots), default=0.0)
    if core.period_ms > end:
        ax.barh(
            row,
            core.period_ms - end,
            left=end,
            height=0.6,
            color="white",
            edgecolor="grey",
            hatch="//",
            label="slack",
        )
        if _fits("slack", core.period_ms - end, span):
            ax.text((end + core.period_ms) / 2, row, "slack", ha="center", va="center", fontsize="small")


def _dedicated_row(
    ax: Axes,
    row: int,
    runs: Sequence[SubchainRun],
    span: float,
    colors: Mapping[str, tuple[float, float, float, float]],
) -> None:
    first = runs[0]
    ax.barh(row, span, left=0.0, height=0.6, color=colors[first.name], alpha=0.55, label=first.name)
    for run in runs:
        if span / run.period_ms <= MAX_PERIOD_TICKS:
            ticks = [k * run.period_ms for k in range(1, math.floor(span / run.period_ms) + 1)]
            ax.vlines(ticks, row - 0.3, row + 0.3, color="white", linewidth=1.0)
    label = "; ".join(
        f"{run.name} ({', '.join(run.nodes)}): dedicated, period {run.period_ms:.2f} ms ({1000 / run.period_ms:.3g} Hz)"
        for run in runs
    )
    ax.text(
        span / 2,
        row,
        label,
        ha="center",
        va="center",
        fontsize="small",
        bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.5},
    )


# --------------------------------------------------------------------------- rates.png


def _rates_figure(results: Sequence[PolicyResult], styles: _Styles, title: str, nodes: Sequence[str] | None) -> Figure:
    chosen = list(nodes) if nodes is not None else sorted({node for r in results for node in r.node_done_ms})
    shown, left_out = _first(chosen, "nodes")
    figure, axes = _panels(max(1, len(shown)), 2.6, f"{title}: node rates (runs per {RATE_BIN_S:g} s){left_out}")
    if not shown:
        _note(axes[0], "no nodes to draw")
        return figure
    for ax, node in zip(axes, shown, strict=True):
        ax.set_title(node, loc="left", fontsize="medium")
        drawn: list[float] = []
        for result in results:
            done = result.node_done_ms.get(node)
            if done is None:
                continue
            bins = rate_bins((t / 1000.0 for t in done), result.duration_s)
            if bins:
                edges = [start for start, _ in bins] + [result.duration_s]
                rates = [hz for _, hz in bins]
                color, width = styles.colors[result.policy], styles.widths[result.policy]
                ax.stairs(rates, edges, baseline=None, color=color, linewidth=width, label=result.policy)
                drawn.extend(rates)
        if not drawn:
            _note(ax, "no completion times for this node")
            continue
        if _log_scale(ax, "y", drawn):  # 600 Hz beside 5 Hz: a zero-rate bin drops below the axis
            ax.set_ylim(bottom=0.5 * min(hz for hz in drawn if hz > 0))
        else:
            ax.set_ylim(bottom=0.0)
        ax.set_xlim(left=0.0)
        ax.set_ylabel("Hz")
        ax.set_xlabel("time (s)")
        ax.grid(True, alpha=0.3)
    _outside_legend(figure, axes)
    return figure
