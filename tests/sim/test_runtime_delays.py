"""What the simulator models of the real runtime (issue 49 item 3), worked by hand on one core.

A run reads its inputs when it first runs, as a real thread does when it wakes (``catanc bench``'s
workers record their start then), not when it is triggered: fifo-static's VR Render, triggered at
vsync behind Timewarp, reads the IMU sample that came while it waited.  Both engines alike.
"""

from __future__ import annotations

from typing import Any

import pytest

from catanc.sim.simulate import Setup, simulate
from catanc.spec.language import Spec
from tests.support.strategies import spec_of

# hi (3 ms) and lo (1 ms) on 100 Hz timers from 0 ms, hi above lo (its chain weighs more); lo reads
# the 500 Hz sensor imu (ticks at 0, 2, 4, ... ms).
BEHIND: dict[str, Any] = {
    "catan": 1,
    "app": "behind",
    "nodes": {
        "imu": {"scheduled": False, "rate_hz": 500},
        "hi": {"compute_ms": 3},
        "lo": {"compute_ms": 1},
        "out": {"scheduled": False},
    },
    "edges": [["imu", "lo"], ["hi", "out"], ["lo", "out"]],
    "subchains": {"hi": ["hi"], "lo": ["lo"]},
    "objective": [{"chain": ["hi", "out"], "weight": 1.0}, {"chain": ["imu", "lo", "out"], "weight": 0.1}],
    "baseline": {"rates_hz": {"hi": 100, "lo": 100}},
}

# cam (4 ms) -> det (6 ms), one subchain: catanc runs it dedicated at 50 Hz; the baseline at 25 Hz.
ONE_SUBCHAIN: dict[str, Any] = {
    "catan": 1,
    "app": "one",
    "nodes": {"cam": {"compute_ms": 4}, "det": {"compute_ms": 6}, "out": {"scheduled": False}},
    "edges": [["cam", "det"], ["det", "out"]],
    "subchains": {"main": ["cam", "det"]},
    "objective": [{"chain": ["cam", "det", "out"], "weight": 1.0}],
    "constraints": [{"node": "cam", "max_rate_hz": 50}],
    "baseline": {"rates_hz": {"cam": 25}},
}


def constant(spec: Spec, _seed: int) -> Any:
    return lambda node, _at_s: spec.nodes[node].mean_compute_ms


def chain_response(document: dict[str, Any], policy: str, first: str, **options: Any) -> tuple[float, float]:
    """(mean, max) response of the chain starting at ``first`` over 2 s."""
    spec = spec_of(document)
    if options.pop("engine", "python") == "compiled":  # no workload in the spec: it draws the constant times
        result = simulate(Setup(spec, 1, 2.0, 0), policy, engine="compiled", **options)
    else:
        result = simulate(Setup(spec, 1, 2.0, 0), policy, constant, engine="python", **options)
    (chain,) = [c for c in result.chains if c.nodes[0] == first]
    assert chain.response is not None
    return chain.response.mean, chain.response.max


@pytest.mark.parametrize("engine", ["python", "compiled"])
def test_a_run_waiting_behind_a_higher_level_reads_when_it_first_runs(engine: str) -> None:
    # lo is triggered at 10k ms but runs 10k+3 .. 10k+4, after hi: it reads imu's tick at 10k+2,
    # not the one at 10k.  Each output is measured from the origin before it: 10k+4 - (10(k-1)+2) = 12.
    # (Read at the trigger it would be 14.)
    assert chain_response(BEHIND, "fifo-static", "imu", engine=engine) == pytest.approx((12.0, 12.0))
