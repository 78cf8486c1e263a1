"""What the simulator models of the real runtime (issue 49 item 3), worked by hand on one core.

- A run reads its inputs when it first runs, as a real thread does when it wakes (``catanc bench``'s
  workers record their start then), not when it is triggered: fifo-static's VR Render, triggered
  at vsync behind Timewarp, reads the IMU sample that came while it waited.
- :class:`~catanc.sim.policies.Delays`: the runtime's wake-up (a trigger to its thread running) and
  the enforcer's late slot switches, each a constant the caller measures (``catanc report``).

Both engines read at the first run (the compiled one is held to the Python one); delays are the
Python engine's only.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.errors import UsageError
from catanc.sim.policies import Delays
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
    # (Read at its trigger, as before, it was 16: the timer fires before the tick at 10k, so lo read 10k-2.)
    assert chain_response(BEHIND, "fifo-static", "imu", engine=engine) == pytest.approx((12.0, 12.0))


def test_a_wake_up_delays_each_hop_of_the_baseline() -> None:
    # cam's timer at 40k ms, cam runs from 40k + d (its origin) for 4 ms, det d after it for 6 ms:
    # done at 40k + 2d + 10, measured from the origin before it, 40(k-1) + d: 50 + d.
    assert chain_response(ONE_SUBCHAIN, "baseline", "cam", delays=Delays(wake_ms=0.5)) == pytest.approx((50.5, 50.5))


def test_a_wake_up_delays_each_hop_of_catancs_dedicated_subchain() -> None:
    # Triggered every 20 ms: the same count as the baseline's, 20 + 10 + d.
    assert chain_response(ONE_SUBCHAIN, "catan", "cam", delays=Delays(wake_ms=0.5)) == pytest.approx((30.5, 30.5))


@settings(max_examples=10, deadline=None)
@given(wake=st.floats(0.0, 2.0), late=st.floats(0.0, 2.0))
def test_no_delay_is_the_model_and_a_delay_never_shortens_the_baseline(wake: float, late: float) -> None:
    # The baseline's chain is 50 ms without delays (the test above, d = 0); each of its two hops adds
    # the wake-up, its origin one of them; the enforcer's switches do not touch it.
    got = chain_response(ONE_SUBCHAIN, "baseline", "cam", delays=Delays(wake_ms=wake, switch_late_ms=late))
    assert got == pytest.approx((50.0 + wake, 50.0 + wake))


# fast (1 ms) and slow (10 ms) share catanc's one core: slot-triggered heads, no sensor.
TWO_SHARED: dict[str, Any] = {
    "catan": 1,
    "app": "two",
    "nodes": {"fast": {"compute_ms": 1}, "slow": {"compute_ms": 10}, "out": {"scheduled": False}},
    "edges": [["fast", "out"], ["slow", "out"]],
    "subchains": {"fast": ["fast"], "slow": ["slow"]},
    "objective": [{"chain": ["fast", "out"], "weight": 1.0}, {"chain": ["slow", "out"], "weight": 0.1}],
}


@settings(max_examples=3, deadline=None)
@given(late=st.floats(0.01, 1.0))
def test_switches_all_equally_late_shift_the_schedule_but_no_response(late: float) -> None:
    # Every switch (and so every head's trigger and every raise) moves by the same amount: each run
    # moves with its trigger, and a chain that starts at a scheduled head measures from that head's
    # run, so every response stays (1.9 s: before the first re-solve at 2 s).
    spec = spec_of(TWO_SHARED)

    def figures(delays: Delays) -> list[float]:
        result = simulate(Setup(spec, 1, 1.9, 0), "catan", constant, engine="python", delays=delays)
        return [value for c in result.chains if c.response for value in (c.response.mean, c.response.max)]

    on_time = figures(Delays())
    assert len(on_time) == 4
    assert figures(Delays(switch_late_ms=late)) == pytest.approx(on_time, abs=1e-6)


def test_the_compiled_engine_refuses_delays_and_negative_ones_are_refused() -> None:
    spec = spec_of(ONE_SUBCHAIN)
    with pytest.raises(UsageError, match="delays"):
        simulate(Setup(spec, 1, 1.0, 0), "baseline", engine="compiled", delays=Delays(wake_ms=0.1))
    with pytest.raises(ValueError, match="negative"):
        Delays(wake_ms=-0.1)
