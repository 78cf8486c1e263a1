"""The compiled simulator's cost in instructions: a measure that does not move with the machine's load.

    python -m benchmarks.instructions                     # nav2d, 1 and 2 cores, catan and static-fullrun, 50 s
    python -m benchmarks.instructions --policy baseline --cores 2 --duration 20

On a shared VM the same run's wall time differs by 20% from one process to
the next (benchmarks/RESULTS.md, fifth pass), so a change to the kernel smaller
than that cannot be timed.  Instructions can be counted exactly: each row
runs one simulation under valgrind's callgrind and counts the instructions
executed inside calls to numba's compiled functions (``--toggle-collect``
on the dispatcher's C entry point), i.e. the kernel and the small compiled
helpers around it, not the Python planner.  The same code and input give
the same count to the instruction, on any machine with the same numba and
LLVM.

Each child first simulates ``--warmup`` seconds uninstrumented (numba loads
its cache, every code path compiles or loads, re-solves and a Stage I
re-allocation happen), then switches instrumentation on and simulates
``--duration`` seconds afresh.  A row takes about a minute (valgrind runs
the warm-up too, ~5x slower than native).  Needs valgrind (Debian:
``apt install valgrind``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import numba

from catanc.model.load import load_spec
from catanc.sim import kernel
from catanc.sim.simulate import POLICIES, Setup, simulate

CHILD_FLAG = "--child"


class Case(NamedTuple):
    spec: str
    cores: int
    policy: str
    duration_s: float
    warmup_s: float


@numba.njit  # type: ignore[untyped-decorator]
def kernel_counts(sim: kernel.Sim) -> tuple[int, int]:
    """Events scheduled and completions recorded so far."""
    return int(sim.order), int(sim.done_n)


def child(case: Case, out: Path) -> None:
    """Inside valgrind: warm up, switch instrumentation on, simulate, write the run's counts."""
    seen = {"events": 0, "completions": 0}
    compiled_run = kernel.run

    def counting_run(sim: kernel.Sim, end_ms: float) -> int:
        status = int(compiled_run(sim, end_ms))
        seen["events"], seen["completions"] = kernel_counts(sim)
        return status

    kernel.run = counting_run  # kernel_counts compiles during the warm-up, like every other function
    spec = load_spec(case.spec)
    simulate(Setup(spec, case.cores, case.warmup_s, 0), case.policy)
    subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], check=True, capture_output=True)
    simulate(Setup(spec, case.cores, case.duration_s, 0), case.policy)
    out.write_text(json.dumps(seen))


def count(case: Case) -> dict[str, float]:
    """Instructions inside numba's compiled functions for one simulation, with its kernel's event counts."""
    with tempfile.TemporaryDirectory() as scratch:
        profile = Path(scratch) / "callgrind.out"
        seen = Path(scratch) / "counts.json"
        command = [
            "valgrind", "--tool=callgrind", "--instr-atstart=no", "--collect-atstart=no",
            "--toggle-collect=*Dispatcher_call*", f"--callgrind-out-file={profile}",
            sys.executable, "-m", "benchmarks.instructions", CHILD_FLAG,
            *map(str, case), str(seen),
        ]  # fmt: skip
        done = subprocess.run(command, check=False, capture_output=True, text=True)
        if done.returncode != 0 or not seen.exists():
            raise SystemExit(f"valgrind run failed ({done.returncode}):\n{done.stderr[-2000:]}")
        totals = re.search(r"^(?:summary|totals): (\d+)", profile.read_text(), re.MULTILINE)
        if totals is None:
            raise SystemExit(f"no instruction total in {profile}")
        counts = json.loads(seen.read_text())
    return {"instructions": float(totals.group(1)), **counts}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == CHILD_FLAG:
        spec, cores, policy, duration, warmup, out = sys.argv[2:8]
        child(Case(spec, int(cores), policy, float(duration), float(warmup)), Path(out))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default="specs/nav2d.yaml")
    parser.add_argument("--cores", type=int, action="append", help="Cores (repeatable; 1 and 2).")
    parser.add_argument("--policy", action="append", choices=POLICIES, help="(repeatable; catan, static-fullrun)")
    parser.add_argument("--duration", type=float, default=50.0, help="Simulated seconds counted (50).")
    parser.add_argument("--warmup", type=float, default=25.0, help="Simulated seconds run first, not counted (25).")
    args = parser.parse_args()
    for tool in ("valgrind", "callgrind_control"):
        if shutil.which(tool) is None:
            raise SystemExit(f"benchmarks.instructions needs {tool} (Debian: apt install valgrind)")
    print(f"{args.spec}: instructions in compiled code over {args.duration:g} simulated s (callgrind)")
    print(f"{'cores':>5} {'policy':<15} {'instructions':>14} {'per sim s':>12} {'events':>8} {'completions':>11}")
    for cores in args.cores or [1, 2]:
        for policy in args.policy or ["catan", "static-fullrun"]:
            row = count(Case(args.spec, cores, policy, args.duration, args.warmup))
            print(
                f"{cores:>5} {policy:<15} {row['instructions']:>14,.0f} {row['instructions'] / args.duration:>12,.0f} "
                f"{row['events']:>8,.0f} {row['completions']:>11,.0f}"
            )


if __name__ == "__main__":
    main()
