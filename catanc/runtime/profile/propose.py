"""Compute profiles from measurements: what ``catanc profile`` proposes for a spec, from a ``catanc run`` log.

Pure: :func:`~catanc.runtime.logs.samples.read_samples` turns a log's text into each node's
compute samples, :func:`propose` turns those into a proposal per scheduled node of a spec, :func:`deviations`
says where a spec is more than a tolerance off, and :func:`spec_edits` says which values of
the spec's text to rewrite (:mod:`catanc.spec.profile_edit` rewrites them).

What is proposed, per scheduled node (``q`` = :attr:`~catanc.spec.language.Runtime.percentile`,
95 by default, the statistic the runtime plans with: :mod:`catanc.control.measure`):

- **compute_ms**: the ``q``-th percentile (:func:`~catanc.control.measure.percentile`) of the
  node's one-thread compute times, the ``ms`` of the log's ``compute`` samples: what the
  enforcer recorded for planning.  Where the node ran on one thread at least
  :data:`MIN_SAMPLES` times, only those runs count (a run on several threads was converted to
  one-thread time with the spec's speedup, which is what is being measured).
- **modes**, where the samples are clearly multimodal (:func:`find_modes`): split where the
  logs of the samples separate best (Otsu's rule), each side keeping at least
  :data:`MIN_MODE_SHARE` of the samples (and :data:`MIN_MODE_SAMPLES`), if the upper side's
  5th percentile is at least :data:`MODE_SEPARATION` times the lower side's 95th (a few stray
  samples in between do not hide two modes; one wide mode is never split); at most
  :data:`MAX_MODES` modes.  The groups are then regrouped by the runtime's own rule (each
  sample to the mode time nearest on a log scale, :func:`~catanc.control.measure.split_modes`)
  until they settle, so the runtime sees the modes proposed.  Each mode's ``ms`` is the
  ``q``-th percentile of its samples and its ``share`` the fraction of samples in it: then
  the spec's planning figure (share-weighted mean) is the runtime's estimate of the whole log.
  The spec language's modes are exactly these ``{share, ms}`` pairs.
- **threads.speedup**, where runs used several threads and the spec lists speedups:
  ``speedup(k) = P(one-thread times) / P(times of the runs on k threads)`` (``P`` the same
  percentile; a run's time on ``k`` threads is its own figure, its wall time), so that
  ``compute_ms / speedup(k)`` is the ``k``-thread runs' percentile, as the planner's Eq. 1
  uses it.  Measured only for thread counts with :data:`MIN_SAMPLES` runs, and only with as
  many one-thread runs; the others keep the spec's value.

What the kernel said is reported beside each node (:class:`KernelCheck`): the enforcer also
measures every 8th run of a head by its thread's CPU count (:mod:`catanc.runtime.enforcer.runs`), which
holds the client's own work around the callback, and keeps the node's figure where the count
makes it plausible (:func:`~catanc.control.measure.reconcile`); the summary says by how much the
count exceeded the node's figure and on how many runs it replaced it.

And per edge inside a subchain, its **hop** (``hops_ms``, docs/explanation/model.md section 5): the p95
of the delays from the producer's end to the consumer's start that the enforcer measured (its
last ``hop_by_edge`` figures: the latest 1024 hops of each edge), where it measured at least
:data:`MIN_SAMPLES`.  The planner adds it to the subchain's ``c(S)``.  ``--check`` flags a hop
that is off by more than the tolerance *and* :data:`HOP_TOLERANCE_MS` (a spec without hops
reads as 0 ms each: catanc's own trigger hop, ~0.05 ms, is no drift).  Edges between
subchains are not proposed: no plan counts them.

And per subchain head, its **dispatch** (``dispatch_ms``): the p95 of the delays from the enforcer's
trigger to the head's start (its last ``dispatch_by_head`` figures), where it measured at least
:data:`MIN_SAMPLES`, written and checked as a hop is (a head not in the spec reads as 0 ms).  Not for a
head whose executor thread also runs another subchain's nodes (nav2d's GM beside GL in the Mapper):
its trigger waits there for their runs too (11 ms p95 for GM behind GL's 12 ms mode), which is no
cost of its dispatch; the plan's executor model (``explain``) speaks of that wait.

``--check`` also fails where a chain with a bound (``max_response_ms``) was measured slower than
it: the p95 of its response from origins (:func:`~catanc.control.run_summary.chain_response`,
what ``catanc report`` shows), over at least :data:`MIN_SAMPLES` runs, above the bound.  The p95,
not the maximum: the plan holds the bound with p95 compute times, and one run preempted by
something outside the plan would fail a maximum.  Where the chain's last scheduled node reports no
ages, the figure stops at an earlier node: a lower bound, which fails only when even it is over.

Numbers are rounded to what is written (compute times and hops to 4 significant digits, shares
and speedups to 2 decimals), so a spec written from a proposal checks clean against it.

The log must have samples for every scheduled node (and be readable:
:mod:`catanc.runtime.logs.samples`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from catanc.control.measure import MIN_PLANNING_MS, percentile, split_modes
from catanc.control.run_summary import chain_response
from catanc.errors import CatancError, FieldPath, format_path
from catanc.model.problem import Problem
from catanc.runtime.enforcer.costs import edge_key
from catanc.runtime.logs.samples import LogSamples, MeasurementsError, Sample, read_samples
from catanc.runtime.logs.writer import BATCHED
from catanc.spec.language import ModalCompute, Spec, parse_arrow
from catanc.spec.profile_edit import Edit
from catanc.spec.speedup import threads_and_speedup

MIN_SAMPLES = 10
"""Fewest samples a figure is measured from (a node's compute time, a thread count's speedup)."""
MODE_SEPARATION = 2.0
"""Two modes are clear when the upper one's 5th percentile is at least twice the lower one's 95th ..."""
EDGE_PERCENTILE = 5.0
MIN_MODE_SHARE = 0.05
"""... and each mode keeps at least 5% of the samples ..."""
MIN_MODE_SAMPLES = 5
"""... and at least 5 of them."""
MAX_MODES = 4
REGROUPINGS = 8
"""The runtime's regrouping of modes settles within this many rounds, or the modes are not clear."""

