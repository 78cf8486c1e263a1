"""What the explanation says, once, as neutral blocks: headings, paragraphs, tables, a timeline bar, a list.

:func:`report_blocks` turns an :class:`~catanc.explain.analysis.Explanation`
into the report's blocks in reading order; the renderers
(:mod:`catanc.explain.terminal`, :mod:`catanc.explain.markdown`) only lay
them out, so the terminal and ``PLAN.md`` say the same.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from catanc.explain.analysis import (
    BINDING_TOLERANCE,
    EXECUTOR_SPACING,
    DedicatedView,
    Explanation,
    SharedCoreView,
    cores_text,
    runs_per_period,
)
from catanc.model.priorities import ENFORCER_FIFO, RUNNING_FIFO, UNSCHEDULED_FIFO, resting_fifo
from catanc.planning.baseline import BaselineGap
from catanc.text import plural

if TYPE_CHECKING:
    from catanc.planning.types import SubchainPlan

ROW_LIMIT = 12
"""Rows shown in the chain and term tables; the rest are summarised in one line."""

BAR_WIDTH = 64
"""Characters in a shared core's timeline bar."""

SLICE_MARKS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


Align = Literal["left", "right"]


@dataclass(frozen=True)
class Heading:
    """A numbered section's title ("2. Subchains")."""

    text: str


@dataclass(frozen=True)
class Paragraph:
    """One paragraph of prose; ``strong`` for the report's opening line."""

    text: str
    strong: bool = False


@dataclass(frozen=True)
class Preformatted:
    """A line whose spacing carries meaning (a timeline bar): shown verbatim, in Markdown in a code block."""

    text: str


@dataclass(frozen=True)
class Bullets:
    """A list of notes (the warnings)."""

    items: tuple[str, ...]


@dataclass(frozen=True)
class Column:
    header: str
    align: Align = "left"


@dataclass(frozen=True)
class TableBlock:
    """A table: an optional title above it, one cell per column in every row, an optional note below it."""

    columns: tuple[Column, ...]
    rows: tuple[tuple[str, ...], ...]
    title: str | None = None
    footer: str | None = None

    def __post_init__(self) -> None:
        for row in self.rows:
            if len(row) != len(self.columns):
                raise ValueError(f"a row of {len(row)} cells in a table of {len(self.columns)} columns: {row}")


Block = Heading | Paragraph | Preformatted | Bullets | TableBlock
"""One piece of the report, as neutral data: :func:`render` and :func:`render_markdown` only lay it out."""


def _columns(headers: Sequence[str], left: Sequence[str] = ()) -> tuple[Column, ...]:
    """Columns right-aligned (numbers) except those named in ``left``."""
    return tuple(Column(header, "left" if header in left else "right") for header in headers)


# --------------------------------------------------------------------------- the report's blocks


def _ms(value: float) -> str:
    return f"{value:.3f}"


def _rate(period_ms: float) -> str:
    return f"{1000.0 / period_ms:.2f}"


def _share(part: float, whole: float) -> str:
    return f"{part / whole:.1%}" if whole > 0 else "-"


def timeline_bar(view: SharedCoreView, width: int = BAR_WIDTH) -> str:
    """A proportional bar of one period: a letter per subchain's slice, ``|`` switches, ``.`` idle.

    Every slice and a non-empty idle gap get at least one character, so a
    1 ms slice in a 700 ms period still shows.
    """
    total = view.period_ms
    marks = {name: SLICE_MARKS[index % len(SLICE_MARKS)] for index, name in enumerate(view.order)}
    exact = [segment.length_ms / total * width if total > 0 else 0.0 for segment in view.segments]
    counts = [math.floor(x) for x in exact]
    for index in sorted(range(len(exact)), key=lambda i: (-(exact[i] - counts[i]), i)):
        if sum(counts) >= width:
            break
        counts[index] += 1
    for index, segment in enumerate(view.segments):
        if segment.kind != "switch" and segment.length_ms > 0 and counts[index] == 0:
            counts[index] = 1
    while sum(counts) > width:
        largest = max(range(len(counts)), key=lambda i: (counts[i], -i))
        counts[largest] -= 1
    chars = []
    for segment, count in zip(view.segments, counts, strict=True):
        if segment.kind == "switch":
            mark = "|"
        elif segment.kind == "idle":
            mark = "."
        else:
            assert segment.subchain is not None
            mark = marks[segment.subchain]
        chars.append(mark * count)
    return "".join(chars)


