"""A synthetic worker: app nodes that burn CPU when ``catanc run`` triggers them.

::

    python -m catanc.runtime.worker --node NAME [--node NAME2 ...] (--compute-ms MS | --modes W:MS,...)
        [--seed N] [--scale-after S:FACTOR] [--socket PATH]

One thread per node, each a :class:`catanc.client.Node` loop.  On each
trigger a node burns its compute time, measured in thread CPU time (so being
preempted does not shorten the work), then reports done.  ``--modes
"0.8:1,0.2:12"`` makes a multimodal node: 1 ms with weight 0.8, 12 ms with
weight 0.2, drawn with a generator seeded from ``--seed`` and the node name.
``--compute-ms`` or ``--modes`` given once applies to every node; given once
per ``--node``, the i-th applies to the i-th node (:func:`worker_command`
writes them next to their node).  ``--scale-after 5:3`` multiplies the
compute time by 3 for every run that starts 5 s (wall time) or more after
its node registered.  The socket defaults to ``$CATANC_SOCKET``.

The worker exits 0 when the enforcer says stop and on SIGINT or SIGTERM
(each node says bye), 1 if a node cannot register or loses the enforcer.

Python threads share one interpreter lock, so nodes of one worker never
compute at the same time: give nodes that should run in parallel a worker
each.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import queue
import random
import signal
import sys
import threading
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from catanc.client import ClientError, Node
from catanc.errors import ExitCode
from catanc.runtime.protocol import ProtocolError, Welcome
from catanc.speedup import threads_and_speedup

MODULE = "catanc.runtime.worker"

Modes = tuple[tuple[float, float], ...]
"""A node's compute profile: (weight, compute_ms) pairs."""

Profile = float | Sequence[tuple[float, float]]
"""What :func:`worker_command` takes per node: a compute time in ms, or (weight, compute_ms) modes."""


def check_profile(profile: Profile) -> Modes:
    """A profile as modes; ValueError if a compute time is negative or a weight not positive."""
    if isinstance(profile, int | float):
        modes: Modes = ((1.0, float(profile)),)
    else:
        modes = tuple((float(weight), float(compute)) for weight, compute in profile)
    if not modes:
        raise ValueError("a node needs at least one mode")
    for weight, compute in modes:
        if not (math.isfinite(weight) and weight > 0):
            raise ValueError(f"a mode's weight must be a positive number, got {weight!r}")
        if not (math.isfinite(compute) and compute >= 0):
            raise ValueError(f"a compute time must be a number of ms >= 0, got {compute!r}")
    return modes


def format_modes(modes: Sequence[tuple[float, float]]) -> str:
    """``[(0.8, 1.0), (0.2, 12.0)]`` -> ``"0.8:1.0,0.2:12.0"`` (what ``--modes`` reads)."""
    return ",".join(f"{float(weight)!r}:{float(compute)!r}" for weight, compute in modes)


def parse_modes(text: str) -> Modes:
    """``"0.8:1,0.2:12"`` -> ``((0.8, 1.0), (0.2, 12.0))``; ValueError with the reason if malformed."""
    modes = []
    for part in text.split(","):
        weight, sep, compute = part.partition(":")
        if not sep:
            raise ValueError(f"{part.strip()!r} is not WEIGHT:MS")
        try:
            modes.append((float(weight), float(compute)))
        except ValueError:
            raise ValueError(f"{part.strip()!r} is not WEIGHT:MS (two numbers)") from None
    return check_profile(modes)


def worker_command(
    nodes: Mapping[str, Profile],
    *,
    seed: int | None = None,
    scale_after: tuple[float, float] | None = None,
    socket_path: str | os.PathLike[str] | None = None,
    python: str | None = None,
    speedups: Mapping[str, Sequence[float]] | None = None,
) -> list[str]:
    """The argv that starts one worker process serving ``nodes`` (name -> compute ms, or (weight, ms) modes).

    ``speedups`` gives multi-threaded nodes their speedup with 1, 2, ... threads (the spec's
    ``threads.speedups``).  Without ``socket_path`` the worker reads ``$CATANC_SOCKET``.
    """
    if not nodes:
        raise ValueError("a worker serves at least one node")
    argv = [python or sys.executable, "-m", MODULE]
    for name, profile in nodes.items():
        _check_name(name)
        modes = check_profile(profile)
        argv += ["--node", name]
        if isinstance(profile, int | float):
            argv += ["--compute-ms", repr(modes[0][1])]
        else:
            argv += ["--modes", format_modes(modes)]
    for name, values in sorted((speedups or {}).items()):
        if name in nodes and tuple(values) != (1.0,):
            argv += ["--speedup", f"{name}={_format_speedups(_check_speedups(values))}"]
    if seed is not None:
        argv += ["--seed", str(seed)]
    if scale_after is not None:
        after_s, factor = _check_scale(*scale_after)
        argv += ["--scale-after", f"{after_s!r}:{factor!r}"]
    if socket_path is not None:
        argv += ["--socket", os.fspath(socket_path)]
    return argv