DEFAULT_TOLERANCE = 0.15
"""``--check``: a planning figure more than 15% off the measured one fails."""

HOP_TOLERANCE_MS = 0.1
"""``--check``: a hop is off only where it is also more than 0.1 ms from the spec's."""
HOP_DECIMALS = 4
"""A hop's smallest step written (the log keeps hops to 0.1 us)."""

SIGNIFICANT_DIGITS = 4
LOGGED_DECIMALS = dict(BATCHED["compute"][1])["ms"] or 0
"""The decimals the log keeps of a sample's ``ms`` (the node's own figure is written in full)."""
SHARE_DECIMALS = 2
SPEEDUP_DECIMALS = 2


# --------------------------------------------------------------------------- modes


def find_modes(
    samples: Sequence[float],
    *,
    separation: float = MODE_SEPARATION,
    min_share: float = MIN_MODE_SHARE,
    min_count: int = MIN_MODE_SAMPLES,
    max_modes: int = MAX_MODES,
) -> list[list[float]]:
    """``samples`` sorted and split into modes (the module's rule, before the runtime's regrouping).

    Each mode is split in two where the split best separates its samples on a log scale (Otsu's
    rule: the largest between-group variance of the logs, each side keeping at least
    ``max(min_count, ceil(min_share * n))`` of the ``n`` samples), if the upper side's
    :data:`EDGE_PERCENTILE`-th percentile is at least ``separation`` times the lower side's
    ``100 - EDGE_PERCENTILE``-th: a few stray samples in between (a run preempted, a wake-up
    counted) do not hide two modes, and one wide mode is never split.  The best separated split
    first, while there are fewer than ``max_modes`` modes.
    """
    ordered = sorted(samples)
    least = max(min_count, math.ceil(min_share * len(ordered)), 1)
    groups = [ordered]
    while len(groups) < max_modes:
        best: tuple[float, int, int] | None = None  # (separation, group, split index)
        for g, group in enumerate(groups):
            i = _best_split(group, least)
            if i is None:
                continue
            ratio = _floored(percentile(group[i:], EDGE_PERCENTILE)) / _floored(
                percentile(group[:i], 100.0 - EDGE_PERCENTILE)
            )
            if ratio >= separation and (best is None or ratio > best[0]):
                best = (ratio, g, i)
        if best is None:
            break
        _, g, i = best
        groups[g : g + 1] = [groups[g][:i], groups[g][i:]]
    return groups


def _floored(ms: float) -> float:
    return max(ms, MIN_PLANNING_MS)