def _runs_text(sub: SubchainPlan, batch: bool, length: float, *, spaced: bool = False) -> str:
    """How often ``sub`` runs and is triggered; ``spaced``: its ``k`` is Stage II's executor trade, not a cap."""
    runs = runs_per_period(sub, batch)
    if runs == 1:
        text = "a whole run every period"
    elif runs is not None:
        text = f"one run every {runs} periods ({runs * length:.3f} ms)"
    elif sub.fraction >= 1:
        text = f"{sub.fraction:.3g} runs per period"
    else:
        text = f"one run every {1.0 / sub.fraction:.3g} periods on average"
    if sub.every is not None and sub.every > (runs or 1):
        why = "to free its executor's thread" if spaced else "rate cap"
        text += f"; triggered at its slot every {sub.every} periods ({sub.period_ms:.3f} ms, {why})"
    elif sub.every is not None:
        text += "; triggered at its slot"
    elif sub.period_ms > sub.latency_ms * (1 + BINDING_TOLERANCE):
        text += f"; triggered every {sub.period_ms:.3f} ms on its own clock (rate cap)"
    return text


def _shared_blocks(view: SharedCoreView, explanation: Explanation) -> list[Block]:
    subs = {sub.name: sub for sub in explanation.subchains}
    spaced = {binding.subject for binding in explanation.bindings if binding.kind == EXECUTOR_SPACING}
    title = (
        f"core {view.core}: shared by {plural(len(view.order), 'subchain')}, "
        f"schedule period T = {view.period_ms:.3f} ms ({_rate(view.period_ms)} Hz)"
    )
    marks = "  ".join(f"{SLICE_MARKS[i % len(SLICE_MARKS)]} {name}" for i, name in enumerate(view.order))
    rows = []
    for segment in view.segments:
        if segment.kind == "switch":
            if segment.length_ms <= 0:
                continue
            what, often = f"switch to {segment.subchain}", ""
        elif segment.kind == "idle":
            what, often = f"idle (slack {explanation.schedule.slack:.0%} of T)", ""
        else:
            assert segment.subchain is not None
            sub = subs[segment.subchain]
            what = f"{segment.subchain}: slice f*c = {sub.fraction:.4g} x {explanation.compute_ms[sub.name]:.3f} ms"
            often = _runs_text(sub, sub.name in explanation.batch, view.period_ms, spaced=sub.name in spaced)
        rows.append(
            (_ms(segment.offset_ms), _ms(segment.length_ms), _share(segment.length_ms, view.period_ms), what, often)
        )
    columns = _columns(("offset ms", "length ms", "share of T", "what", "how often"), left=("what", "how often"))
    blocks: list[Block] = [
        TableBlock(columns, tuple(rows), title=title),
        Preformatted(f"{timeline_bar(view)}\n{marks}; | switch, . idle"),
    ]
    if len(view.order) > 1 and not explanation.schedule.stealing:
        blocks.append(Paragraph("No stealing (schedule.stealing: false): each slice is its subchain's."))
    elif len(view.order) > 1:
        ranked = sorted(view.order, key=lambda name: (-subs[name].priority, name))
        blocks.append(
            Paragraph(
                f"Stealing order: {' > '.join(ranked)} (a subchain that is late takes the slice of one after it)."
            )
        )
    return blocks


def _dedicated_line(view: DedicatedView, explanation: Explanation) -> Paragraph:
    sub = next(s for s in explanation.subchains if s.name == view.subchain)
    cores = len(view.cores)
    load = sub.latency_ms / sub.period_ms
    spread = f", {load * sub.threads / cores:.0%} of its {cores} cores" if cores > 1 else ""
    return Paragraph(
        f"{cores_text(view.cores)}: dedicated to {sub.name}, {plural(sub.threads, 'thread')}, "
        f"period {sub.period_ms:.3f} ms ({_rate(sub.period_ms)} Hz), latency {sub.latency_ms:.3f} ms: "
        f"busy {load:.0%} (latency/period){spread}, {explanation.schedule.slack:.0%} slack kept idle"
    )


