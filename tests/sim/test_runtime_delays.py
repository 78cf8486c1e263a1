"""What the simulator models of the real runtime (issue 49 item 3), worked by hand on one core.

- A run reads its inputs when it first runs, as a real thread does when it wakes (``catanc bench``'s
  workers record their start then), not when it is triggered: fifo-static's VR Render, triggered
  at vsync behind Timewarp, reads the IMU sample that came while it waited.
- :class:`~catanc.sim.policies.Delays`: the runtime's wake-up (a trigger to its thread running) and
  the enforcer's late slot switches, each a constant the caller measures (``catanc report``); the
  CPU a node's thread spends before and after each run (``benchmarks.vr_run_cpu``), and the
  enforcer's CPU at each slot switch.

Both engines read at the first run (the compiled one is held to the Python one); delays are the
Python engine's only.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.control.policy import boundary_ms
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


@settings(max_examples=10, deadline=None)
@given(before=st.floats(0.0, 2.0), after=st.floats(0.0, 2.0))
def test_cpu_around_each_run_of_catancs_dedicated_subchain(before: float, after: float) -> None:
    # cam triggered every 20 ms: it runs b + 4 ms (b before its work, then its output), its thread
    # goes on for a more at the front of the level, then det runs b + 6: done at 20k + 10 + 2b + a,
    # measured from the origin before it (20(k-1), cam's first CPU): 30 + 2b + a.
    got = chain_response(ONE_SUBCHAIN, "catan", "cam", delays=Delays(before_run_ms=before, after_run_ms=after))
    assert got == pytest.approx((30.0 + 2 * before + after, 30.0 + 2 * before + after))


@settings(max_examples=10, deadline=None)
@given(before=st.floats(0.0, 0.45), after=st.floats(0.0, 0.45))
def test_cpu_around_each_run_under_fifo_static(before: float, after: float) -> None:
    # At 10k ms hi runs b + 3 ms, then its thread's a (its level is above lo's), then lo b + 1, reading
    # imu's tick at 10k + 2 (it first runs at 10k + 3 + b + a < 10k + 4): done at 10k + 4 + 2b + a,
    # measured from the origin before it, 10(k-1) + 2: 12 + 2b + a.
    got = chain_response(BEHIND, "fifo-static", "imu", delays=Delays(before_run_ms=before, after_run_ms=after))
    assert got == pytest.approx((12.0 + 2 * before + after, 12.0 + 2 * before + after))


@pytest.mark.parametrize("cpu", [0.005, 0.02])
def test_the_enforcers_cpu_at_each_switch_fills_the_core_and_never_shortens_a_chain(cpu: float) -> None:
    # A job of c ms above every node at each boundary: the core is busier by c for every boundary
    # before the end, less what the app's work, later by a few c, has not done by the end (under
    # 10 c here); a head first runs c after its switch and a run that crosses its slot's end loses
    # c more there, so no response gets shorter.
    spec = spec_of(TWO_SHARED)
    duration_ms = 1900.0

    def run(delays: Delays) -> tuple[list[float], float, int]:
        result = simulate(Setup(spec, 1, duration_ms / 1000, 0), "catan", constant, engine="python", delays=delays)
        assert result.schedule is not None
        (core,) = result.schedule.shared
        boundaries = sum(
            1
            for k in range(int(duration_ms // core.period_ms) + 1)
            for position in range(len(core.slots) + 1)
            if k * core.period_ms < duration_ms and boundary_ms(core, k * core.period_ms, position) < duration_ms
        )
        responses = [value for c in result.chains if c.response for value in (c.response.mean, c.response.max)]
        return responses, result.utilisation[0] * duration_ms, boundaries

    on_time, busy, _ = run(Delays())
    slower, busy_with, boundaries = run(Delays(switch_cpu_ms=cpu))
    assert len(slower) == len(on_time) == 4
    assert all(got >= want - 1e-9 for got, want in zip(slower, on_time, strict=True))
    assert busy + (boundaries - 10) * cpu <= busy_with <= busy + boundaries * cpu + 1e-6


@pytest.mark.parametrize(("before", "after"), [(0.1, 0.05), (0.3, 0.0)])
def test_a_run_charged_with_the_cpu_around_it_gets_that_much_more_slot_after_the_replan(
    before: float, after: float
) -> None:
    # After the re-solve at 2 s, fast's slot is the p95 of its measured compute: 1 ms when a run
    # reports its work only (the CPU around it goes unplanned), 1 + b + a when charged with it.
    spec = spec_of(TWO_SHARED)

    def fast_slot_ms(delays: Delays) -> float:
        result = simulate(Setup(spec, 1, 2.5, 0), "catan", constant, engine="python", delays=delays)
        assert result.schedule is not None
        assert result.replans == 1
        (core,) = result.schedule.shared
        (slot,) = [slot for slot in core.slots if slot.subchain == "fast"]
        return slot.length_ms

    assert fast_slot_ms(Delays(before_run_ms=before, after_run_ms=after)) == pytest.approx(1.0)
    charged = Delays(before_run_ms=before, after_run_ms=after, charged=True)
    assert fast_slot_ms(charged) == pytest.approx(1.0 + before + after)


def test_the_compiled_engine_refuses_delays_and_negative_ones_are_refused() -> None:
    spec = spec_of(ONE_SUBCHAIN)
    refused = (Delays(wake_ms=0.1), Delays(before_run_ms=0.1), Delays(after_run_ms=0.1), Delays(switch_cpu_ms=0.1))
    for delays in (*refused, Delays(charged=True)):
        with pytest.raises(UsageError, match="delays"):
            simulate(Setup(spec, 1, 1.0, 0), "baseline", engine="compiled", delays=delays)
    for field in ("wake_ms", "switch_late_ms", "before_run_ms", "after_run_ms", "switch_cpu_ms"):
        with pytest.raises(ValueError, match="negative"):
            Delays(**{field: -0.1})  # type: ignore[arg-type]
