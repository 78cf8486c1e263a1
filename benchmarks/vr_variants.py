"""Issue 30's VR target on VR specs that are not in the repo: chains A, B and C against FIFO static priorities.

    python -m benchmarks.vr_variants                       # 20 variants, 5 seeds each, 60 s, 1 core
    python -m benchmarks.vr_variants --variants 5 --seeds 2 --duration 20

Each variant is ``specs/vr_illixr.yaml`` with every scheduled node's compute time scaled by its own
factor drawn uniformly from [0.7, 1.3] and each jitter's cv from [0.5, 1.5] of the spec's
(a seeded draw: variant ``i`` is the same on every machine), so the DAG and the weights are the
paper's but the timings are not the ones the example spec was tuned with.  Each variant is simulated
on 1 core with ``catan`` and ``fifo-static`` over the same seeds (the same workload draws), and chain
A's, B's and C's mean responses are compared seed by seed (paired).  The issue's target: B at least 10%
lower than FIFO static's, A no more than 2% higher (C is shown, not judged: issue 49 asks it to be no
worse than fifo-static's).
"""

from __future__ import annotations

import argparse
import copy
import random
import statistics
from collections.abc import Mapping
from typing import Any

from benchmarks.scenarios import VR_CHAINS, response
from catanc.model.load import load_spec
from catanc.sim.simulate import Setup, simulate
from tests.support.scenario_specs import spec_file, spec_yaml

COMPUTE_SCALE = (0.7, 1.3)
CV_SCALE = (0.5, 1.5)
B_TARGET, A_TARGET = -0.10, 0.02


def variant(base: Mapping[str, Any], index: int) -> tuple[dict[str, Any], dict[str, float]]:
    """Variant ``index`` of ``base`` and the compute times it drew."""
    draw = random.Random(f"vr-variant-{index}")
    data = copy.deepcopy(dict(base))
    data["app"] = f"vr-variant-{index}"
    computes = {}
    for name, node in sorted(data["nodes"].items()):
        if "compute_ms" not in node:
            continue
        node["compute_ms"] = round(node["compute_ms"] * draw.uniform(*COMPUTE_SCALE), 3)
        computes[name] = node["compute_ms"]
        jitter = node.get("workload", {}).get("jitter")
        if jitter is not None:
            jitter["cv"] = round(jitter["cv"] * draw.uniform(*CV_SCALE), 3)
    return data, computes


def mean_responses(data: Mapping[str, Any], policy: str, seeds: range, duration_s: float) -> dict[str, list[float]]:
    """Per chain (A, B, C): the run's mean response, one per seed (nan where a chain had no output)."""
    with spec_file(data) as path:
        spec = load_spec(path)
    means: dict[str, list[float]] = {"A": [], "B": [], "C": []}
    for seed in seeds:
        result = simulate(Setup(spec, 1, duration_s, seed), policy)
        for chain, values in means.items():
            mean = response(result, VR_CHAINS[chain])["mean_ms"]
            values.append(float("nan") if mean is None else mean)
    return means


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", type=int, default=20)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--duration", type=float, default=60.0)
    args = parser.parse_args()
    base = spec_yaml("vr_illixr")
    seeds = range(args.seeds)
    print(
        "| variant | compute ms (Camera, VIO, Render, Timewarp) | A vs fifo-static | B vs fifo-static "
        "| C vs fifo-static | met? |"
    )
    print("|---|---|---|---|---|---|")
    met = 0
    for index in range(args.variants):
        data, computes = variant(base, index)
        catan = mean_responses(data, "catan", seeds, args.duration)
        fifo = mean_responses(data, "fifo-static", seeds, args.duration)
        ratio = {
            chain: statistics.fmean(a / b - 1.0 for a, b in zip(catan[chain], fifo[chain], strict=True))
            for chain in ("A", "B", "C")
        }
        ok = ratio["B"] <= B_TARGET and ratio["A"] <= A_TARGET
        met += ok
        times = ", ".join(f"{computes[n]:g}" for n in ("Camera", "VIO", "Render", "Timewarp"))
        shown = " | ".join(f"{ratio[chain]:+.1%}" for chain in ("A", "B", "C"))
        print(f"| {index} | {times} | {shown} | {'yes' if ok else 'no'} |", flush=True)
    print(f"\n{met} of {args.variants} variants meet both targets (B <= {B_TARGET:+.0%}, A <= {A_TARGET:+.0%})")


if __name__ == "__main__":
    main()
