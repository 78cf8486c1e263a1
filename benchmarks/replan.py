"""Planning and re-planning speed, and what planning Stage I's runners-up buys.

    python -m benchmarks.replan            # tables
    python -m benchmarks.replan --json     # the same numbers as JSON
    python -m benchmarks.replan --quick    # fewer repeats (a smoke run)

Sections:

- ``resolve``: :meth:`catanc.Replanner.resolve` on nav2d (2 cores) and VR
  (1 core), warm, with every compute time drifting by up to 3% between
  calls (as the runtime's re-measured p95s do); where the time goes; one
  relaxation re-solve alone, by the conic model and by cvxpy.
- ``at_scale``: the Autoware reference system (benchmarks/autoware.yaml) on 1-8 cores:
  the first plan, then warm ``resolve`` and ``reallocate`` calls with drifting times.
- ``cold``: a fresh process: importing the planner, building a
  ``Replanner`` (both stages, runners-up included) and its first resolve.
- ``commands``: whole-process times of ``catanc validate`` and ``catanc explain``.
- ``runners_up``: every example spec on 1-4 cores: the paper's plain
  two-stage objective against the best allocation under exact Stage II.

Numbers go into benchmarks/RESULTS.md by hand, with the machine they came from.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.solvers import median_ms
from catanc.model.load import load_spec
from catanc.planning.replan import RUNTIME_GAP
from catanc.planning.types import Plan

ROOT = Path(__file__).resolve().parent.parent
PAPER_STAGE2_MS = {"nav2d": 25.0, "vr_illixr": 5.5}  # C++/Mosek, paper section 6 (24-26 ms, 5-6 ms)
TARGET_RESOLVE_MS = {"nav2d": 1.0, "vr_illixr": 0.5}
PROTOTYPE_RESOLVE_MS = {"nav2d": 0.40, "vr_illixr": 0.19}  # one relaxed re-solve of a throwaway prototype
DRIFT = 0.03


def resolve_speed(name: str, cores: int, repeats: int, gap: float) -> dict[str, Any]:
    from catanc.planning.replan import Replanner  # noqa: PLC0415
    from catanc.planning.stage2.relaxed import RelaxedStage2  # noqa: PLC0415

    spec = load_spec(ROOT / "specs" / f"{name}.yaml")
    replanner = Replanner(spec, cores, gap=gap)
    times = {
        node: c
        for sub in replanner.spec_problem.subchains
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
    }
    rng = random.Random(1)
    drifts = [{node: c * rng.uniform(1 - DRIFT, 1 + DRIFT) for node, c in times.items()} for _ in range(repeats)]
    # Untimed: the first re-solve builds the conic model of the layout in slot order, which re-solves keep;
    # the first plan's models are keyed by its layouts in the spec's order (so before it: no model found).
    replanner.resolve(times)
    layout = replanner.layout
    model = replanner.models.get(layout)
    in_solver = 0.0
    solves = 0
    if model is not None:
        original = model.solve

        def timed(scale: float = 1.0) -> Any:
            nonlocal in_solver, solves
            started = time.perf_counter()
            try:
                return original(scale)
            finally:
                in_solver += time.perf_counter() - started
                solves += 1

        model.solve = timed  # type: ignore[method-assign]
    elapsed = []
    for drift in drifts:
        started = time.perf_counter()
        replanner.resolve(drift)
        elapsed.append((time.perf_counter() - started) * 1000)
    row: dict[str, Any] = {
        "resolve_median_ms": round(statistics.median(elapsed), 3),
        "resolve_p90_ms": round(sorted(elapsed)[int(0.9 * len(elapsed))], 3),
        "relaxations_per_resolve": round(solves / repeats, 2),
        "share_in_relaxations": round(in_solver * 1000 / sum(elapsed), 3),
        "paper_ms": PAPER_STAGE2_MS[name],
        "target_ms": TARGET_RESOLVE_MS[name],
        "prototype_one_resolve_ms": PROTOTYPE_RESOLVE_MS[name],
    }
    row["vs_paper"] = round(PAPER_STAGE2_MS[name] / row["resolve_median_ms"], 1)
    if model is not None:
        model.solve = original  # type: ignore[method-assign]
        reference = RelaxedStage2(replanner.problem, layout, spec.schedule)
        reference.set_numbers(replanner.problem)
        reference.solve()

        drifted = replanner.problem.with_compute(drifts[0])

        def relaxed(which: Any) -> None:
            which.set_numbers(drifted)  # new numbers, the root box, one solve: the prototype's measure
            which.set_box({})
            which.solve()

        row["one_relaxation_conic_ms"] = round(median_ms(lambda: relaxed(model), repeats), 3)
        row["one_relaxation_cvxpy_ms"] = round(median_ms(lambda: relaxed(reference), max(5, repeats // 5)), 3)
    return row


def at_scale(cores: int, repeats: int) -> dict[str, float]:
    """The Autoware reference system (benchmarks/autoware.yaml): ``Replanner.resolve`` and ``reallocate``, warm.

    Every compute time drifts by up to :data:`DRIFT` between calls, with the runtime's default gap.
    """
    from catanc.planning.replan import Replanner  # noqa: PLC0415

    spec = load_spec(ROOT / "benchmarks" / "autoware.yaml")
    started = time.perf_counter()
    replanner = Replanner(spec, cores)
    first_ms = (time.perf_counter() - started) * 1000
    times = {
        node: c
        for sub in replanner.spec_problem.subchains
        for node, c in zip(sub.nodes, sub.node_compute_ms, strict=True)
    }
    rng = random.Random(1)

    def drifted() -> dict[str, float]:
        return {node: c * rng.uniform(1 - DRIFT, 1 + DRIFT) for node, c in times.items()}

    resolves, reallocations = [], []
    for _ in range(repeats):
        started = time.perf_counter()
        replanner.resolve(drifted())
        resolves.append((time.perf_counter() - started) * 1000)
    for _ in range(max(3, repeats // 20)):
        started = time.perf_counter()
        replanner.reallocate(drifted())
        reallocations.append((time.perf_counter() - started) * 1000)
    return {
        "first_plan_ms": round(first_ms, 1),
        "resolve_median_ms": round(statistics.median(resolves), 2),
        "resolve_max_ms": round(max(resolves), 2),
        "reallocate_median_ms": round(statistics.median(reallocations), 1),
        "reallocate_max_ms": round(max(reallocations), 1),
    }


def cold(name: str, cores: int) -> dict[str, float]:
    """A fresh interpreter: import, build a Replanner (both stages), first resolve."""
    script = f"""
