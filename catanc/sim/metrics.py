"""What a simulated (or measured) run shows: chain response times, node rates and staleness, core use.

A chain's response time is measured the way the model bounds it
(docs/explanation/model.md section 2: an event waits for the head to sample it, then
flows through): for each output of the chain's last node that carries a
*newer* origin than the one before it, the time from the previous origin to
this output.  An event just after the previous head run is first reflected
in this output, so that is the worst case for the events of that window.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from catanc.control.measure import between, percentile, percentile_rank
from catanc.control.schedule import RuntimeSchedule

FloatArray = npt.NDArray[np.float64]


def response_arrays(
    arrivals: Sequence[tuple[float, float]] | FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """From a chain's ``(origin, done)`` arrivals at its last node, in completion order: when each output that
    shows a response was done, and its response time (ms).

    The window before an output starts at the newest origin any earlier output carried: the
    running maximum, so one vectorised pass gives what the loop over arrivals would.
    """
    pairs = np.asarray(arrivals, dtype=np.float64).reshape(-1, 2)
    if len(pairs) < 2:
        return np.empty(0), np.empty(0)
    origins, done = pairs[:, 0], pairs[1:, 1]
    previous = np.maximum.accumulate(origins)[:-1]
    newer = origins[1:] > previous
    return done[newer], done[newer] - previous[newer]


def percentile_of(values: Sequence[float] | FloatArray, q: float) -> float:
    """:func:`~catanc.control.measure.percentile` to the last bit, without sorting an array (no NaN).

    The percentile depends on two order statistics only, which ``np.partition`` finds in linear time:
    sorting nav2d's ~500k staleness samples took most of turning a run into results.
    """
    if not isinstance(values, np.ndarray):
        return percentile(values, q)
    i, t = percentile_rank(len(values), q)
    ranks = [i] if t == 0.0 else [i, i + 1]
    chosen = np.partition(values, ranks)[ranks].tolist()
    return float(chosen[0]) if t == 0.0 else between(chosen[0], chosen[1], t)


SMALL_SUM = 1024
"""Below this many values, :func:`exact_sum` is ``math.fsum``: its per-call cost wins over the per-value one."""


def exact_sum(values: FloatArray) -> float:
    """``math.fsum(values)``, the correctly rounded sum, to the last bit (for finite values fsum can sum).

    fsum walks a Python list at ~30 ns a value, which made the exact means of nav2d's ~200k response
    times of a 250 s run 2% of its simulation; :func:`sum_by_exponent` does it in array passes.
    """
    if len(values) < SMALL_SUM:
        return math.fsum(values.tolist())
    return sum_by_exponent(values)


def sum_by_exponent(values: FloatArray) -> float:
    """The exact sum of ``values``, rounded once (non-finite values: ``math.fsum``'s answer).

    Each value is ``m 2**e`` with ``0.5 <= |m| < 1``, so ``m 2**53`` is a whole number of 53 bits,
    cut exactly into three pieces of at most 18 bits (scaling by powers of two and taking off a
    whole part are exact in floating point).  Per exponent, ``np.bincount`` adds each piece in
    float64 without rounding: fewer than ``2**35`` values of under ``2**18`` stay below ``2**53``.
    Python integers then add the per-exponent sums in place, and the one division at the end is
    correctly rounded, as fsum's result is.
    """
    if not len(values):
        return 0.0
    if len(values) >= 1 << 35:  # pragma: no cover - a bincount sum could round
        return math.fsum(values.tolist())
    fraction, exponent = np.frexp(values)
    if not np.isfinite(fraction).all():
        return math.fsum(values.tolist())
    lowest = int(exponent.min())
    place = exponent - lowest
    length = int(place.max()) + 1
    whole = fraction * 2.0**17
    high = np.trunc(whole)
    rest = (whole - high) * 2.0**18
    middle = np.trunc(rest)
    low = (rest - middle) * 2.0**18
    total = 0
    for piece, shift in ((high, 36), (middle, 18), (low, 0)):
        sums = np.bincount(place, weights=piece, minlength=length)
        for at in np.flatnonzero(sums).tolist():
            total += int(sums[at]) << (shift + at)
    scale = lowest - 53  # the sum is total * 2**scale
    return float(total << scale) if scale >= 0 else total / (1 << -scale)


@dataclass(frozen=True)
class Summary:
    count: int
    mean: float
    p95: float
    max: float

    @classmethod
    def of(cls, values: FloatArray) -> Summary | None:
        """The count, mean, p95 and maximum of ``values`` (no NaN); None for none."""
        if not len(values):
            return None
        return cls(len(values), exact_sum(values) / len(values), percentile_of(values, 95), float(values.max()))

    def as_dict(self) -> dict[str, float]:
        return {"mean": round(self.mean, 3), "p95": round(self.p95, 3), "max": round(self.max, 3)}


@dataclass(frozen=True)
class ChainResult:
    nodes: tuple[str, ...]
    named: bool  # the objective or a constraint names it (else: another source-to-sink path)
    response: Summary | None  # None: no output reached the end of the chain
    model_ms: float | None  # the plan's analytic response time R (catan policies, named chains)
    samples: FloatArray = field(default_factory=lambda: np.empty((0, 2)), compare=False, repr=False)
    """Every ``(done_ms, response_ms)`` behind ``response`` as the rows of an (n, 2) array, in completion
    order (for plots; not in the JSON).  An array: nav2d keeps ~100k of them a minute."""

    def as_dict(self) -> dict[str, Any]:
        body: dict[str, Any] = {"nodes": list(self.nodes), "named": self.named}
        body["response_ms"] = self.response.as_dict() if self.response else None
        body["outputs"] = self.response.count if self.response else 0
        if self.model_ms is not None:
            body["model_ms"] = round(self.model_ms, 3)
        return body


@dataclass(frozen=True)
class NodeResult:
    rate_hz: float
    staleness_ms_p95: float | None
    planned_hz: float | None = None  # a subchain head's rate as the last plan promises it run (catan policies)

    def as_dict(self) -> dict[str, Any]:
        stale = None if self.staleness_ms_p95 is None else round(self.staleness_ms_p95, 3)
        body: dict[str, Any] = {"rate_hz": round(self.rate_hz, 3), "staleness_ms_p95": stale}
        if self.planned_hz is not None:
            body["planned_hz"] = round(self.planned_hz, 3)
        return body


@dataclass(frozen=True)
class PolicyResult:
    policy: str
    duration_s: float
    chains: tuple[ChainResult, ...]
    nodes: dict[str, NodeResult]
    utilisation: tuple[float, ...]  # per core, 0..1
    replans: int
    node_done_ms: dict[str, FloatArray] = field(default_factory=dict, compare=False, repr=False)
    """Per node, when each run (or tick) finished, for rates over time (plots; not in the JSON)."""
    schedule: RuntimeSchedule | None = field(default=None, compare=False, repr=False)
    """The schedule in force at the end (catan and static policies), for a timeline of one period per core."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "duration_s": self.duration_s,
            "chains": [chain.as_dict() for chain in self.chains],
            "nodes": {name: node.as_dict() for name, node in sorted(self.nodes.items())},
            "cores": [{"core": i, "utilisation": round(u, 4)} for i, u in enumerate(self.utilisation)],
            "replans": self.replans,
        }


def chain_result(
    nodes: tuple[str, ...],
    named: bool,
    arrivals: Sequence[tuple[float, float]] | FloatArray,
    model_ms: float | None,
) -> ChainResult:
    """What a chain's ``(origin, done)`` arrivals at its last node show (see :func:`response_arrays`)."""
    done, response = response_arrays(arrivals)
    return ChainResult(nodes, named, Summary.of(response), model_ms, samples=np.column_stack((done, response)))


def node_result(
    done_ms: Sequence[float] | FloatArray,
    staleness_ms: Sequence[float] | FloatArray,
    duration_ms: float,
    planned_hz: float | None = None,
) -> NodeResult:
    stale = percentile_of(staleness_ms, 95) if len(staleness_ms) else None
    return NodeResult(len(done_ms) * 1000.0 / duration_ms, stale, planned_hz)
