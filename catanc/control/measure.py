"""Measuring compute times at runtime: what the re-optimiser plans with (docs/explanation/model.md section 5).

Per scheduled node the enforcer keeps the last ``runtime.window`` compute
times (ms) in a :class:`ComputeWindow` and plans with an *estimate*:

- **Unimodal node**: the ``runtime.percentile``-th percentile of the window
  (:func:`percentile`: linear interpolation between closest ranks, numpy's
  default).
- **Multimodal node** (``compute_ms: {modes: [...]}``): each sample goes to
  the spec mode whose time is nearest *on a log scale* (:func:`assign_mode`),
  and the estimate is ``sum_i w_i * percentile(samples of mode i)`` with
  ``w_i`` = the share of the window's samples in mode ``i``.  A mode with no
  samples in the window contributes nothing (the weights are shares of the
  observed samples, so they sum to 1 over the observed modes).  The spec's
  mode *shares* are not used: the observed frequencies replace them.
- **No samples yet**: ``runtime.bootstrap_ms``.

Sample hygiene: a sample that is not a finite number >= 0 (NaN, inf,
negative, not a number at all) is counted as rejected and otherwise ignored;
0 is a valid sample.

:class:`Measurements` holds one window per scheduled node of a spec behind
one lock, so the receiver thread may :meth:`~Measurements.record` while the
re-optimiser thread reads :meth:`~Measurements.estimates` or the status
reads :meth:`~Measurements.snapshot`.  A :class:`ComputeWindow` on its own is
*not* thread-safe; share windows only through a :class:`Measurements`.

Cross-checking with the kernel: :mod:`catanc.runtime.linux.cpu_clocks` reads a thread's on-CPU
time; :func:`reconcile` decides between a client's own figure and the kernel's.
"""

from __future__ import annotations

import bisect
import itertools
import math
import threading
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from catanc.errors import UsageError, did_you_mean
from catanc.spec.language import ModalCompute, Node, Runtime, Spec

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

MIN_PLANNING_MS = 1e-3
"""Floor of :meth:`Measurements.estimates` (1 us): the planner takes only positive times
(:meth:`catanc.model.problem.Problem.with_compute`), but a node may well measure 0 ms."""

RECONCILE_REL_TOL = 0.10
""":func:`reconcile` keeps a client's figure within 10% of the kernel's ..."""
RECONCILE_ABS_TOL_MS = 0.05
"""... or within 50 us of it (whichever is looser), and otherwise takes the kernel's ..."""
CLIENT_WORK_MS = 0.5
"""... but the kernel's count may exceed the client's figure by this much more: the client's own work per run
outside the callback it times (waking on the trigger, reporting, waking the next node, blocking again), which
the kernel counts for the head's thread.  Measured with the Python client on the 2-core development VM: 0.08-0.45
ms per run (benchmarks/RESULTS.md, issue 32).  It is not the node's compute: the plan budgets it as the hop
delay, the trigger (or the previous node's end) to the node's start (:mod:`catanc.runtime.enforcer.costs`)."""


# --------------------------------------------------------------------------- the numbers


def valid_sample(value: object) -> bool:
    """Whether ``value`` is a usable compute time: a finite int or float >= 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    return math.isfinite(value) and value >= 0


def percentile(samples: Iterable[float], q: float) -> float:
    """The ``q``-th percentile (0 <= q <= 100) of ``samples``, by linear interpolation between closest ranks.

    With the ``n`` samples sorted as ``x[0] <= ... <= x[n-1]``, ``h = (n - 1) * q / 100``
    and ``i = floor(h)``, the result is ``x[i] + (h - i) * (x[i+1] - x[i])`` (``x[n-1]`` when
    ``i = n - 1``).  This is numpy's default (``method="linear"``, Hyndman & Fan's type 7):
    ``q = 100`` gives the maximum, ``q = 0`` the minimum, one sample gives itself.
    The result always lies in ``[x[i], x[i+1]]``.  Raises ``ValueError`` on no samples.
    """
    ordered = sorted(samples)
    i, t = percentile_rank(len(ordered), q)
    return ordered[i] if t == 0.0 else between(ordered[i], ordered[i + 1], t)


def percentile_rank(count: int, q: float) -> tuple[int, float]:
    """Where :func:`percentile` lies among ``count`` sorted samples: ``(i, t)``, ``t`` of the way from ``x[i]`` to
    ``x[i+1]`` (``t = 0`` at the last sample).  Raises ``ValueError`` on no samples or ``q`` outside [0, 100]."""
    if count == 0:
        raise ValueError("percentile of no samples")
    if not (0.0 <= q <= 100.0):
        raise ValueError(f"percentile must be in [0, 100], got {q!r}")
    h = (count - 1) * (q / 100.0)
    i = min(math.floor(h), count - 1)
    return i, (0.0 if i == count - 1 else h - i)


def between(low: float, high: float, t: float) -> float:
    """``t`` of the way from ``low`` to ``high`` as numpy's ``_lerp``: from the nearer end, clamped for rounding."""
    value = low + (high - low) * t if t < 0.5 else high - (high - low) * (1.0 - t)
    return min(max(value, low), high)