def _best_split(ordered: Sequence[float], least: int) -> int | None:
    """Where sorted ``ordered`` splits best on a log scale (Otsu): the index of the upper side's first sample."""
    count = len(ordered)
    if count < 2 * least:
        return None
    logs = [math.log(_floored(x)) for x in ordered]
    prefix = [0.0]
    for value in logs:
        prefix.append(prefix[-1] + value)
    best, where = -1.0, None
    for i in range(least, count - least + 1):
        low, high = prefix[i] / i, (prefix[count] - prefix[i]) / (count - i)
        score = i * (count - i) * (high - low) ** 2
        if score > best:
            best, where = score, i
    return where


# --------------------------------------------------------------------------- proposals


@dataclass(frozen=True)
class Mode:
    share: float
    ms: float
    count: int


@dataclass(frozen=True)
class KernelCheck:
    """What the kernel's count said of a node's one-thread runs it checked (a head's every 8th run)."""

    runs: int  # runs checked
    replaced: int  # runs where the kernel's count stood in for the node's figure (implausible)
    extra_ms: float  # the median of the kernel's count less the node's figure: the client's own work per run


@dataclass(frozen=True)
class Proposal:
    """What the measurements say one node's profile is."""

    node: str
    count: int  # samples the compute time is measured from
    ms: float  # the percentile of those samples (a modal node's too, for reference)
    modes: tuple[Mode, ...] = ()  # () unless clearly multimodal
    speedups: tuple[float | None, ...] = ()  # per thread count 1..threads.max: measured, or None; () for one thread
    threads: Mapping[int, int] = field(default_factory=dict)  # thread count -> runs
    notes: tuple[str, ...] = ()
    kernel: KernelCheck | None = None  # None: the kernel checked none of its runs

    @property
    def planning_ms(self) -> float:
        """The figure planning uses: the time, or the share-weighted mean of the modes."""
        if self.modes:
            return math.fsum(mode.share * mode.ms for mode in self.modes)
        return self.ms


def propose(spec: Spec, measured: LogSamples) -> dict[str, Proposal]:
    """A proposal per scheduled node of ``spec``; :class:`MeasurementsError` naming every node with too few samples."""
    q = spec.runtime.percentile
    proposals: dict[str, Proposal] = {}
    missing: list[str] = []
    for name, node in spec.nodes.items():
        if not node.scheduled:
            continue
        samples = measured.samples.get(name, ())
        if len(samples) < MIN_SAMPLES:
            where = _where(spec, ("nodes", name))
            got = "no compute samples" if not samples else f"only {len(samples)} compute samples"
            missing.append(f"{where}nodes.{name}: {got} in {measured.file} (at least {MIN_SAMPLES} needed)")
            continue
        proposals[name] = _propose_node(name, samples, q, node.threads.speedups, node.threads.speedup is not None)
    if missing:
        hint = "did the node run (registered, triggered) for long enough? a longer --duration gives more"
        raise MeasurementsError("\n".join(missing) + f"\n({hint})")
    return proposals


def propose_hops(spec: Spec, measured: LogSamples) -> dict[tuple[str, str], float]:
    """Per edge inside a subchain of ``spec`` with :data:`MIN_SAMPLES` hops measured: their p95, as written."""
    inside = {pair for nodes in spec.subchains.values() for pair in itertools.pairwise(nodes)}
    return {
        edge: float(format_hop(figures.p95_ms))
        for edge, figures in sorted(measured.hops.items())
        if edge in inside and figures.count >= MIN_SAMPLES
    }


def propose_dispatches(spec: Spec, problem: Problem, measured: LogSamples) -> dict[str, float]:
    """Per subchain head of ``spec`` with :data:`MIN_SAMPLES` dispatches measured: their p95, as written; none for a
    head whose thread runs another subchain's nodes too (:func:`thread_sharing_heads`)."""
    heads = {nodes[0] for nodes in spec.subchains.values() if nodes} - set(thread_sharing_heads(problem))
    return {
        head: float(format_hop(figures.p95_ms))
        for head, figures in sorted(measured.dispatches.items())
        if head in heads and figures.count >= MIN_SAMPLES
    }


def thread_sharing_heads(problem: Problem) -> dict[str, tuple[str, ...]]:
    """Each subchain head whose executor thread runs nodes of other subchains too: those subchains."""
    found = {}
    for executor in problem.executors:
        for sub in problem.subchains:
            if sub.nodes[0] in executor.nodes and len(executor.subchains) > 1:
                found[sub.nodes[0]] = tuple(other for other in executor.subchains if other != sub.name)
    return found