def _subchain_tables(explanation: Explanation) -> list[TableBlock]:
    """Two tables, so each fits an 80-column editor: where each subchain runs, then its rate and slice."""
    placement, timing = [], []
    for sub in explanation.subchains:
        runs = runs_per_period(sub, sub.name in explanation.batch)
        fraction = f"1/{runs}" if runs is not None and runs > 1 else f"{sub.fraction:.4g}"
        placement.append(
            (
                sub.name,
                " -> ".join(sub.nodes),
                ",".join(str(c) for c in sub.cores) or "-",
                "shared" if sub.shared else "dedicated",
                fifo_levels(sub.shared),
            )
        )
        timing.append(
            (
                sub.name,
                _rate(sub.period_ms),
                _ms(sub.period_ms),
                fraction,
                "-" if sub.every is None else str(sub.every),
                _ms(sub.fraction * explanation.compute_ms[sub.name]) if sub.shared else "-",
                _ms(sub.latency_ms),
            )
        )
    unscheduled = explanation.unscheduled
    own_clock = f" Unscheduled nodes ({', '.join(unscheduled)}): {UNSCHEDULED_FIFO}." if unscheduled else ""
    fifo_note = (
        "FIFO: the SCHED_FIFO levels of a subchain's threads as deployed: at rest (launch.sh sets it) -> in "
        f"its slice (catanc run raises it).{own_clock} catanc run's own threads: {ENFORCER_FIFO}."
    )
    placement_columns = ("subchain", "nodes", "cores", "cores are", "FIFO")
    timing_columns = ("subchain", "rate Hz", "period ms", "fraction", "every k", "slice ms", "latency ms")
    return [
        TableBlock(
            _columns(placement_columns, left=("subchain", "nodes", "cores are", "FIFO")),
            tuple(placement),
            footer=fifo_note,
        ),
        TableBlock(
            _columns(timing_columns, left=("subchain",)),
            tuple(timing),
            title="Rates and slices (a slice is f*c of the schedule period; - on dedicated cores)",
        ),
    ]


def fifo_levels(shared: bool) -> str:
    """The SCHED_FIFO levels of a subchain's threads as deployed (docs/explanation/model.md section 6)."""
    return f"{resting_fifo(shared)}->{RUNNING_FIFO}"


def _chain_table(explanation: Explanation) -> TableBlock:
    chains = explanation.chains
    columns = ("chain", "subchains", "weight", "bound ms", "latency ms", "period ms", "response ms")
    rows = tuple(
        (
            " -> ".join(view.nodes),
            " -> ".join(view.stages) or "-",
            f"{view.weight:g}" if view.weight > 0 else "-",
            f"{view.bound_ms:g}" if view.bound_ms is not None else "-",
            _ms(view.latency_ms),
            _ms(view.period_ms),
            _ms(view.response_ms),
        )
        for view in chains[:ROW_LIMIT]
    )
    footer = None
    if len(chains) > ROW_LIMIT:
        rest = chains[ROW_LIMIT:]
        weighted = math.fsum(view.weight * view.response_ms for view in rest)
        share = _share(weighted, explanation.objective)
        footer = f"... {plural(len(rest), 'more chain')} (together {share} of the objective)"
    return TableBlock(_columns(columns, left=("chain", "subchains")), rows, footer=footer)


def _binding_table(explanation: Explanation) -> Block:
    if not explanation.bindings:
        return Paragraph("Binding constraints: none (every rate and chain bound has room, no slice is at a limit)")
    return TableBlock(
        (Column("constraint"), Column("on"), Column("detail")),
        tuple((item.kind, item.subject, item.detail) for item in explanation.bindings),
        title="Binding constraints",
    )


def _term_table(explanation: Explanation) -> TableBlock:
    terms = sorted(explanation.terms, key=lambda t: -t.contribution)
    total = explanation.objective
    columns = ("term", "spec", "weight", "value ms", "weight x value", "share")
    rows = tuple(
        (
            term.label,
            term.origin,
            f"{term.weight:g}",
            _ms(term.value_ms),
            _ms(term.contribution),
            _share(term.contribution, total),
        )
        for term in terms[:ROW_LIMIT]
    )
    footer = None
    if len(terms) > ROW_LIMIT:
        rest = math.fsum(t.contribution for t in terms[ROW_LIMIT:])
        footer = f"... {plural(len(terms) - ROW_LIMIT, 'more term')} ({_share(rest, total)} of the objective)"
    return TableBlock(
        _columns(columns, left=("term", "spec")), rows, title=f"Objective terms: {total:.3f} ms in all", footer=footer
    )


