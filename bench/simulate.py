"""How much faster than real time the simulator runs (issue 7's aim: at least 1000x on nav2d).

    python -m bench.simulate                  # nav2d, 1 and 2 cores, every policy, 60 simulated s
    python -m bench.simulate --duration 20 --spec specs/vr_illixr.yaml

Wall time of :func:`catanc.simulate.run.simulate` per policy (planning
included: the static plans and ``catan``'s first plan and re-solves are part
of a run), and the speed-up ``simulated s / wall s``, for the compiled kernel
(the default) and, with ``--python``, for the Python engine it is checked
against.  Each policy runs once for a second first, so numba's compiling or
loading its cache is not timed.
"""

from __future__ import annotations

import argparse
import itertools
import time

from catanc.load import load_spec
from catanc.simulate.run import POLICIES, EngineChoice, Setup, simulate

AIM = 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default="specs/nav2d.yaml")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--cores", type=int, action="append")
    parser.add_argument("--python", action="store_true", help="Also time the Python engine.")
    args = parser.parse_args()
    spec = load_spec(args.spec)
    engines: list[EngineChoice] = ["compiled", "python"] if args.python else ["compiled"]
    for policy in POLICIES:  # imports, compiling (or loading numba's cache) and first solver calls out of the way
        simulate(Setup(spec, 1, 1.0, 0), policy)
    for engine, cores, policy in itertools.product(engines, args.cores or [1, 2], POLICIES):
        began = time.perf_counter()
        result = simulate(Setup(spec, cores, args.duration, 0), policy, engine=engine)
        wall = time.perf_counter() - began
        speed = args.duration / wall
        print(
            f"{spec.app} {engine:8} {cores} core(s) {policy:15} {wall:7.3f} s wall for {args.duration:g} s: "
            f"{speed:7.0f}x real time ({speed / AIM:.2f}x the aim), {result.replans} re-plans"
        )


if __name__ == "__main__":
    main()
