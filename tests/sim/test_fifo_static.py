"""The simulator's fifo-static with the fair levels, worked by hand on one core.

fast (1 ms) on a 100 Hz timer and slow (10 ms) on a 25 Hz timer, both from 0 ms.  The objective
weighs fast's chain more, so fast runs at the higher SCHED_FIFO level although the spec's
stealing priorities (schedule.priorities) rank slow above it: those are catanc's, not the baseline's.
"""

from __future__ import annotations

from typing import Any

import pytest

from catanc.sim.simulate import Setup, simulate
from catanc.spec.language import Spec
from tests.support.strategies import spec_of

TWO_TIMERS: dict[str, Any] = {
    "catan": 1,
    "app": "two",
    "nodes": {"fast": {"compute_ms": 1}, "slow": {"compute_ms": 10}, "out": {"scheduled": False}},
    "edges": [["fast", "out"], ["slow", "out"]],
    "subchains": {"fast": ["fast"], "slow": ["slow"]},
    "objective": [{"chain": ["fast", "out"], "weight": 1.0}, {"chain": ["slow", "out"], "weight": 0.1}],
    "schedule": {"priorities": {"fast": 0, "slow": 1}},
    "baseline": {"rates_hz": {"fast": 100, "slow": 25}},
}


def constant(spec: Spec, _seed: int) -> Any:
    return lambda node, _at_s: spec.nodes[node].mean_compute_ms


def responses(document: dict[str, Any], engine: str) -> dict[str, tuple[float, float]]:
    """Each chain's (mean, max) response over 2 s of fifo-static (constant compute times)."""
    spec = spec_of(document)
    if engine == "python":
        result = simulate(Setup(spec, 1, 2.0, 0), "fifo-static", constant, engine="python")
    else:  # no workload in the spec: its model draws the compute times themselves
        result = simulate(Setup(spec, 1, 2.0, 0), "fifo-static", engine="compiled")
    summary = {}
    for chain in result.chains:
        assert chain.response is not None
        summary[chain.nodes[0]] = (chain.response.mean, chain.response.max)
    return summary


@pytest.mark.parametrize("engine", ["python", "compiled"])
def test_a_10_ms_low_priority_run_no_longer_blocks_the_important_one(engine: str) -> None:
    # fast preempts slow at once: each output 1 ms after its trigger, measured from the trigger
    # before it: 10 + 1.  slow, triggered every 40 ms (a multiple of 10), first runs at 1 ms, after
    # fast, and its run starts (the chain's origin) then; it loses 1 ms more at 10 ms: done at 12,
    # measured from the origin before it, 40 ms earlier at 1: 51, every time.
    got = responses(TWO_TIMERS, engine)
    assert got["fast"] == pytest.approx((11.0, 11.0))
    assert got["slow"] == pytest.approx((51.0, 51.0))


@pytest.mark.parametrize("engine", ["python", "compiled"])
def test_the_specs_baseline_priorities_set_the_levels(engine: str) -> None:
    # slow above fast: slow runs 40k..40k+10 ms.  fast, due at 40k, first runs (its origin) at 40k+10,
    # done at 40k+11; its timer at 40k+10 waits for that run, so the next starts at 40k+11, done at
    # 40k+12; then on time at 40k+20 and 40k+30.  Each output measured from the origin before it:
    # 40k+11 - (40k-10) = 21, then 12 - 10 = 2, 21 - 11 = 10 and 31 - 20 = 11: 44 a cycle of 40 ms.
    # In 2 s: 50 cycles, the first without its 21 (its first output has no origin before it).
    # slow is never preempted: done 10 ms after its trigger, 40 + 10.
    document = {**TWO_TIMERS, "baseline": {**TWO_TIMERS["baseline"], "priorities": {"slow": 1}}}
    got = responses(document, engine)
    assert got["fast"] == pytest.approx(((2 + 10 + 11 + 49 * 44) / 199, 21.0))
    assert got["slow"] == pytest.approx((50.0, 50.0))