def _baseline_section(explanation: Explanation) -> list[Block]:
    baseline = explanation.baseline
    if isinstance(baseline, BaselineGap):
        return [Paragraph(f"Baseline: {baseline.reason}; nothing to compare with.")]
    listed = ", ".join(f"{row.node} {row.rate_hz:g} Hz" for row in baseline.nodes.values() if row.rate_hz is not None)
    inherited = ", ".join(f"{row.node} on {row.trigger}" for row in baseline.nodes.values() if row.trigger is not None)
    cores = plural(baseline.cores, "core")
    blocks: list[Block] = [
        Paragraph(
            f"Baseline: the spec's hand-tuned timers ({listed})"
            + (f", the rest on their inputs ({inherited})" if inherited else "")
            + f", CPU shared fairly by Linux over {cores}: utilisation {baseline.utilisation:.1%}, "
            f"latency = compute / (1 - utilisation)."
        ),
    ]
    if baseline.overloaded:
        blocks.append(
            Paragraph(
                f"The baseline is overloaded: its rates ask for {baseline.utilisation:.1%} of {cores}, which Linux "
                f"cannot sustain; every period is stretched x{baseline.stretch:.3f} and latencies are taken "
                f"at 95% utilisation."
            )
        )
    pairs = sorted(
        zip(baseline.terms, explanation.terms, strict=True),
        key=lambda pair: -max(pair[0].contribution, pair[1].contribution),
    )
    rows = [
        (base.label, f"{base.weight:g}", _ms(base.value_ms), _ms(mine.value_ms), _ratio(base.value_ms, mine.value_ms))
        for base, mine in pairs[:ROW_LIMIT]
    ]
    if len(pairs) > ROW_LIMIT:
        rows.append((f"... {plural(len(pairs) - ROW_LIMIT, 'more term')}", "", "", "", ""))
    rows.append(
        (
            "objective (weighted sum)",
            "",
            _ms(baseline.objective),
            _ms(explanation.objective),
            _ratio(baseline.objective, explanation.objective),
        )
    )
    columns = _columns(("term", "weight", "baseline ms", "plan ms", "baseline / plan"), left=("term",))
    blocks.append(TableBlock(columns, tuple(rows), title="Baseline versus plan (same model)"))
    return blocks


def _ratio(base: float, mine: float) -> str:
    return f"{base / mine:.2f}x" if mine > 0 else "-"


def report_blocks(explanation: Explanation) -> list[Block]:
    """The whole report, in reading order, as blocks: the one place that decides what it says."""
    scale = (
        "every bound as written"
        if explanation.constraint_scale == 1.0
        else f"every bound scaled by {explanation.constraint_scale:.4g}"
    )
    cores = plural(explanation.cores, "core")
    blocks: list[Block] = [
        Paragraph(f"{explanation.app} on {cores}: objective {explanation.objective:.3f} ms, {scale}.", strong=True),
        Paragraph(explanation.allocation),
        *(Paragraph(note) for note in explanation.executors),
        *([Paragraph(explanation.machine)] if explanation.machine else []),
        Heading("1. Cores: one schedule period each"),
    ]
    for view in explanation.shared:
        blocks += _shared_blocks(view, explanation)
    blocks += [_dedicated_line(view, explanation) for view in explanation.dedicated]
    blocks += [Paragraph(f"core {core}: idle (no subchain runs here)") for core in explanation.idle_cores]
    blocks += [Heading("2. Subchains"), *_subchain_tables(explanation)]
    blocks += [Paragraph(note) for note in explanation.offered]
    count = len(explanation.chains)
    chains = f"3. Chains ({count}, the most weighted first)" if count > 1 else f"3. Chains ({count})"
    blocks += [Heading(chains), _chain_table(explanation)]
    blocks += [Heading("4. What binds and what dominates"), _binding_table(explanation), _term_table(explanation)]
    blocks.append(Heading("5. Warnings"))
    blocks.append(Bullets(explanation.warnings) if explanation.warnings else Paragraph("none"))
    blocks.append(Heading("6. Baseline"))
    blocks += _baseline_section(explanation)
    if explanation.processes:
        blocks += [Heading("7. Processes"), _process_table(explanation)]
    return blocks


def _process_table(explanation: Explanation) -> TableBlock:
    """Each process the launchers start: its nodes, the union of their cores, the highest of their levels, and
    whether its nodes are planned as one executor (one thread) and why."""
    rows = tuple(
        (view.key, ", ".join(view.nodes), ",".join(str(c) for c in view.cores) or "-", str(view.level), view.threads)
        for view in explanation.processes
    )
    return TableBlock(
        _columns(("process", "nodes", "cores", "FIFO", "threads"), left=("process", "nodes", "threads")),
        rows,
        footer="cores: the union of its nodes' cores; FIFO: the highest of their resting levels, at launch.",
    )
