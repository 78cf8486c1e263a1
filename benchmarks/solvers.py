"""Solver speed: Stage I on the paper's nav2d and on random layered apps.

    python -m benchmarks.solvers            # a table
    python -m benchmarks.solvers --json     # the same numbers as JSON
    python -m benchmarks.solvers --quick    # fewer repeats and sizes (a smoke run)

Numbers go into benchmarks/RESULTS.md by hand, with the machine they came from.
Tests never time anything; this file is where speed is measured.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.model.problem import Problem
from catanc.planning.stage1 import allocate
from catanc.planning.stage1.milp import DEFAULT_TIME_LIMIT_S, relaxation_bound
from catanc.spec.language import Spec
from tests.support.layered_apps import layered_spec

ROOT = Path(__file__).resolve().parent.parent
PAPER_STAGE1_NAV2D_MS = 60.0  # C++/Mosek, nav on 2 cores (paper section 6)
TARGET_STAGE1_NAV2D_MS = 6.0
PROTOTYPE_STAGE1_NAV2D_MS = 16.0  # a throwaway prototype of the model, through pulp


def median_ms(run: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append((time.perf_counter() - started) * 1000)
    return statistics.median(times)


def nav2d_stage1(repeats: int) -> dict[str, Any]:
    problem = build_problem(load_spec(ROOT / "specs" / "nav2d.yaml"))
    rows: dict[str, Any] = {}
    for label, kwargs in [
        ("auto (default: enumerates)", {}),
        ("exhaustive", {"method": "exhaustive"}),
        ("milp/highs", {"method": "milp", "solver": "highs"}),
        ("milp/cbc", {"method": "milp", "solver": "cbc"}),
    ]:
        first_started = time.perf_counter()
        result = allocate(problem, 2, **kwargs)  # type: ignore[arg-type]
        first = (time.perf_counter() - first_started) * 1000
        warm = median_ms(lambda kw=kwargs: allocate(problem, 2, **kw), repeats)  # type: ignore[misc]
        rows[label] = {
            "first_ms": round(first, 2),
            "median_ms": round(warm, 3),
            "vs_paper": round(PAPER_STAGE1_NAV2D_MS / warm, 1),
            "vs_target": round(TARGET_STAGE1_NAV2D_MS / warm, 2),
            "objective": round(result.objective, 4),
        }
    return rows


def stage2_examples(repeats: int) -> dict[str, Any]:
    """Stage II on the example specs: whole plans, and the GP's first and warm solves."""
    from catanc.planning.planner import ordered_layout, plan  # noqa: PLC0415 - cvxpy only for this section
    from catanc.planning.stage2.integer import solve_integer  # noqa: PLC0415
    from catanc.planning.stage2.relaxed import Layout, RelaxedStage2  # noqa: PLC0415

    rows: dict[str, Any] = {}
    for name, cores in [("nav2d", 1), ("nav2d", 2), ("vr_illixr", 1), ("nav2d_yolo", 1)]:
        spec = load_spec(ROOT / "specs" / f"{name}.yaml")
        problem = build_problem(spec)
        layout = ordered_layout(
            Layout.from_allocation(allocate(problem, cores).allocation), spec.schedule, problem.importance(), problem
        )
        started = time.perf_counter()
        model = RelaxedStage2(problem, layout, spec.schedule)
        model.set_numbers(problem)
        relaxed = model.solve()
        first = (time.perf_counter() - started) * 1000

        def warm(gp: RelaxedStage2 = model, numbers: Problem = problem) -> None:
            gp.set_numbers(numbers)  # as the runtime would, with re-measured compute times
            gp.solve()

        def whole_plan(spec: Spec = spec, cores: int = cores) -> None:
            plan(spec, cores)

        integer = solve_integer(model, problem)
        if relaxed is None or integer is None:
            raise RuntimeError(f"{name}: Stage II found no plan")
        rows[f"{name}, {cores} core{'s' if cores > 1 else ''}"] = {
            "plan_ms": round(median_ms(whole_plan, max(3, repeats // 20)), 1),
            "gp_first_ms": round(first, 1),
            "gp_warm_ms": round(median_ms(warm, max(3, repeats // 2)), 2),
            "relaxations": integer.nodes,
            "relaxed": round(relaxed.objective, 4),
            "integer": round(integer.objective, 4),
        }
    return rows


def scaling(
    sizes: list[int], cores: list[int], seeds: list[int], solvers: list[str], progress: Callable[[str], None]
) -> list[dict[str, Any]]:
    rows = []
    for size in sizes:
        problems: list[Problem] = [build_problem(layered_spec(size, seed)) for seed in seeds]
        for k in cores:
            for solver in solvers:
                times, gaps, proven = [], [], 0
                for problem in problems:
                    started = time.perf_counter()
                    result = allocate(problem, k, method="milp", solver=solver)
                    times.append((time.perf_counter() - started) * 1000)
                    proven += result.optimal
                    gaps.append(result.gap)
                known = [g for g in gaps if g is not None]
                rows.append(
                    {
                        "subchains": size,
                        "cores": k,
                        "solver": solver,
                        "median_ms": round(statistics.median(times), 1),
                        "max_ms": round(max(times), 1),
                        "proven_optimal": f"{proven}/{len(problems)}",
                        "max_gap": None if len(known) < len(gaps) else round(max(known), 5),
                    }
                )
                progress(_scaling_line(rows[-1]))
    return rows


def formulation(sizes: list[int], cores: list[int], seeds: list[int]) -> list[dict[str, Any]]:
    """LP bound with and without the rows g[m] >= x[i, m], against the best allocation known."""
    rows = []
    for size in sizes:
        for k in cores:
            for seed in seeds:
                problem = build_problem(layered_spec(size, seed))
                best = allocate(problem, k, method="milp", time_limit_s=60).objective
                plain = relaxation_bound(problem, k, strengthen=False)
                strong = relaxation_bound(problem, k, strengthen=True)
                rows.append(
                    {
                        "subchains": size,
                        "cores": k,
                        "seed": seed,
                        "best": round(best, 3),
                        "plain_lp_share": None if plain is None else round(plain / best, 4),
                        "strengthened_lp_share": None if strong is None else round(strong / best, 4),
                    }
                )
    return rows


def _scaling_line(row: dict[str, Any]) -> str:
    gap = "?" if row["max_gap"] is None else f"{row['max_gap']:.2%}"
    return (
        f"{row['subchains']:>4} {row['cores']:>3} {row['solver']:>6} {row['median_ms']:>9.1f} "
        f"{row['max_ms']:>9.1f} {row['proven_optimal']:>7} {gap:>8}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and sizes")
    args = parser.parse_args()
    repeats = 15 if args.quick else 100
    sizes = [10, 30] if args.quick else [10, 30, 60, 100]
    seeds = [1] if args.quick else [1, 2, 3]
    report: dict[str, Any] = {
        "stage1_time_limit_s": DEFAULT_TIME_LIMIT_S,
        "nav2d_2_cores": nav2d_stage1(repeats),
    }
    report["stage2"] = stage2_examples(repeats)
    if not args.json:
        print("Stage II on the example specs (plan: Stage I + Stage II; GP: the relaxed program via cvxpy)")
        print(f"{'app':<22}{'plan ms':>9}{'GP first':>10}{'GP warm':>9}{'B&B GPs':>9}{'relaxed':>10}{'integer':>10}")
        for label, row in report["stage2"].items():
            print(
                f"{label:<22}{row['plan_ms']:>9}{row['gp_first_ms']:>10}{row['gp_warm_ms']:>9}"
                f"{row['relaxations']:>9}{row['relaxed']:>10}{row['integer']:>10}"
            )
        print()
        print(
            f"Stage I, nav2d on 2 cores (median of {repeats}; paper {PAPER_STAGE1_NAV2D_MS:g} ms, target "
            f"{TARGET_STAGE1_NAV2D_MS:g} ms, prototype {PROTOTYPE_STAGE1_NAV2D_MS:g} ms)"
        )
        print(f"{'method':<28}{'first ms':>10}{'median ms':>11}{'x paper':>9}{'x target':>10}")
        for label, row in report["nav2d_2_cores"].items():
            print(
                f"{label:<28}{row['first_ms']:>10.2f}{row['median_ms']:>11.3f}{row['vs_paper']:>9}{row['vs_target']:>10}"
            )
        print(f"\nStage I MILP on random layered apps ({len(seeds)} seeds; time limit {DEFAULT_TIME_LIMIT_S} s)")
        print("   N   K solver median ms    max ms  proven  max gap")

    def progress(line: str) -> None:
        print(line, file=sys.stderr if args.json else sys.stdout, flush=True)

    report["scaling"] = scaling(sizes, [2, 4, 8, 16], seeds, ["highs", "cbc"], progress)
    report["formulation"] = formulation([30, 60], [4, 16], seeds[:2])
    if args.json:
        print(json.dumps(report, indent=2))
        return
    print("\nLP bound as a share of the best allocation (why the rows g[m] >= x[i, m] are there)")
    print("   N   K seed  plain LP  strengthened LP")
    for row in report["formulation"]:
        print(
            f"{row['subchains']:>4}{row['cores']:>4}{row['seed']:>5}{row['plain_lp_share']:>10}"
            f"{row['strengthened_lp_share']:>17}"
        )


if __name__ == "__main__":
    main()