def dispatch_deviations(spec: Spec, dispatches: Mapping[str, float], tolerance: float) -> list[str]:
    """Where ``spec``'s dispatches are off the measured ones by more than ``tolerance`` and :data:`HOP_TOLERANCE_MS`."""
    found = []
    for head, measured in sorted(dispatches.items()):
        written = spec.dispatch_ms.get(head, 0.0)
        if _delay_off(measured, written, tolerance):
            where = _where(spec, ("dispatch_ms", head) if head in spec.dispatch_ms else ("subchains",))
            found.append(_delay_deviation(f"{where}dispatch_ms.{head}", written, measured, tolerance))
    return found


def _delay_off(measured: float, written: float, tolerance: float) -> bool:
    """Whether a measured hop or dispatch is off the spec's by more than ``tolerance`` and :data:`HOP_TOLERANCE_MS`."""
    return abs(measured - written) > max(tolerance * written, HOP_TOLERANCE_MS)


def _delay_deviation(field: str, written: float, measured: float, tolerance: float) -> str:
    return (
        f"{field}: {written:g} ms planned, {measured:g} ms measured "
        f"(more than {tolerance:.0%} and {HOP_TOLERANCE_MS:g} ms off)"
    )


def dispatch_edits(spec: Spec, dispatches: Mapping[str, float]) -> tuple[list[Edit], list[tuple[str, str]]]:
    """The spec's dispatches to rewrite where it gives them, and the ``(head, value)`` entries to add."""
    edits, entries = [], []
    for head, ms in sorted(dispatches.items()):
        if head in spec.dispatch_ms:
            edits.append(Edit(("dispatch_ms", head), format_hop(ms)))
        else:
            entries.append((head, format_hop(ms)))
    return edits, entries


def dispatch_lines(spec: Spec, dispatches: Mapping[str, float], measured: LogSamples) -> tuple[str, ...]:
    """One line per measured head: samples, the spec's dispatch and the measured p95."""
    return tuple(
        f"  dispatch {head}: {measured.dispatches[head].count} samples; spec {spec.dispatch_ms.get(head, 0.0):.4g} ms, "
        f"measured p95 {ms:.4g} ms"
        for head, ms in sorted(dispatches.items())
    )


def unproposed_dispatch_lines(problem: Problem, measured: LogSamples) -> tuple[str, ...]:
    """One line per measured head whose thread runs other subchains' nodes: why its dispatch is not proposed."""
    sharing = thread_sharing_heads(problem)
    return tuple(
        f"  dispatch {head}: {figures.count} samples, p95 {figures.p95_ms:.4g} ms: not proposed, its thread runs "
        f"subchain{'s' if len(sharing[head]) > 1 else ''} {', '.join(sharing[head])} too (the delay holds their runs)"
        for head, figures in sorted(measured.dispatches.items())
        if head in sharing
    )


def spec_hops(spec: Spec) -> dict[tuple[str, str], tuple[str, float]]:
    """The spec's ``hops_ms`` by edge: the key as written, and the hop."""
    return {parse_arrow(key): (key, ms) for key, ms in spec.hops_ms.items()}


def format_hop(ms: float) -> str:
    """A hop as written in a spec: 4 significant digits, at most :data:`HOP_DECIMALS` decimals, 0 for none."""
    if ms <= 0 or round(ms, HOP_DECIMALS) == 0:
        return "0"
    decimals = min(HOP_DECIMALS, max(0, SIGNIFICANT_DIGITS - 1 - math.floor(math.log10(ms))))
    text = f"{ms:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def _where(spec: Spec, path: FieldPath) -> str:
    source = spec.source
    return "" if source is None else f"{source.locate(path, at_key=True)}: "


def _propose_node(
    name: str, samples: Sequence[Sample], q: float, spec_speedups: tuple[float, ...], listed: bool
) -> Proposal:
    threads: dict[int, int] = {}
    for sample in samples:
        threads[sample.threads] = threads.get(sample.threads, 0) + 1
    notes: list[str] = []
    single = [s.ms for s in samples if s.threads == 1]
    if len(single) >= MIN_SAMPLES:
        base = single
    else:
        base = [s.ms for s in samples]
        if single != base:
            notes.append(
                f"too few one-thread runs ({len(single)}): compute_ms from every run, converted with the spec's speedup"
            )
    ms = round_ms(percentile(base, q))
    modes = _modes(base, q)
    speedups: tuple[float | None, ...] = ()
    if len(spec_speedups) > 1:
        speedups = _speedups(samples, single, q, spec_speedups)
        if any(s is not None for s in speedups[1:]) and not listed:
            notes.append("threads.speedup is not listed in the spec (perfect scaling assumed): add it by hand")
        elif len(single) < MIN_SAMPLES and any(k > 1 for k in threads):
            notes.append("speedups not measured: they need one-thread runs too")
        elif all(k == 1 for k in threads):
            notes.append("every run used one thread: speedups not measured (the spec's are kept)")
    kernel = _kernel_check(samples)
    if kernel is not None and kernel.replaced:
        notes.append(
            f"the kernel's count stood in for the node's own figure on {kernel.replaced} of {kernel.runs} checked runs "
            "(more CPU than it reported, beyond the client's own work, or less than it claimed)"
        )
    return Proposal(name, len(base), ms, modes, speedups, dict(sorted(threads.items())), tuple(notes), kernel)


