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
drawing for one node never moves another's values.  Modes and jitter are
drawn with numpy (PCG64) in blocks of :data:`BLOCK` runs, each from its own
stream: a run's values do not depend on how many runs are asked for at once,
so the compiled simulation can take thousands in one call and still see
exactly what the run-by-run Python engine sees.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import random

import numpy as np
import numpy.typing as npt

from catanc.spec.language import ModalCompute, Node, Spec, Workload

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


BLOCK = 1024
"""Runs drawn at a time (any size gives the same values)."""


def _seed(seed: int, node: str, purpose: str) -> int:
    """A seed for one node and purpose; never Python's hash(), which is salted per process."""
    digest = hashlib.sha256(f"catanc-workload\0{seed}\0{node}\0{purpose}".encode()).digest()
    return int.from_bytes(digest, "big")


def _stream(seed: int, node: str, purpose: str) -> random.Random:
    return random.Random(_seed(seed, node, purpose))


def _generator(seed: int, node: str, purpose: str) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(_seed(seed, node, purpose)))


class NodeStream:
    """One node's draws; everything a run needs is precomputed into plain floats.

    :meth:`draw` is one run.  A compiled simulation takes the same values in
    parts: :meth:`base` for each normal run and :meth:`spikes_until` for the
    spike arrivals, applying :func:`growth_factor`'s line itself.
    """

    __slots__ = (
        "_arrivals",
        "_factors",
        "_growth",
        "_jitter",
        "_jitter_a",
        "_jitter_b",
        "_jitter_draws",
        "_mode_draws",
        "_mode_ms",
        "_mode_thresholds",
        "_modes",
        "_next",
        "_next_spike_s",
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
        self._mode_draws = _generator(seed, name, "modes")
        self._jitter_draws = _generator(seed, name, "jitter")
        self._modes: npt.NDArray[np.float64] = np.empty(0)  # drawn, not yet taken: runs self._next onwards
        self._factors: npt.NDArray[np.float64] = np.empty(0)
        self._next = 0
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
        if self._next >= len(self._modes):
            self._draw_blocks(1)
        i = self._next
        self._next = i + 1
        return float(self._modes[i]), float(self._factors[i])

    def bases(self, count: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The next ``count`` :meth:`base` draws: their modes and their jitter multipliers."""
        missing = count - (len(self._modes) - self._next)
        if missing > 0:
            self._draw_blocks(-(-missing // BLOCK))
        i = self._next
        self._next = i + count
        return self._modes[i : i + count], self._factors[i : i + count]

    def _draw_blocks(self, blocks: int) -> None:
        """``blocks`` more BLOCKs of runs after the ones still to be taken, joined once (not once a block:
        a million draws at once took 3,000 copies of a growing array)."""
        modes, factors = self._blocks(blocks)
        self._modes = np.concatenate([self._modes[self._next :], modes])
        self._factors = np.concatenate([self._factors[self._next :], factors])
        self._next = 0

    def _blocks(self, blocks: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The next ``blocks`` BLOCKs of runs' modes and jitter multipliers.

        Drawn in one call per generator where the values do not depend on the block: a generator's
        ``random(n)`` and ``standard_normal(n)`` give the values of ``n`` calls of one, and the block
        matters only for the normal jitter's redraws.
        """
        count = blocks * BLOCK
        if self._mode_thresholds:
            picks = np.searchsorted(self._mode_thresholds, self._mode_draws.random(count), side="right")
            modes = np.asarray(self._mode_ms)[picks]
        else:
            modes = np.full(count, self._mode_ms[0])
        kind, a, b = self._jitter, self._jitter_a, self._jitter_b
        if kind == "lognormal":
            factors = np.exp(a + b * self._jitter_draws.standard_normal(count))
        elif kind == "uniform":
            factors = a + b * self._jitter_draws.random(count)
        elif kind == "normal":
            factors = np.concatenate([self._normal_block() for _ in range(blocks)])
        else:
            factors = np.ones(count)
        return modes, factors

    def _normal_block(self) -> npt.NDArray[np.float64]:
        """The next BLOCK normal jitter multipliers, redrawn until positive: the next positive values, in
        order; positives past the block are dropped, so a stream is defined block by block."""
        a, b = self._jitter_a, self._jitter_b
        kept: list[npt.NDArray[np.float64]] = []
        have = 0
        while have < BLOCK:
            values = a + b * self._jitter_draws.standard_normal(BLOCK)
            values = values[values > 0.0]
            kept.append(values)
            have += len(values)
        return np.concatenate(kept)[:BLOCK]

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
