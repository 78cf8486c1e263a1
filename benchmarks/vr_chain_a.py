"""Issue 49 item 4: when VR's Timewarp runs late, and whether catanc's stealing recovers chain A.

    python -m benchmarks.vr_chain_a                      # 20 seeds x 15 s, 1 core
    python -m benchmarks.vr_chain_a --seeds 20 --duration 60

``specs/vr_illixr.yaml`` on 1 core, ``catan``, ``catan-nosteal`` and ``fifo-static`` on the same
seeds, under variations of what the spec's model leaves out (the workload and the baseline stay the
spec's): none; the runtime's delays as measured (:mod:`benchmarks.vr_agreement`); the same at their
p95s; and the IMU's clock shifted against the schedule.  Per row: chain A's mean against
fifo-static's, paired by seed, with its 95% interval, and the share of Timewarp's runs that end
more than ``LATE_AFTER_MS`` after their vsync (Timewarp's slot holds its p95 compute, ~1.8 ms, plus
the switch: a run that ends later crossed its slot's end and waited behind VIO or Render).
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Callable
from pathlib import Path

import numpy as np

import catanc.sim.simulate as simulate_module
from benchmarks.vr_agreement import DRIVER, ENFORCER, half_width
from catanc.model.load import load_spec
from catanc.sim import policies
from catanc.sim.dataflow import Dataflow
from catanc.sim.engine import Engine
from catanc.sim.policies import NO_DELAYS, Delays
from catanc.sim.simulate import Setup, simulate
from catanc.spec.language import Spec

SPEC = Path(__file__).resolve().parent.parent / "specs" / "vr_illixr.yaml"
CHAIN_A = ("IMU", "Int", "Timewarp", "Display")
VSYNC_MS = 1000.0 / 120.0
LATE_AFTER_MS = 2.5
ENFORCER_P95 = Delays(wake_ms=0.15, switch_late_ms=0.1)
DRIVER_P95 = Delays(wake_ms=0.35)


def shifted_sensors(phase_ms: float) -> Callable[[Engine, Dataflow, Spec], None]:
    """Unscheduled clocks ticking from ``phase_ms`` instead of 0 (the IMU against the schedule's period)."""

    def start(engine: Engine, flow: Dataflow, spec: Spec) -> None:
        policies.start_sensors(engine, flow, spec, phase_ms)

    return start


def run(policy: str, seed: int, duration_s: float, delays: Delays, phase_ms: float) -> tuple[float, float]:
    """Chain A's mean response and the share of Timewarp's runs that end late in their vsync period."""
    spec = load_spec(SPEC)
    # The simulator's sensors tick from 0; this benchmark alone shifts them (the real IMU's phase).
    setattr(simulate_module, "start_sensors", shifted_sensors(phase_ms))  # noqa: B010
    try:
        result = simulate(Setup(spec, 1, duration_s, seed), policy, engine="python", delays=delays)
    finally:
        setattr(simulate_module, "start_sensors", policies.start_sensors)  # noqa: B010
    (chain,) = [c for c in result.chains if c.nodes == CHAIN_A]
    assert chain.response is not None
    done = np.asarray(result.node_done_ms["Timewarp"])
    late = float(np.mean(np.mod(done, VSYNC_MS) > LATE_AFTER_MS)) if len(done) else 0.0
    return chain.response.mean, late


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--duration", type=float, default=15.0)
    args = parser.parse_args()
    rows = [
        ("the spec's model", NO_DELAYS, NO_DELAYS, 0.0),
        ("delays as measured", ENFORCER, DRIVER, 0.0),
        ("delays at their p95", ENFORCER_P95, DRIVER_P95, 0.0),
        ("IMU from 1.66 ms", NO_DELAYS, NO_DELAYS, 1.66),
        ("p95 delays, IMU from 1.66 ms", ENFORCER_P95, DRIVER_P95, 1.66),
    ]
    print(f"{args.seeds} seeds x {args.duration:g} s, 1 core: chain A against fifo-static (paired, 95% interval)")
    for label, enforcer, driver, phase in rows:
        fifo = [run("fifo-static", seed, args.duration, driver, phase) for seed in range(args.seeds)]
        cells = []
        for policy in ("catan", "catan-nosteal"):
            got = [run(policy, seed, args.duration, enforcer, phase) for seed in range(args.seeds)]
            ratios = [100 * (mine / theirs - 1) for (mine, _), (theirs, _) in zip(got, fifo, strict=True)]
            late = statistics.mean(share for _, share in got)
            cells.append(
                f"{policy} {statistics.mean(ratios):+.1f}% ± {half_width(ratios):.1f} (late {100 * late:.1f}%)"
            )
        fifo_late = statistics.mean(share for _, share in fifo)
        fifo_a = statistics.mean(mean for mean, _ in fifo)
        print(
            f"{label:26s} fifo-static A {fifo_a:.2f} ms (late {100 * fifo_late:.1f}%) | " + " | ".join(cells),
            flush=True,
        )


if __name__ == "__main__":
    main()
