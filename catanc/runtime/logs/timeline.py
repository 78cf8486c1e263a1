"""The timeline plot of ``catanc report --plot``: a run's planned and measured rates, compute times, re-plans."""

from __future__ import annotations

from pathlib import Path

from catanc.control.run_summary import RATE_BIN_S, RunSummary, rate_bins
from catanc.errors import OutputError


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
            if any(p.as_run_hz is not None for p in sub.planned):  # what an executor's thread leaves of it
                kept = [p.expected_hz for p in sub.planned] + [sub.planned[-1].expected_hz]
                ax.step(xs, kept, where="post", color="C3", linestyle=":", linewidth=1.2, label="planned as run")
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