@dataclass(frozen=True)
class WorkerOptions:
    """The parsed command line."""

    nodes: dict[str, Modes]
    speedups: dict[str, tuple[float, ...]]  # node -> speedup with 1, 2, ... threads; absent: one thread
    seed: int
    scale_after: tuple[float, float] | None
    socket_path: Path | None


def parse_args(argv: Sequence[str] | None = None) -> WorkerOptions:
    """Parse the worker's command line (argparse: exits 2 with a message on bad usage)."""
    parser = argparse.ArgumentParser(
        prog=f"python -m {MODULE}", description="Synthetic app nodes that burn CPU when catanc run triggers them."
    )
    parser.add_argument("--node", action="append", dest="nodes", required=True, metavar="NAME", help="a DAG node")
    parser.add_argument(
        "--compute-ms", action="append", dest="profiles", type=_compute_arg, metavar="MS", help="compute per run"
    )
    parser.add_argument(
        "--modes", action="append", dest="profiles", type=_modes_arg, metavar="W:MS,...", help="weighted modes"
    )
    parser.add_argument(
        "--speedup",
        action="append",
        dest="speedups",
        type=_speedup_arg,
        default=[],
        metavar="NODE=S1,S2,...",
        help="a multi-threaded node's speedup with 1, 2, ... threads (it burns on the threads a trigger gives it)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the mode draws (default 0)")
    parser.add_argument(
        "--scale-after", type=_scale_arg, metavar="S:FACTOR", help="multiply compute by FACTOR S s after registering"
    )
    parser.add_argument("--socket", type=Path, metavar="PATH", help="the enforcer's socket (default $CATANC_SOCKET)")
    args = parser.parse_args(argv)
    names: list[str] = args.nodes
    profiles: list[Modes] = args.profiles or []
    for name in names:
        try:
            _check_name(name)
        except ValueError as exc:
            parser.error(str(exc))
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        parser.error(f"node(s) given twice: {', '.join(duplicates)}")
    if not profiles:
        parser.error("give each node a compute time: --compute-ms MS or --modes W:MS,...")
    if len(profiles) == 1:
        profiles = profiles * len(names)
    if len(profiles) != len(names):
        parser.error(f"{len(names)} nodes but {len(profiles)} compute profiles: give one, or one per --node")
    speedups = dict(args.speedups)
    unknown = sorted(set(speedups) - set(names))
    if unknown:
        parser.error(f"--speedup for node(s) this worker does not serve: {', '.join(unknown)}")
    return WorkerOptions(
        nodes=dict(zip(names, profiles, strict=True)),
        speedups=speedups,
        seed=args.seed,
        scale_after=args.scale_after,
        socket_path=args.socket,
    )


def burn(compute_ms: float) -> None:
    """Busy-loop until this thread has used ``compute_ms`` of CPU time."""
    end = time.thread_time() + compute_ms / 1000.0
    while time.thread_time() < end:
        pass


HASHED_BLOCK = bytes(16 * 1024)
"""What a parallel burn hashes at a time: hashlib lets go of the interpreter lock for blocks this big."""


def burn_released(compute_ms: float) -> None:
    """:func:`burn`, but in C code that releases the interpreter lock, so threads really burn in parallel."""
    end = time.thread_time() + compute_ms / 1000.0
    while time.thread_time() < end:
        hashlib.sha256(HASHED_BLOCK)


