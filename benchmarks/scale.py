"""Planning at scale: ``catanc explain --json`` of the Autoware reference system, this tree beside another.

    python -m benchmarks.scale [--old REF] [--runs 3] [--cores 1 2 4 8] [--spec benchmarks/autoware.yaml]

Issue 49's target: the Autoware reference system (16 processing nodes, 9
subchains, 53 chains: benchmarks/autoware.yaml) planned at K = 1, 2, 4, 8
within 2 s, whole process, on a quiet 2-core machine, with the same plans.
Each K's command runs in this tree and in a checkout of ``--old`` (default
``main``: a detached ``git worktree`` under a temporary folder, removed
afterwards), alternately, ``--runs`` rounds, so that a busy minute slows both
alike; both use this interpreter and its libraries. Reported per K: median
wall and CPU (user + system) seconds of each, their ratio, and whether the two
plans' objectives agree within 1e-9 (relatively).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 2.0
SAME_PLAN = 1e-9


def git(*argv: str) -> None:
    subprocess.run(["git", *argv], cwd=ROOT, check=True, capture_output=True)


def explain(tree: Path, spec: Path, cores: int) -> tuple[float, float, float]:
    """Wall and CPU seconds of one whole ``catanc explain --json`` process in ``tree``, and its plan's objective."""
    environment = {**os.environ, "PYTHONPATH": str(tree)}
    environment.pop("PYTHONDONTWRITEBYTECODE", None)
    argv = [sys.executable, "-m", "catanc", "explain", "--json", str(spec), "-k", str(cores)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run(argv, cwd=tree, env=environment, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, float(json.loads(done.stdout)["plan"]["objective"])


def measure(trees: dict[str, Path], spec: Path, cores: list[int], runs: int) -> list[dict[str, float | int | bool]]:
    rows = []
    for k in cores:
        explain(trees["new"], spec, k)  # untimed: bytecode and the page cache, for both trees alike
        explain(trees["old"], spec, k)
        times: dict[str, list[tuple[float, float]]] = {"old": [], "new": []}
        objectives: dict[str, float] = {}
        for _ in range(runs):
            for name in ("old", "new"):
                wall, cpu, objectives[name] = explain(trees[name], spec, k)
                times[name].append((wall, cpu))
        row: dict[str, float | int | bool] = {"cores": k}
        for name in ("old", "new"):
            row[f"{name}_wall_s"] = round(statistics.median(wall for wall, _ in times[name]), 2)
            row[f"{name}_cpu_s"] = round(statistics.median(cpu for _, cpu in times[name]), 2)
            row[f"{name}_objective"] = objectives[name]
        row["cpu_ratio"] = round(float(row["old_cpu_s"]) / float(row["new_cpu_s"]), 2)
        row["same_plan"] = abs(objectives["new"] - objectives["old"]) <= SAME_PLAN * abs(objectives["old"])
        row["not_worse"] = objectives["new"] <= objectives["old"] * (1 + SAME_PLAN)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", default="main", help="the git ref to compare with (default: main)")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--cores", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--spec", type=Path, default=ROOT / "benchmarks" / "autoware.yaml")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()
    spec = args.spec.resolve()
    with tempfile.TemporaryDirectory(prefix="catanc-old-") as folder:
        old = Path(folder) / "tree"
        git("worktree", "add", "--detach", str(old), args.old)
        try:
            rows = measure({"old": old, "new": ROOT}, spec, args.cores, args.runs)
        finally:
            git("worktree", "remove", "--force", str(old))
    load = os.getloadavg()[0]
    if args.json:
        print(json.dumps({"spec": str(spec), "old": args.old, "load_average": load, "rows": rows}, indent=2))
        return
    print(f"catanc explain --json {spec.name}: {args.old} against this tree (median of {args.runs}; load {load:.1f})")
    print(f"{'K':>3}{'old wall s':>12}{'new wall s':>12}{'old CPU s':>11}{'new CPU s':>11}{'CPU ratio':>11}  plan")
    for row in rows:
        plan = "same" if row["same_plan"] else ("better" if row["not_worse"] else "WORSE")
        print(
            f"{row['cores']:>3}{row['old_wall_s']:>12}{row['new_wall_s']:>12}{row['old_cpu_s']:>11}"
            f"{row['new_cpu_s']:>11}{row['cpu_ratio']:>11}x  {plan}"
        )
    print(f"target: at most {TARGET_S} s whole process at every K on a quiet 2-core machine")


if __name__ == "__main__":
    main()