import json, time
started = time.perf_counter()
from catanc.planning.replan import Replanner
from benchmarks.solvers import median_ms
from catanc.model.load import load_spec
from catanc.planning.replan import RUNTIME_GAP
imported = time.perf_counter()
spec = load_spec({str(ROOT / "specs" / f"{name}.yaml")!r})
loaded = time.perf_counter()
replanner = Replanner(spec, {cores})
built = time.perf_counter()
replanner.resolve({{}})
resolved = time.perf_counter()
print(json.dumps({{"import_ms": (imported - started) * 1e3, "load_ms": (loaded - imported) * 1e3,
                   "replanner_ms": (built - loaded) * 1e3, "first_resolve_ms": (resolved - built) * 1e3}}))
"""
    runs = [
        json.loads(subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True).stdout)
        for _ in range(3)
    ]
    return {key: round(statistics.median(run[key] for run in runs), 1) for key in runs[0]}


def commands(repeats: int) -> dict[str, float]:
    catanc = str(Path(sys.executable).with_name("catanc"))
    cases = {
        "catanc validate specs/nav2d.yaml": [catanc, "validate", "specs/nav2d.yaml"],
        "catanc explain specs/nav2d.yaml -k 2": [catanc, "explain", "specs/nav2d.yaml", "-k", "2"],
        "catanc explain specs/vr_illixr.yaml -k 1": [catanc, "explain", "specs/vr_illixr.yaml", "-k", "1"],
    }
    rows = {}
    for label, command in cases.items():

        def run_command(command: list[str] = command) -> None:
            subprocess.run(command, check=True, capture_output=True, cwd=ROOT)

        rows[label] = round(median_ms(run_command, repeats), 0)
    return rows


def ranked_by(plan: Plan) -> float:
    """What the planner ranks plans by: the objective as run, where an executor's thread makes it differ."""
    return plan.objective if plan.objective_as_run is None else plan.objective_as_run