def _kernel_check(samples: Sequence[Sample]) -> KernelCheck | None:
    """The node's one-thread runs the kernel checked: how many, on how many its count replaced the node's figure,
    and by how much the count exceeded the node's figure (the median)."""
    checked = [(s.ms, s.wall_ms, s.kernel_ms) for s in samples if s.threads == 1 and s.kernel_ms is not None]
    pairs = [(ms, own, kernel) for ms, own, kernel in checked if own is not None]
    if not pairs:
        return None
    replaced = sum(1 for ms, own, _ in pairs if ms != round(own, LOGGED_DECIMALS))
    return KernelCheck(len(pairs), replaced, percentile([kernel - own for _, own, kernel in pairs], 50.0))


def _modes(samples: Sequence[float], q: float) -> tuple[Mode, ...]:
    """The modes of ``samples`` as the runtime will see them: :func:`find_modes`, then regrouped by the runtime's
    rule (each sample to the mode time nearest on a log scale) until the groups stop changing."""
    groups: Sequence[Sequence[float]] = find_modes(samples)
    least = max(MIN_MODE_SAMPLES, math.ceil(MIN_MODE_SHARE * len(samples)))
    for _ in range(REGROUPINGS):
        if len(groups) < 2 or any(len(group) < least for group in groups):
            return ()
        times = [percentile(group, q) for group in groups]
        if len(set(times)) < len(times):
            return ()
        regrouped = split_modes(samples, times)
        if [len(group) for group in regrouped] == [len(group) for group in groups]:
            shares = round_shares([len(group) / len(samples) for group in groups])
            return tuple(
                Mode(share, round_ms(ms), len(group)) for share, ms, group in zip(shares, times, groups, strict=True)
            )
        groups = regrouped
    return ()  # the runtime's groups keep moving: not clearly modes


def _speedups(
    samples: Sequence[Sample], single: Sequence[float], q: float, spec_speedups: tuple[float, ...]
) -> tuple[float | None, ...]:
    """Per thread count 1..max: the measured speedup (1.0 for one thread), or None where not measurable."""
    measured: list[float | None] = [1.0]
    one = percentile(single, q) if len(single) >= MIN_SAMPLES else None
    for k in range(2, len(spec_speedups) + 1):
        walls = [_wall(s, spec_speedups) for s in samples if s.threads == k]
        if one is None or len(walls) < MIN_SAMPLES:
            measured.append(None)
            continue
        at_k = percentile(walls, q)
        speedup = round(one / at_k, SPEEDUP_DECIMALS) if at_k > 0 else 0.0
        measured.append(speedup if speedup > 0 else None)  # a spec's speedup is > 0: too slow to write is unknown
    return tuple(measured)


def _wall(sample: Sample, spec_speedups: tuple[float, ...]) -> float:
    """A several-thread run's time: its own figure, else its one-thread time divided back by the spec's speedup."""
    if sample.wall_ms is not None:
        return sample.wall_ms
    _, speedup = threads_and_speedup(spec_speedups, sample.threads)
    return sample.ms / speedup


def round_ms(ms: float) -> float:
    """``ms`` (floored at :data:`MIN_PLANNING_MS`, the runtime's floor) to :data:`SIGNIFICANT_DIGITS` digits."""
    return float(format_ms(ms))


def format_ms(ms: float) -> str:
    """``ms`` as written in a spec: 4 significant digits, no exponent, no trailing zeros (``25``, ``0.2123``)."""
    value = max(ms, MIN_PLANNING_MS)
    decimals = max(0, SIGNIFICANT_DIGITS - 1 - math.floor(math.log10(value)))
    text = f"{value:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def round_shares(shares: Sequence[float]) -> list[float]:
    """Shares to :data:`SHARE_DECIMALS` decimals summing to 1 (largest remainders get the rounding's hundredths)."""
    scale = 10**SHARE_DECIMALS
    floors = [math.floor(share * scale) for share in shares]
    left = scale - sum(floors)
    order = sorted(range(len(shares)), key=lambda i: (-(shares[i] * scale - floors[i]), i))
    for i in order[:left]:
        floors[i] += 1
    return [units / scale for units in floors]


