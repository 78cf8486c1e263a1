"""Issue 49 item 3: VR's simulated chain ratios against fifo-static, step by step towards the real kernel's.

    python -m benchmarks.vr_agreement                   # seed 0, 15 s, as `catanc bench --duration 15`
    python -m benchmarks.vr_agreement --seeds 20 --duration 60

Each row simulates ``specs/vr_illixr.yaml`` on 1 core with ``catan`` and ``fifo-static`` under one
model of the runtime, adding one term per row, and prints each chain's mean and p95 against
fifo-static's (paired by seed).  The delays are those ``catanc report`` and a traced ``catanc bench``
measured on the 2-core development VM (docs/results.md, section 4, "Simulator and kernel"):

- ``spec``: the spec's plan, no delays (the committed results);
- ``+ delays``: fifo-static's driver wakes a triggered node 0.2 ms late (its timer's lateness and the
  hop); catanc's enforcer switches 0.05 ms late and wakes a head or the next node 0.09 ms after it;
- ``+ costs``: catanc plans with the slack its measured costs raise it to (0.08: the enforcer's
  share of the core beside Linux's 5%), as the real enforcer re-plans after 2 s;
- ``+ 0.2 ms a run``: every run takes 0.2 ms more CPU than its draw (what the real runtime spends
  around a run: the worker's done message and record, the enforcer's or driver's wake-ups for it;
  ``catanc report`` measured the enforcer alone at 0.055-0.08 ms a wake-up).  Not a term of the
  simulator: a what-if, made with a sampler.
"""

from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path

from benchmarks.scenarios import VR_CHAINS
from catanc.model.load import load_spec
from catanc.sim.policies import NO_DELAYS, Delays, Sampler
from catanc.sim.simulate import SamplerFactory, Setup, simulate, workload_sampler
from catanc.spec.language import Spec

SPEC = Path(__file__).resolve().parent.parent / "specs" / "vr_illixr.yaml"
DRIVER = Delays(wake_ms=0.2)
ENFORCER = Delays(wake_ms=0.09, switch_late_ms=0.05)
MEASURED_SLACK = 0.08
RUN_OVERHEAD_MS = 0.2
T_975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 10: 2.228, 20: 2.093}


def with_slack(spec: Spec, slack: float) -> Spec:
    return spec.model_copy(update={"schedule": spec.schedule.model_copy(update={"slack": slack})})


def with_overhead(overhead_ms: float) -> SamplerFactory:
    """The spec's workload model with ``overhead_ms`` more on every run."""

    def sampler_for(spec: Spec, seed: int) -> Sampler:
        draw = workload_sampler(spec, seed)
        return lambda node, at_s: draw(node, at_s) + overhead_ms

    return sampler_for


def chain_figures(
    spec: Spec, policy: str, seed: int, duration_s: float, delays: Delays, *, overhead_ms: float = 0.0
) -> dict[str, tuple[float, float]]:
    sampler_for = with_overhead(overhead_ms) if overhead_ms else workload_sampler
    result = simulate(Setup(spec, 1, duration_s, seed), policy, sampler_for, engine="python", delays=delays)
    by_nodes = {chain.nodes: chain.response for chain in result.chains}
    out = {}
    for name, nodes in VR_CHAINS.items():
        summary = by_nodes[tuple(nodes)]
        assert summary is not None
        out[name] = (summary.mean, summary.p95)
    return out


def half_width(values: list[float]) -> float:
    if len(values) < 2:
        return 0.0
    t = T_975.get(len(values) - 1, 1.96)
    return t * statistics.stdev(values) / math.sqrt(len(values))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--duration", type=float, default=15.0)
    args = parser.parse_args()
    base = load_spec(SPEC)
    rows = [
        ("spec", base, NO_DELAYS, NO_DELAYS, 0.0),
        ("+ delays", base, ENFORCER, DRIVER, 0.0),
        ("+ costs", with_slack(base, MEASURED_SLACK), ENFORCER, DRIVER, 0.0),
        ("+ 0.2 ms a run", with_slack(base, MEASURED_SLACK), ENFORCER, DRIVER, RUN_OVERHEAD_MS),
    ]
    print(f"{args.seeds} seed(s) x {args.duration:g} s, 1 core; catan against fifo-static, per chain: mean, p95")
    for label, spec, catan_delays, fifo_delays, overhead in rows:
        ratios: dict[str, list[tuple[float, float]]] = {name: [] for name in VR_CHAINS}
        for seed in range(args.seeds):
            catan = chain_figures(spec, "catan", seed, args.duration, catan_delays, overhead_ms=overhead)
            fifo = chain_figures(base, "fifo-static", seed, args.duration, fifo_delays, overhead_ms=overhead)
            for name in VR_CHAINS:
                ratios[name].append((catan[name][0] / fifo[name][0] - 1, catan[name][1] / fifo[name][1] - 1))
        cells = []
        for name, pairs in ratios.items():
            means, p95s = [100 * m for m, _ in pairs], [100 * p for _, p in pairs]
            cells.append(
                f"{name} {statistics.mean(means):+.1f}% ± {half_width(means):.1f} / {statistics.mean(p95s):+.1f}%"
                f" ± {half_width(p95s):.1f}"
            )
        print(f"{label:15s}", " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