def mode_times(compute: float | ModalCompute | None) -> tuple[float, ...]:
    """A node's mode times (ms), sorted and distinct; ``()`` for a unimodal node."""
    if not isinstance(compute, ModalCompute):
        return ()
    return tuple(sorted({float(mode.ms) for mode in compute.modes}))


def mode_boundaries(modes: Sequence[float]) -> tuple[float, ...]:
    """Between sorted mode times ``m[i] < m[i+1]``: their geometric mean, the midpoint on a log scale."""
    bounds = []
    for low, high in itertools.pairwise(modes):
        product = low * high
        bounds.append(math.sqrt(product) if math.isfinite(product) else math.sqrt(low) * math.sqrt(high))
    return tuple(bounds)


def assign_mode(sample: float, modes: Sequence[float]) -> int:
    """Index of the mode (in sorted ``modes``) nearest ``sample`` on a log scale.

    That is ``argmin_i |log(sample) - log(m[i])|``: the sample goes to mode ``i`` when it
    lies between the geometric means of ``m[i]`` with its neighbours.  A sample exactly on a
    boundary goes to the *higher* mode (plan for more, not less); 0 goes to the lowest.
    Log scale, because modes differ by factors (GL in nav2d: 1 ms and 12 ms, boundary
    sqrt(12) = 3.46 ms), and a run's spread around its mode grows with the mode's time.
    """
    return bisect.bisect_right(mode_boundaries(modes), sample)  # how many boundaries lie at or below it


def split_modes(samples: Iterable[float], modes: Sequence[float]) -> tuple[tuple[float, ...], ...]:
    """The samples of each mode, in sorted-mode order (samples keep their order)."""
    groups: list[list[float]] = [[] for _ in modes]
    bounds = mode_boundaries(modes)  # once, not per sample
    for sample in samples:
        groups[bisect.bisect_right(bounds, sample)].append(sample)
    return tuple(tuple(group) for group in groups)


def estimate(samples: Sequence[float], q: float, modes: Sequence[float] = (), bootstrap_ms: float = 5.0) -> float:
    """The planning compute time of one window of valid ``samples`` (see the module's docstring).

    ``modes``: sorted distinct mode times, ``()`` for a unimodal node.  The result lies
    within ``[min(samples), max(samples)]``; with no samples it is ``bootstrap_ms``.
    """
    if not samples:
        return bootstrap_ms
    if len(modes) <= 1:
        return percentile(samples, q)
    groups = split_modes(samples, modes)
    weighted = math.fsum(len(group) * percentile(group, q) for group in groups if group) / len(samples)
    return min(max(weighted, min(samples)), max(samples))  # a weighted mean of values in the range


# --------------------------------------------------------------------------- one node


@dataclass(frozen=True)
class ModeStat:
    """How a multimodal node's window splits into one mode."""

    ms: float  # the spec's mode time
    count: int  # samples of the window in this mode
    share: float  # count / samples in the window (0 for an empty window)
    percentile_ms: float | None  # percentile of this mode's samples; None when it has none

    def as_dict(self) -> dict[str, Any]:
        return {"ms": self.ms, "count": self.count, "share": self.share, "percentile_ms": self.percentile_ms}