# --------------------------------------------------------------------------- the spec against them


def deviations(spec: Spec, proposals: Mapping[str, Proposal], tolerance: float) -> list[str]:
    """Where ``spec`` is more than ``tolerance`` (relative) off ``proposals``: each a message naming the node."""
    found = []
    for name, proposal in sorted(proposals.items()):
        node = spec.nodes[name]
        where = _where(spec, ("nodes", name, "compute_ms"))
        written, measured = node.mean_compute_ms, proposal.planning_ms
        off = (measured - written) / written
        if abs(off) > tolerance:
            found.append(
                f"{where}nodes.{name}.compute_ms: {written:g} ms planned, {measured:g} ms measured "
                f"({off:+.0%}, more than {tolerance:.0%} off)"
            )
        for k, value in enumerate(proposal.speedups, start=1):
            spec_value = node.threads.speedups[k - 1]
            if value is None or k == 1:
                continue
            off = (value - spec_value) / spec_value
            if abs(off) > tolerance:
                found.append(
                    f"{_where(spec, ('nodes', name, 'threads'))}nodes.{name}.threads.speedup[{k - 1}]: "
                    f"{spec_value:g} in the spec, {value:g} measured ({off:+.0%}, more than {tolerance:.0%} off)"
                )
    return found


def hop_deviations(spec: Spec, hops: Mapping[tuple[str, str], float], tolerance: float) -> list[str]:
    """Where ``spec``'s hops are off the measured ``hops`` by more than ``tolerance`` and :data:`HOP_TOLERANCE_MS`."""
    written = spec_hops(spec)
    found = []
    for (a, b), measured in sorted(hops.items()):
        key, hop = written.get((a, b), (edge_key(a, b), 0.0))
        if _delay_off(measured, hop, tolerance):
            where = _where(spec, ("hops_ms", key)) if (a, b) in written else _where(spec, ("edges",))
            found.append(_delay_deviation(f"{where}hops_ms.{key}", hop, measured, tolerance))
    return found


def chain_deviations(spec: Spec, problem: Problem, measured: LogSamples) -> list[str]:
    """Each bounded chain whose response from origins was measured (p95) above its ``max_response_ms``."""
    found = []
    for bound in problem.response_bounds:
        chain = problem.chains[bound.chain]
        at, whole, response = chain_response(chain.nodes, problem.last_scheduled(chain.nodes), measured.ages)
        if response is None or response.count < MIN_SAMPLES or response.p95_ms <= bound.max_response_ms:
            continue
        part = "" if whole else ", part of the chain: its last scheduled node reports no origins"
        found.append(
            f"{_where(spec, bound.origin)}{format_path(bound.origin)}: chain {chain.label}: p95 "
            f"{response.p95_ms:.4g} ms from origins (at {at}, {response.count} runs{part}) over its "
            f"max_response_ms {bound.max_response_ms:g}"
        )
    return found


def chain_lines(problem: Problem, measured: LogSamples) -> tuple[str, ...]:
    """One line per bounded chain measured from origins: p50, p95, max, where, against its bound."""
    lines = []
    for bound in problem.response_bounds:
        chain = problem.chains[bound.chain]
        at, whole, response = chain_response(chain.nodes, problem.last_scheduled(chain.nodes), measured.ages)
        if response is None:
            continue
        part = "" if whole else " (part of the chain)"
        lines.append(
            f"  chain {chain.label}: {response.count} runs at {at}{part}; from origins p50 {response.p50_ms:.4g}, "
            f"p95 {response.p95_ms:.4g}, max {response.max_ms:.4g} ms; bound {bound.max_response_ms:g} ms"
        )
    return tuple(lines)


def hop_edits(spec: Spec, hops: Mapping[tuple[str, str], float]) -> tuple[list[Edit], list[tuple[str, str]]]:
    """The spec's hops to rewrite where it gives them, and the ``(key, value)`` entries to add where it does not."""
    written = spec_hops(spec)
    edits, entries = [], []
    for edge, ms in sorted(hops.items()):
        if edge in written:
            edits.append(Edit(("hops_ms", written[edge][0]), format_hop(ms)))
        else:
            entries.append((edge_key(*edge), format_hop(ms)))
    return edits, entries