def burn_parallel(compute_ms: float, threads: int, speedups: Sequence[float]) -> None:
    """One run of a node whose single-thread compute is ``compute_ms``, on ``threads`` threads.

    As the planner models it (``c^q = c / speedup(q)``), each of the ``q`` threads the speedup
    table makes worth using burns ``c / speedup(q)`` of CPU time, so the run takes that long.
    The calling thread is one of them: it is the one the enforcer pins and measures.
    """
    q, speedup = threads_and_speedup(speedups, threads)
    each_ms = compute_ms / speedup
    if q == 1:
        burn(each_ms)
        return
    helpers = [threading.Thread(target=burn_released, args=(each_ms,), daemon=True) for _ in range(q - 1)]
    for helper in helpers:
        helper.start()
    burn_released(each_ms)
    for helper in helpers:
        helper.join()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the worker until the enforcer stops it or a signal arrives; return the exit code."""
    options = parse_args(argv)
    try:
        nodes = [Node(name, socket_path=options.socket_path) for name in options.nodes]
    except ClientError as exc:
        print(f"catanc worker: {exc}", file=sys.stderr)
        return 1
    if len(nodes) > 1:
        sys.setswitchinterval(0.0005)  # hand the interpreter lock over promptly when a trigger arrives

    def stop() -> None:
        for node in nodes:
            node.interrupt()

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop()

    handled = (signal.SIGINT, signal.SIGTERM)
    in_main = threading.current_thread() is threading.main_thread()
    previous = {signum: signal.signal(signum, on_signal) for signum in handled} if in_main else {}
    finished: queue.Queue[tuple[Node, Exception | None]] = queue.Queue()
    try:
        for node in nodes:
            rng = random.Random(f"{options.seed}/{node.name}")
            thread = threading.Thread(
                target=_serve,
                args=(node, finished),
                kwargs={
                    "modes": options.nodes[node.name],
                    "speedups": options.speedups.get(node.name, (1.0,)),
                    "rng": rng,
                    "scale_after": options.scale_after,
                },
                name=f"catanc-{node.name}",
                daemon=True,
            )
            thread.start()
        status = 0
        for _ in nodes:
            node, error = finished.get()
            if error is None:
                continue
            if isinstance(error, ClientError):
                print(f"catanc worker: {error}", file=sys.stderr)
                status = max(status, 1)  # the enforcer is missing or went away
            else:
                print(f"catanc worker: node {node.name!r} crashed (a bug):", file=sys.stderr)
                traceback.print_exception(error, file=sys.stderr)
                status = int(ExitCode.INTERNAL)
            stop()
        return status
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _serve(
    node: Node,
    finished: queue.Queue[tuple[Node, Exception | None]],
    *,
    modes: Modes,
    speedups: tuple[float, ...],
    rng: random.Random,
    scale_after: tuple[float, float] | None,
) -> None:
    error: Exception | None = None
    try:
        with node:
            registered_at = time.monotonic()
            weights = [weight for weight, _ in modes]
            computes = [compute for _, compute in modes]
            for trigger in node:
                compute_ms = computes[0] if len(modes) == 1 else rng.choices(computes, weights)[0]
                if scale_after is not None and time.monotonic() - registered_at >= scale_after[0]:
                    compute_ms *= scale_after[1]
                started = time.monotonic()
                burn_parallel(compute_ms, trigger.threads, speedups)
                # On one thread, its CPU time (the client's default); on more, the run's wall time.
                node.done(None if trigger.threads == 1 else (time.monotonic() - started) * 1000.0)
    except Exception as exc:
        error = exc
    finally:
        finished.put((node, error))


def _check_name(name: str) -> None:
    try:
        Welcome(name)
    except ProtocolError as exc:
        raise ValueError(f"bad node name: {exc}") from None


def _check_speedups(values: Sequence[float]) -> tuple[float, ...]:
    speedups = tuple(float(value) for value in values)
    if not speedups or speedups[0] != 1.0 or not all(math.isfinite(s) and s > 0 for s in speedups):
        raise ValueError(f"a speedup list starts with 1 and holds positive numbers, got {list(values)!r}")
    return speedups


def _format_speedups(speedups: Sequence[float]) -> str:
    return ",".join(repr(s) for s in speedups)


def _speedup_arg(text: str) -> tuple[str, tuple[float, ...]]:
    name, _, values = text.partition("=")
    try:
        return name, _check_speedups([float(v) for v in values.split(",")])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: expected NODE=S1,S2,... ({exc})") from None


def _check_scale(after_s: float, factor: float) -> tuple[float, float]:
    after_s, factor = float(after_s), float(factor)
    if not (math.isfinite(after_s) and after_s >= 0):
        raise ValueError(f"--scale-after: the delay must be a number of seconds >= 0, got {after_s!r}")
    if not (math.isfinite(factor) and factor >= 0):
        raise ValueError(f"--scale-after: the factor must be a number >= 0, got {factor!r}")
    return after_s, factor


def _compute_arg(text: str) -> Modes:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of ms") from None
    try:
        return check_profile(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _modes_arg(text: str) -> Modes:
    try:
        return parse_modes(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _scale_arg(text: str) -> tuple[float, float]:
    after, _, factor = text.partition(":")
    try:
        numbers = float(after), float(factor)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not S:FACTOR (two numbers)") from None
    try:
        return _check_scale(*numbers)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


if __name__ == "__main__":
    sys.exit(main())