@dataclass(frozen=True)
class NodeSnapshot:
    """One node's measurements at one moment (for the live status and the JSON-lines log)."""

    node: str
    count: int  # samples in the window (<= window)
    total: int  # samples accepted since the start
    rejected: int  # samples rejected since the start (not finite, negative, not a number)
    last_ms: float | None  # the latest accepted sample
    percentile_ms: float | None  # the plain percentile of the whole window, ignoring modes
    estimate_ms: float  # what the planner gets (bootstrap_ms while count == 0; not floored)
    modes: tuple[ModeStat, ...]  # per mode of a multimodal node, by mode time; () if unimodal

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready; the caller picks key order and float format."""
        return {
            "node": self.node,
            "count": self.count,
            "total": self.total,
            "rejected": self.rejected,
            "last_ms": self.last_ms,
            "percentile_ms": self.percentile_ms,
            "estimate_ms": self.estimate_ms,
            "modes": [mode.as_dict() for mode in self.modes],
        }


class ComputeWindow:
    """The last ``window`` valid compute times of one node, and its planning estimate.

    Not thread-safe on its own: :class:`Measurements` serialises access.
    """

    def __init__(
        self, *, window: int = 50, percentile: float = 95.0, bootstrap_ms: float = 5.0, modes: Iterable[float] = ()
    ) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window!r}")
        if not (0.0 <= percentile <= 100.0):
            raise ValueError(f"percentile must be in [0, 100], got {percentile!r}")
        times = tuple(sorted(set(modes)))
        if any(not (math.isfinite(m) and m > 0) for m in times):
            raise ValueError(f"mode times must be positive and finite, got {times!r}")
        self.window = window
        self.percentile = percentile
        self.bootstrap_ms = bootstrap_ms
        self.modes: tuple[float, ...] = times if len(times) > 1 else ()
        self._samples: deque[float] = deque(maxlen=window)
        self.total = 0
        self.rejected = 0

    @classmethod
    def for_node(cls, node: Node, runtime: Runtime) -> ComputeWindow:
        """A window with the spec's ``runtime`` settings and the node's modes (if it has several)."""
        return cls(
            window=runtime.window,
            percentile=runtime.percentile,
            bootstrap_ms=runtime.bootstrap_ms,
            modes=mode_times(node.compute_ms),
        )

    def add(self, compute_ms: float) -> bool:
        """Keep one sample (evicting the oldest beyond ``window``); ``False``: rejected and counted."""
        if not valid_sample(compute_ms):
            self.rejected += 1
            return False
        self._samples.append(float(compute_ms))
        self.total += 1
        return True

    def extend(self, compute_ms: Iterable[float] | npt.NDArray[np.float64], *, earlier: int = 0) -> int:
        """:meth:`add` each of ``compute_ms`` in order, at once; how many were kept (the rest rejected and counted).

        A float64 array is checked in one numpy pass and only its last ``window`` valid
        samples are copied in: the window, ``total`` and ``rejected`` end as adding one by
        one leaves them.  Anything else is added one by one.

        ``earlier`` counts valid samples that came before these and that the window could not
        keep anyway (at least ``window`` valid ones follow them): they count in ``total`` and in
        what is returned (the simulator keeps only each node's last ``window``).
        """
        # Imported here: the enforcer's process never calls this and must not load numpy, whose
        # OpenBLAS starts a thread at import (the enforcer's threads are all its own, by policy).
        import numpy as np  # noqa: PLC0415

        if earlier < 0:
            raise ValueError(f"earlier must be a count >= 0, got {earlier}")
        if not (isinstance(compute_ms, np.ndarray) and compute_ms.dtype == np.float64 and compute_ms.ndim == 1):
            values = list(compute_ms)
            if earlier:
                self._check_earlier(earlier, sum(valid_sample(value) for value in values))
            kept = sum(self.add(value) for value in values)
        else:
            valid = compute_ms[np.isfinite(compute_ms) & (compute_ms >= 0.0)]
            kept = len(valid)
            if earlier:
                self._check_earlier(earlier, kept)
            self.rejected += len(compute_ms) - kept
            self.total += kept
            self._samples.extend(valid[-self.window :].tolist())
        self.total += earlier
        return kept + earlier

    def _check_earlier(self, earlier: int, kept: int) -> None:
        """Raise unless ``kept`` valid samples after ``earlier`` ones leave the window no room for those."""
        if kept < self.window:
            raise ValueError(
                f"{earlier} earlier samples with {kept} valid ones after them: the window of {self.window} "
                "would have kept some of them"
            )

    @property
    def samples(self) -> tuple[float, ...]:
        """The window, oldest first."""
        return tuple(self._samples)

    def estimate(self) -> float:
        """The planning compute time (ms): see :func:`estimate`."""
        return estimate(self._samples, self.percentile, self.modes, self.bootstrap_ms)

    def snapshot(self, node: str) -> NodeSnapshot:
        samples = self.samples
        stats: tuple[ModeStat, ...] = ()
        if self.modes:
            groups = split_modes(samples, self.modes)
            stats = tuple(
                ModeStat(
                    ms=ms,
                    count=len(group),
                    share=len(group) / len(samples) if samples else 0.0,
                    percentile_ms=percentile(group, self.percentile) if group else None,
                )
                for ms, group in zip(self.modes, groups, strict=True)
            )
        return NodeSnapshot(
            node=node,
            count=len(samples),
            total=self.total,
            rejected=self.rejected,
            last_ms=samples[-1] if samples else None,
            percentile_ms=percentile(samples, self.percentile) if samples else None,
            estimate_ms=self.estimate(),
            modes=stats,
        )


# --------------------------------------------------------------------------- all nodes


class Measurements:
    """One :class:`ComputeWindow` per scheduled node, safe to share between threads.

    Every method takes one lock, so any number of threads may record while
    others read; a reader sees each recorded sample either wholly or not at all.
    It takes over the ``windows`` it is given: do not touch them afterwards.
    """

    def __init__(self, windows: Mapping[str, ComputeWindow]) -> None:
        self._windows = dict(sorted(windows.items()))
        self._lock = threading.Lock()

    @classmethod
    def for_spec(cls, spec: Spec) -> Measurements:
        """A window for each scheduled node of ``spec``, with ``spec.runtime``'s settings."""
        return cls(
            {name: ComputeWindow.for_node(node, spec.runtime) for name, node in spec.nodes.items() if node.scheduled}
        )

    @property
    def nodes(self) -> tuple[str, ...]:
        """The measured nodes, sorted."""
        return tuple(self._windows)

    def record(self, node: str, compute_ms: float) -> bool:
        """Record one run's compute time (ms); ``False`` when the sample is rejected (and counted).

        Raises :class:`~catanc.errors.UsageError` for a node that is not measured here
        (unknown, or not scheduled): that is a wiring mistake, not a bad sample.
        """
        window = self._window(node)
        with self._lock:
            return window.add(compute_ms)

    def record_many(self, node: str, compute_ms: Iterable[float] | npt.NDArray[np.float64], *, earlier: int = 0) -> int:
        """:meth:`record` each of ``compute_ms`` for ``node``, in order, under one lock; how many were kept.

        The same as recording them one by one (:meth:`ComputeWindow.extend`, which says what
        ``earlier`` counts), in one call.
        """
        window = self._window(node)
        with self._lock:
            return window.extend(compute_ms, earlier=earlier)

    def _window(self, node: str) -> ComputeWindow:
        window = self._windows.get(node)
        if window is None:
            raise UsageError(
                f"no compute times are kept for {node!r}: not a scheduled node{did_you_mean(node, self._windows)}"
            )
        return window

    def estimates(self, *, measured_only: bool = False) -> dict[str, float]:
        """Node -> planning compute time (ms), for :meth:`catanc.planning.replan.Replanner.resolve`.

        Every scheduled node (``bootstrap_ms`` for one without samples), or with
        ``measured_only`` only those with samples.  Floored at :data:`MIN_PLANNING_MS`.
        """
        with self._lock:
            return {
                name: max(window.estimate(), MIN_PLANNING_MS)
                for name, window in self._windows.items()
                if not measured_only or window.total
            }

    def snapshot(self) -> dict[str, NodeSnapshot]:
        """Node -> its measurements now, all taken under one lock (a consistent cut)."""
        with self._lock:
            return {name: window.snapshot(name) for name, window in self._windows.items()}


# --------------------------------------------------------------------------- the kernel's figure against the client's


def reconcile(
    reported_ms: float,
    kernel_ms: float | None,
    *,
    rel_tol: float = RECONCILE_REL_TOL,
    abs_tol_ms: float = RECONCILE_ABS_TOL_MS,
    client_ms: float = CLIENT_WORK_MS,
) -> float:
    """The compute time to record when a client reports its own and the kernel's figure may be known.

    The client times exactly its callback (its thread's CPU from the trigger to ``done``); the
    kernel's count spans the head thread's CPU between the enforcer's two readings, which also
    holds the client's own work around the callback (up to ``client_ms``).  So the client's
    figure is checked for plausibility, and stands where it is plausible:

    - No usable kernel figure (``None``, not finite, negative): the client's, as reported
      (a bad one is then rejected by :meth:`Measurements.record`).
    - Client's figure unusable: the kernel's.
    - ``kernel - client_ms - tol <= reported <= kernel + tol`` with
      ``tol = max(abs_tol_ms, rel_tol * kernel)``: the client's.
    - Otherwise the kernel's.  The planner budgets CPU time, and the kernel counts only
      time on a CPU: a client's figure above it is wall-clock time that includes
      preemption and blocking, or a lie (it would inflate the plan, most under contention,
      when the scheduler is least able to afford it); a figure further below it than the
      client's own work explains misses CPU the thread really used, which the plan must
      budget or the slices overrun.
    """
    if kernel_ms is None or not valid_sample(kernel_ms):
        return reported_ms
    if not valid_sample(reported_ms):
        return kernel_ms
    tol = max(abs_tol_ms, rel_tol * kernel_ms)
    if kernel_ms - client_ms - tol <= reported_ms <= kernel_ms + tol:
        return reported_ms
    return kernel_ms