def spec_edits(spec: Spec, proposals: Mapping[str, Proposal]) -> list[Edit]:
    """The values of ``spec``'s text to rewrite so that it says what ``proposals`` do."""
    edits: list[Edit] = []
    for name, proposal in sorted(proposals.items()):
        node = spec.nodes[name]
        path: FieldPath = ("nodes", name, "compute_ms")
        compute = node.compute_ms
        if proposal.modes and isinstance(compute, ModalCompute) and len(compute.modes) == len(proposal.modes):
            for i, mode in enumerate(proposal.modes):
                edits.append(Edit((*path, "modes", i, "share"), format_share(mode.share)))
                edits.append(Edit((*path, "modes", i, "ms"), format_ms(mode.ms)))
        elif proposal.modes:
            edits.append(Edit(path, modes_text(proposal.modes), whole=True))
        else:
            edits.append(Edit(path, format_ms(proposal.ms), whole=isinstance(compute, ModalCompute)))
        if node.threads.speedup is not None:
            for k, value in enumerate(proposal.speedups):
                if k > 0 and value is not None:
                    edits.append(Edit(("nodes", name, "threads", "speedup", k), format_speedup(value)))
    return edits


def format_share(share: float) -> str:
    return f"{share:.{SHARE_DECIMALS}f}".rstrip("0").rstrip(".")


def format_speedup(speedup: float) -> str:
    text = f"{speedup:.{SPEEDUP_DECIMALS}f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def modes_text(modes: Sequence[Mode]) -> str:
    """A flow mapping of modes, as the specs write them: ``{modes: [{share: 0.8, ms: 1}, ...]}``."""
    items = ", ".join(f"{{share: {format_share(m.share)}, ms: {format_ms(m.ms)}}}" for m in modes)
    return f"{{modes: [{items}]}}"


def matches(spec: Spec, proposals: Mapping[str, Proposal]) -> list[str]:
    """Nodes of ``spec`` whose profile is not exactly what ``proposals`` say (after :func:`spec_edits`: none)."""
    wrong = []
    for name, proposal in proposals.items():
        node = spec.nodes[name]
        compute = node.compute_ms
        if proposal.modes:
            said = tuple((m.share, m.ms) for m in compute.modes) if isinstance(compute, ModalCompute) else ()
            ok = said == tuple((m.share, m.ms) for m in proposal.modes)
        else:
            ok = not isinstance(compute, ModalCompute) and compute == proposal.ms
        if node.threads.speedup is not None:
            ok = ok and all(
                value is None or node.threads.speedups[k] == value for k, value in enumerate(proposal.speedups)
            )
        if not ok:
            wrong.append(name)
    return sorted(wrong)


# --------------------------------------------------------------------------- the whole command, without its I/O


@dataclass(frozen=True)
class Profiled:
    """What ``catanc profile`` found: a summary per node, the spec rewritten, its diff, where it is off."""

    proposals: Mapping[str, Proposal]
    hops: Mapping[tuple[str, str], float]  # measured hop per edge inside a subchain (p95, as written)
    dispatches: Mapping[str, float]  # measured dispatch per subchain head (p95, as written)
    summary: tuple[str, ...]  # one line per node, then its notes; one per hop
    text: str  # the spec's text with the proposals written in
    diff: str  # unified diff of the spec's text to ``text`` ("" when they are the same)
    off: tuple[str, ...]  # :func:`deviations` of the spec as it is


