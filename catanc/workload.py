"""Run-by-run compute times that follow a spec's workload model (for simulation and synthetic workers).

A spec's ``compute_ms`` is the planning figure; a node's optional ``workload``
says how single runs vary around it.  One run of a scheduled node starting at
``t`` seconds into the app's run takes, on one thread:

- the spike time ``workload.spikes.ms`` if a spike arrived at or before ``t``
  and no earlier run consumed it.  Spike arrivals are a Poisson process in
  time (mean interval ``every_s``), drawn from their own stream, so they do
  not depend on how often the node runs; arrivals between two runs merge into
  one spike, which the next run takes in place of its whole normal draw;
- otherwise one mode of ``compute_ms`` drawn by share (or the single value),
  times ``growth_factor(workload, t)``, times a jitter multiplier with mean 1
  and the given coefficient of variation: lognormal, uniform on
  ``1 +- sqrt(3) cv``, or normal redrawn until positive.

Each node has its own streams, seeded from ``(seed, node name)`` by SHA-256,
so the same spec, seed and calls give the same times in any process, and
drawing for one node never moves another's values.
"""

from __future__ import annotations

import bisect
import hashlib
import itertools
import math
import random

from catanc.spec import ModalCompute, Node, Spec, Workload

__all__ = ["ComputeSampler", "NodeStream", "growth_factor"]

_SQRT3 = math.sqrt(3.0)


def growth_factor(workload: Workload | None, at_s: float) -> float:
    """The growth multiplier at ``at_s`` seconds: linear from ``start`` at 0 to ``end`` at ``over_s``, then ``end``.

    1.0 without growth; before 0 s it is ``start``.
    """
    growth = None if workload is None else workload.growth
    if growth is None:
        return 1.0
    return _linear(growth.start, growth.end, growth.over_s, at_s)


def _linear(start: float, end: float, over_s: float, at_s: float) -> float:
    if at_s >= over_s:
        return end
    if at_s <= 0.0:
        return start
    return start + (end - start) * (at_s / over_s)


def _stream(seed: int, node: str, purpose: str) -> random.Random:
    """A generator for one node and purpose; never Python's hash(), which is salted per process."""
    digest = hashlib.sha256(f"catanc-workload\0{seed}\0{node}\0{purpose}".encode()).digest()
    return random.Random(int.from_bytes(digest, "big"))


