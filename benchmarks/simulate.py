"""How much faster than real time the simulator runs (issue 7's aim: at least 1000x on nav2d).

    python -m benchmarks.simulate                  # nav2d, 1 and 2 cores, every policy, 60 simulated s
    python -m benchmarks.simulate --duration 60 --duration 250 --breakdown
    python -m benchmarks.simulate --duration 20 --spec specs/vr_illixr.yaml
    python -m benchmarks.simulate --cli --duration 3600  # whole `catanc simulate` processes, start-up included

Wall time of :func:`catanc.sim.simulate.simulate` per policy (planning
included: the static plans and ``catan``'s first plan and re-solves are part
of a run), and the speed-up ``simulated s / wall s``, for the compiled kernel
(the default) and, with ``--python``, for the Python engine it is checked
against.  Each policy runs once for a second first, so numba's compiling or
loading its cache is not timed; each row is the fastest of ``--repeat`` runs
(the machine may be shared: the load average is printed before and after).

``--breakdown`` splits each compiled run's wall time (of its fastest run) by
where it went: planning before the run (the static plans' profiling draws
included), re-solves (``catan``), the kernel, drawing compute times for it,
turning its records into the result, and the rest (arrays, feeding the
measurements to the re-optimiser).  The parts are timed by wrapping those
functions for the run (a few calls each), not by a profiler.

``--cli`` instead times what a user waits for: one ``catanc simulate``
process per row (imports, loading numba's cache, planning, the run and the
report), with its peak memory (``ru_maxrss`` of that child alone).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

from catanc.model.load import load_spec
from catanc.sim import fast, kernel, policies
from catanc.sim import simulate as simulate_run
from catanc.sim.simulate import POLICIES, EngineChoice, Setup, simulate

AIM = 1000.0

PARTS = ("planning", "re-solves", "kernel", "draws", "results")
"""What --breakdown times (wall s per part), beside the rest."""


class Stopwatch:
    """Seconds spent in each wrapped function, by part."""

    def __init__(self) -> None:
        self.spent = dict.fromkeys(PARTS, 0.0)

    def wrap(self, part: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            began = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.spent[part] += time.perf_counter() - began

        return timed


@contextlib.contextmanager
def timing(watch: Stopwatch) -> Iterator[None]:
    """Wrap the parts' functions (where their callers look them up) for the duration of the block."""
    targets: list[tuple[Any, str, str]] = [
        (simulate_run, "prepare", "planning"),
        (policies.Reoptimiser, "step", "re-solves"),
        (kernel, "run", "kernel"),
        (fast.DrawTable, "grow", "draws"),
        (fast, "records_of", "results"),
        (simulate_run, "policy_result", "results"),
    ]
    originals = [(owner, name, getattr(owner, name)) for owner, name, _ in targets]
    try:
        for (owner, name, part), (_, _, function) in zip(targets, originals, strict=True):
            setattr(owner, name, watch.wrap(part, function))
        yield
    finally:
        for owner, name, function in originals:
            setattr(owner, name, function)


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min)"


def time_cli(spec: str, cores: int, duration: float, policy: str) -> tuple[float, float]:
    """Wall seconds and peak resident MB of one ``catanc simulate`` process."""
    command = [sys.executable, "-m", "catanc", "simulate", spec, "--cores", str(cores), "--duration", f"{duration:g}"]
    began = time.perf_counter()
    child = subprocess.Popen([*command, "--policy", policy], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - began
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        raise SystemExit(f"{' '.join(command)} failed with exit code {child.returncode}")
    return wall, usage.ru_maxrss / 1024  # Linux reports KiB


def cli_rows(args: argparse.Namespace) -> None:
    chosen = args.policy or list(POLICIES)
    time_cli(args.spec, 1, 1.0, chosen[0])  # numba's cache filled, files in the page cache
    print(load())
    for duration, cores, policy in itertools.product(args.duration or [60.0], args.cores or [1, 2], chosen):
        wall, peak_mb = min(time_cli(args.spec, cores, duration, policy) for _ in range(args.repeat))
        speed = duration / wall
        print(
            f"catanc simulate {args.spec} {duration:5g} s {cores} core(s) {policy:15} {wall:7.3f} s wall: "
            f"{speed:6.0f}x real time ({speed / AIM:.2f}x the aim), peak {peak_mb:.0f} MB",
            flush=True,
        )
    print(load())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default="specs/nav2d.yaml")
    parser.add_argument("--duration", type=float, action="append", help="Simulated seconds (repeatable; 60).")
    parser.add_argument("--cores", type=int, action="append")
    parser.add_argument("--policy", action="append", choices=POLICIES)
    parser.add_argument("--repeat", type=int, default=3, help="Runs per row; the fastest is shown.")
    parser.add_argument("--python", action="store_true", help="Also time the Python engine.")
    parser.add_argument("--breakdown", action="store_true", help="Where a compiled run's wall time goes.")
    parser.add_argument("--cli", action="store_true", help="Time whole catanc simulate processes instead.")
    args = parser.parse_args()
    if args.cli:
        cli_rows(args)
        return
    spec = load_spec(args.spec)
    engines: list[EngineChoice] = ["compiled", "python"] if args.python else ["compiled"]
    chosen = args.policy or list(POLICIES)
    for policy in chosen:  # imports, compiling (or loading numba's cache) and first solver calls out of the way
        simulate(Setup(spec, 1, 1.0, 0), policy)
    print(load())
    rows = itertools.product(engines, args.duration or [60.0], args.cores or [1, 2], chosen)
    for engine, duration, cores, policy in rows:
        best, parts = float("inf"), Stopwatch()
        for _ in range(args.repeat):
            watch = Stopwatch()
            with timing(watch) if args.breakdown and engine == "compiled" else contextlib.nullcontext():
                began = time.perf_counter()
                result = simulate(Setup(spec, cores, duration, 0), policy, engine=engine)
                wall = time.perf_counter() - began
            if wall < best:
                best, parts = wall, watch
        speed = duration / best
        line = (
            f"{spec.app} {engine:8} {duration:5g} s {cores} core(s) {policy:15} {best:7.3f} s wall: "
            f"{speed:6.0f}x real time ({speed / AIM:.2f}x the aim), {result.replans} re-plans"
        )
        if args.breakdown and engine == "compiled":
            spent = parts.spent
            shown = ", ".join(f"{part} {1000 * spent[part]:.0f}" for part in PARTS)
            line += f"; ms: {shown}, rest {1000 * (best - sum(spent.values())):.0f}"
        print(line, flush=True)
    print(load())


if __name__ == "__main__":
    main()