def runners_up() -> list[dict[str, Any]]:
    from catanc.planning.planner import plan  # noqa: PLC0415

    rows = []
    for path in sorted((ROOT / "specs").glob("*.yaml")):
        spec = load_spec(path)
        for cores in (1, 2, 3, 4):
            started = time.perf_counter()
            ours = plan(spec, cores)
            took = (time.perf_counter() - started) * 1000
            started = time.perf_counter()
            paper = plan(spec, cores, runners_up=False)
            took_paper = (time.perf_counter() - started) * 1000
            # Plans are ranked by the objective as run (an executor's thread counted): compare that.
            two_stage, best = ranked_by(paper), ranked_by(ours)
            better = (two_stage - best) / two_stage if two_stage else 0.0
            rows.append(
                {
                    "spec": path.stem,
                    "cores": cores,
                    "two_stage": round(two_stage, 4),
                    "best": round(best, 4),
                    "lower_by": round(better, 4),
                    "allocations": ours.comparison.allocations,
                    "planned": ours.comparison.planned,
                    "changed": ours.allocation != paper.allocation,
                    "plan_ms": round(took, 1),
                    "two_stage_ms": round(took_paper, 1),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    args = parser.parse_args()
    repeats = 50 if args.quick else 500
    report: dict[str, Any] = {
        "resolve": {
            f"{name}, {cores} core(s){label}": resolve_speed(name, cores, repeats, gap)
            for name, cores in [("nav2d", 2), ("vr_illixr", 1)]
            for gap, label in [(0.0, ", exact"), (RUNTIME_GAP, ", default gap")]
        },
        "at_scale": {f"autoware, {cores} core(s)": at_scale(cores, repeats // 10) for cores in (1, 2, 4, 8)},
        "cold": {f"{name}, {cores} core(s)": cold(name, cores) for name, cores in [("nav2d", 2), ("vr_illixr", 1)]},
        "commands": commands(3 if args.quick else 7),
        "runners_up": runners_up(),
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return
    print(f"Replanner.resolve, warm (median of {repeats}; compute times drift up to {DRIFT:.0%} per call)")
    print(
        f"{'app':<34}{'median ms':>10}{'p90 ms':>8}{'target':>8}{'x paper':>9}{'GPs/call':>10}{'in GPs':>8}"
        f"{'1 GP conic':>12}{'1 GP cvxpy':>12}"
    )
    for label, row in report["resolve"].items():
        print(
            f"{label:<34}{row['resolve_median_ms']:>10}{row['resolve_p90_ms']:>8}{row['target_ms']:>8}{row['vs_paper']:>9}"
            f"{row['relaxations_per_resolve']:>10}{row['share_in_relaxations']:>8.0%}"
            f"{row.get('one_relaxation_conic_ms', '-'):>12}{row.get('one_relaxation_cvxpy_ms', '-'):>12}"
        )
    print(f"\nThe Autoware reference system, warm (drift up to {DRIFT:.0%} per call, default gap; ms)")
    print(f"{'':<22}{'first plan':>11}{'resolve':>9}{'max':>9}{'reallocate':>12}{'max':>9}")
    for label, row in report["at_scale"].items():
        print(
            f"{label:<22}{row['first_plan_ms']:>11}{row['resolve_median_ms']:>9}{row['resolve_max_ms']:>9}"
            f"{row['reallocate_median_ms']:>12}{row['reallocate_max_ms']:>9}"
        )
    print("\nCold, in a fresh process (median of 3; ms)")
    for label, row in report["cold"].items():
        print(f"{label:<22}" + "  ".join(f"{key} {value}" for key, value in row.items()))
    print("\nWhole-process command times (ms)")
    for label, value in report["commands"].items():
        print(f"{label:<44}{value:>8}")
    print(
        "\nStage I's runners-up under exact Stage II, against the paper's plain two-stage plan "
        "(objectives as run: an executor's thread counted)"
    )
    print(
        f"{'spec':<16}{'K':>3}{'two-stage':>11}{'best':>10}{'lower by':>10}{'allocs':>8}{'planned':>9}"
        f"{'plan ms':>9}{'2-stage ms':>11}"
    )
    for row in report["runners_up"]:
        print(
            f"{row['spec']:<16}{row['cores']:>3}{row['two_stage']:>11}{row['best']:>10}{row['lower_by']:>10.2%}"
            f"{row['allocations']:>8}{row['planned']:>9}{row['plan_ms']:>9}{row['two_stage_ms']:>11}"
        )


if __name__ == "__main__":
    main()