class NodeStream:
    """One node's draws; everything a run needs is precomputed into plain floats.

    :meth:`draw` is one run.  A compiled simulation takes the same values in
    parts: :meth:`base` for each normal run and :meth:`spikes_until` for the
    spike arrivals, applying :func:`growth_factor`'s line itself.
    """

    __slots__ = (
        "_arrivals",
        "_growth",
        "_jitter",
        "_jitter_a",
        "_jitter_b",
        "_mode_ms",
        "_mode_thresholds",
        "_next_spike_s",
        "_runs",
        "_spike_ms",
        "_spike_rate",
    )

    def __init__(self, name: str, node: Node, seed: int) -> None:
        compute = node.compute_ms
        assert compute is not None  # a scheduled node has one (Node's validator)
        if isinstance(compute, ModalCompute):
            self._mode_ms = tuple(mode.ms for mode in compute.modes)
            # Upper share bounds of every mode but the last: bisect gives the mode, and a share sum
            # a rounding error under 1 can never select a mode past the end.
            shares = [mode.share for mode in compute.modes]
            self._mode_thresholds = tuple(itertools.accumulate(shares[:-1]))
        else:
            self._mode_ms = (float(compute),)
            self._mode_thresholds = ()
        self._runs = _stream(seed, name, "runs")
        workload = node.workload
        growth = None if workload is None else workload.growth
        self._growth = None if growth is None else (growth.start, growth.end, growth.over_s)
        jitter = None if workload is None else workload.jitter
        # _jitter: "" (none), "lognormal", "uniform" or "normal"; a and b are that distribution's parameters.
        self._jitter = "" if jitter is None or jitter.cv == 0 else jitter.dist
        self._jitter_a = self._jitter_b = 0.0
        if jitter is not None and self._jitter == "lognormal":
            sigma2 = math.log1p(jitter.cv**2)  # mean exp(mu + sigma^2/2) = 1 and CV sqrt(exp(sigma^2) - 1) = cv
            self._jitter_a, self._jitter_b = -sigma2 / 2, math.sqrt(sigma2)
        elif jitter is not None and self._jitter == "uniform":
            self._jitter_a, self._jitter_b = 1 - _SQRT3 * jitter.cv, 2 * _SQRT3 * jitter.cv  # low, width
        elif jitter is not None and self._jitter == "normal":
            self._jitter_a, self._jitter_b = 1.0, jitter.cv
        spikes = None if workload is None else workload.spikes
        self._arrivals = _stream(seed, name, "spikes")
        self._spike_ms = math.nan if spikes is None else spikes.ms
        self._spike_rate = 0.0 if spikes is None else 1.0 / spikes.every_s
        self._next_spike_s = math.inf if spikes is None else self._arrivals.expovariate(self._spike_rate)

    def draw(self, at_s: float) -> float:
        if at_s >= self._next_spike_s:
            while self._next_spike_s <= at_s:  # every arrival up to now is this one run's spike
                self._next_spike_s += self._arrivals.expovariate(self._spike_rate)
            return self._spike_ms
        mode_ms, factor = self.base()
        if self._growth is not None:
            mode_ms *= _linear(*self._growth, at_s)
        return mode_ms * factor

    @property
    def growth(self) -> tuple[float, float, float] | None:
        """``(start, end, over_s)`` of the growth factor, or None."""
        return self._growth

    @property
    def spike_ms(self) -> float:
        """A spike run's compute time (NaN without spikes)."""
        return self._spike_ms

    def base(self) -> tuple[float, float]:
        """The next normal run's mode (ms) and jitter multiplier (1.0 without jitter), growth not applied."""
        runs = self._runs
        if self._mode_thresholds:
            ms = self._mode_ms[bisect.bisect_right(self._mode_thresholds, runs.random())]
        else:
            ms = self._mode_ms[0]
        kind = self._jitter
        if kind == "lognormal":
            return ms, math.exp(self._jitter_a + self._jitter_b * runs.gauss())
        if kind == "uniform":
            return ms, self._jitter_a + self._jitter_b * runs.random()
        if kind == "normal":
            factor = runs.gauss(self._jitter_a, self._jitter_b)
            while factor <= 0.0:  # rare: the spec allows a normal only with cv <= 0.3
                factor = runs.gauss(self._jitter_a, self._jitter_b)
            return ms, factor
        return ms, 1.0

    def bases(self, count: int) -> tuple[list[float], list[float]]:
        """The next ``count`` :meth:`base` draws: their modes and their jitter multipliers."""
        modes, factors = [], []
        for _ in range(count):
            mode_ms, factor = self.base()
            modes.append(mode_ms)
            factors.append(factor)
        return modes, factors

    def spikes_until(self, end_s: float) -> list[float]:
        """The spike arrivals still to come, up to the first one after ``end_s`` (consumes them)."""
        arrivals = [self._next_spike_s]
        while self._next_spike_s <= end_s:
            self._next_spike_s += self._arrivals.expovariate(self._spike_rate)
            arrivals.append(self._next_spike_s)
        return arrivals


class ComputeSampler:
    """Draws one run's compute time (ms, on one thread) per node, following the spec's workload model."""

    __slots__ = ("_nodes", "_unscheduled")

    def __init__(self, spec: Spec, seed: int) -> None:
        self._nodes = {name: NodeStream(name, node, seed) for name, node in spec.nodes.items() if node.scheduled}
        self._unscheduled = frozenset(name for name, node in spec.nodes.items() if not node.scheduled)

    def stream(self, node: str) -> NodeStream:
        """``node``'s own stream (KeyError for an unscheduled or unknown node)."""
        return self._nodes[node]

    def compute_ms(self, node: str, at_s: float) -> float:
        """One run of ``node`` starting at ``at_s`` seconds into the run.

        Calls for one node come in non-decreasing ``at_s``.  Raises ValueError
        for an unscheduled node (it has no compute time) and KeyError for a
        name the spec does not have.
        """
        sampler = self._nodes.get(node)
        if sampler is None:
            if node in self._unscheduled:
                raise ValueError(f"node {node!r} is unscheduled (scheduled: false): it has no compute time to sample")
            raise KeyError(f"no node {node!r} in the spec")
        return sampler.draw(at_s)
