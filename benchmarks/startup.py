"""Start-up: whole ``catanc validate`` and ``compile --check`` processes beside ``python -c pass`` and ``import cvxpy``.

    python -m benchmarks.startup [--runs 10] [--spec specs/nav2d.yaml] [--cores 2]

Issue 33's targets: ``catanc validate SPEC`` at most 0.5 s, and ``catanc
compile SPEC -k 2 --check``, the whole process, at most 1.5x the time of
``python -c "import cvxpy"`` (the model of record needs cvxpy; everything
else should cost little).  The four commands run in turn, ``--runs`` rounds,
so that a busy minute slows all of them alike; medians and ranges are
reported with the load average, and each median as a ratio to ``python -c
pass`` (the interpreter's own start) and to ``import cvxpy``.

The processes may write bytecode (``PYTHONDONTWRITEBYTECODE`` is dropped
from their environment), so the untimed first round caches catanc's as
``pip install`` or a user's first run does; the libraries' is cached at
install.  ``python -X importtime`` shows what a command loads.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMPILE_TARGET = 1.5  # compile --check / import cvxpy
VALIDATE_TARGET_S = 0.5


def catanc() -> list[str]:
    """The console script beside this Python (as a user runs it), else ``python -m catanc``."""
    script = Path(sys.executable).with_name("catanc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "catanc"]


ENVIRONMENT = {name: value for name, value in os.environ.items() if name != "PYTHONDONTWRITEBYTECODE"}


def run(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one whole process; CPU time is what a busy machine inflates least."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(argv, cwd=ROOT, env=ENVIRONMENT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--spec", default="specs/nav2d.yaml")
    parser.add_argument("--cores", type=int, default=2)
    args = parser.parse_args()
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "import cvxpy": [sys.executable, "-c", "import cvxpy"],
        "compile --check": [*catanc(), "compile", args.spec, "-k", str(args.cores), "--check"],
        "validate": [*catanc(), "validate", args.spec],
    }
    for argv in commands.values():  # warm the file cache once, untimed
        run(argv)
    load_before = os.getloadavg()[0]
    walls: dict[str, list[float]] = {name: [] for name in commands}
    cpus: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(args.runs):
        for name, argv in commands.items():
            wall_s, cpu_s = run(argv)
            walls[name].append(wall_s)
            cpus[name].append(cpu_s)
    load_after = os.getloadavg()[0]
    wall = {name: statistics.median(values) for name, values in walls.items()}
    cpu = {name: statistics.median(values) for name, values in cpus.items()}
    print(f"{args.runs} rounds, load average {load_before:.2f} before, {load_after:.2f} after")
    print(f"  {'':16} {'wall median (range)':>25} {'cpu median':>11} {'/ pass':>7} {'/ cvxpy':>8}")
    for name in commands:
        low, high = min(walls[name]), max(walls[name])
        print(
            f"  {name:16} {wall[name]:9.3f} s ({low:.3f}-{high:.3f}) {cpu[name]:9.3f} s "
            f"{wall[name] / wall['python -c pass']:6.1f}x {wall[name] / wall['import cvxpy']:7.2f}x"
        )
    print(
        f"compile --check / import cvxpy: {wall['compile --check'] / wall['import cvxpy']:.2f}x wall, "
        f"{cpu['compile --check'] / cpu['import cvxpy']:.2f}x cpu (target at most {COMPILE_TARGET}x)"
    )
    print(f"validate: {wall['validate']:.3f} s wall, {cpu['validate']:.3f} s cpu (target {VALIDATE_TARGET_S} s)")


if __name__ == "__main__":
    main()