def profile_spec(spec_text: str, spec_file: str, log_text: str, log_file: str, *, tolerance: float) -> Profiled:
    """The spec's text against the log's measurements; :class:`SpecError` or :class:`MeasurementsError` if unusable.

    The rewritten text is read back and must say exactly what was proposed (else nothing is
    proposed for writing: an internal error, never a half-edited spec).
    """
    import difflib  # noqa: PLC0415 - only the command needs it

    from catanc.model.load import check_text  # noqa: PLC0415 - the spec's meaning pass, as validate runs it
    from catanc.spec.profile_edit import add_entries, apply_edits  # noqa: PLC0415

    spec, problem = check_text(spec_text, spec_file)
    measured = read_samples(log_text, log_file)
    proposals = propose(spec, measured)
    hops = propose_hops(spec, measured)
    dispatches = propose_dispatches(spec, problem, measured)
    source = spec.source
    if source is None:  # pragma: no cover - check_text always keeps the source map
        raise MeasurementsError(f"{spec_file}: no source positions to edit")
    rewrites, entries = hop_edits(spec, hops)
    dispatch_rewrites, dispatch_entries = dispatch_edits(spec, dispatches)
    text = apply_edits(spec_text, source, [*spec_edits(spec, proposals), *rewrites, *dispatch_rewrites])
    rewritten, _ = check_text(text, spec_file)
    for field_name, added in (("hops_ms", entries), ("dispatch_ms", dispatch_entries)):
        if added and rewritten.source is not None:  # new keys go in at the positions of the edited text
            text = add_entries(text, rewritten.source, (field_name,), added)
            rewritten, _ = check_text(text, spec_file)
    wrong = matches(rewritten, proposals)
    wrong += [key for key, (_, ms) in _written_hops(rewritten, hops).items() if ms != hops[parse_arrow(key)]]
    wrong += [f"dispatch_ms.{head}" for head, ms in dispatches.items() if rewritten.dispatch_ms.get(head) != ms]
    if wrong:
        raise CatancError(f"{spec_file}: rewriting {', '.join(wrong)} did not give the proposed values (a bug)")
    name = spec_file
    diff = "".join(
        difflib.unified_diff(
            spec_text.splitlines(keepends=True), text.splitlines(keepends=True), f"a/{name}", f"b/{name}"
        )
    )
    off = [
        *deviations(spec, proposals, tolerance),
        *hop_deviations(spec, hops, tolerance),
        *dispatch_deviations(spec, dispatches, tolerance),
        *chain_deviations(spec, problem, measured),
    ]
    summary = (
        *summary_lines(spec, proposals, measured),
        *hop_lines(spec, hops, measured),
        *dispatch_lines(spec, dispatches, measured),
        *unproposed_dispatch_lines(problem, measured),
        *chain_lines(problem, measured),
    )
    return Profiled(proposals, hops, dispatches, summary, text, diff, tuple(off))


def _written_hops(spec: Spec, hops: Mapping[tuple[str, str], float]) -> dict[str, tuple[str, float]]:
    """Each proposed edge's key and hop as ``spec`` writes them (a missing one as 0 ms, which never matches)."""
    written = spec_hops(spec)
    return {edge_key(*edge): written.get(edge, ("", math.nan)) for edge in hops}


def hop_lines(spec: Spec, hops: Mapping[tuple[str, str], float], measured: LogSamples) -> tuple[str, ...]:
    """One line per measured hop of an edge inside a subchain: samples, the spec's hop and the measured p95."""
    written = spec_hops(spec)
    lines = []
    for edge, ms in sorted(hops.items()):
        hop = written.get(edge, ("", 0.0))[1]
        count = measured.hops[edge].count
        lines.append(f"  hop {edge_key(*edge)}: {count} samples; spec {hop:.4g} ms, measured p95 {ms:.4g} ms")
    return tuple(lines)


def summary_lines(spec: Spec, proposals: Mapping[str, Proposal], measured: LogSamples) -> tuple[str, ...]:
    """Per node: samples, threads, the spec's planning figure and the measured one, how far off; then notes."""
    kind = "observed (own timers)" if measured.observed else "enforced"
    lines = [f"{measured.file}: {measured.length_s:.1f} s {kind}, p{spec.runtime.percentile:g} per node:"]
    for name, proposal in sorted(proposals.items()):
        written = spec.nodes[name].mean_compute_ms
        off = (proposal.planning_ms - written) / written
        modes = " modes " + ", ".join(f"{m.share:g}x{m.ms:g}" for m in proposal.modes) if proposal.modes else ""
        threads = ", ".join(f"{k} thread{'s' if k > 1 else ''}: {n}" for k, n in proposal.threads.items())
        speedups = [f"{s:g}" if s is not None else "-" for s in proposal.speedups]
        speedup = f"; speedup [{', '.join(speedups)}]" if proposal.speedups else ""
        lines.append(
            f"  {name}: {proposal.count} samples ({threads}); spec {written:.4g} ms, measured "
            f"{proposal.planning_ms:.4g} ms ({off:+.1%}){modes}{speedup}{_kernel_text(proposal.kernel)}"
        )
        lines += [f"    {name}: {note}" for note in proposal.notes]
    return tuple(lines)


def _kernel_text(kernel: KernelCheck | None) -> str:
    if kernel is None:
        return ""
    return (
        f"; {kernel.runs} runs checked by the kernel: {kernel.extra_ms:+.3f} ms a run over the node's own figure "
        "(median: the client's own work around its callback)"
    )
