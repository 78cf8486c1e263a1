"""A synthetic worker: app nodes that burn CPU when ``catanc run`` triggers them.

::

    python -m catanc.runtime.worker --node NAME [--node NAME2 ...]
        (--compute-ms MS | --modes W:MS,... | --workload SPEC [--clock-start-ns NS])
        [--seed N] [--scale-after S:FACTOR] [--record FILE] [--socket PATH] [--executor NAME,NAME ...]

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

``--workload SPEC`` draws every run's compute time from the spec's workload
model instead (:class:`catanc.core.workload.ComputeSampler`, seeded with
``--seed``: jitter, growth over time, spikes; each node must be a scheduled
node of SPEC), at ``at_s`` = seconds since ``--clock-start-ns``, an instant
on ``CLOCK_MONOTONIC`` (``time.monotonic_ns()``), which every process of a
run can share (default: when the worker started).  ``--record FILE`` writes
every run, as :class:`RunRecord` JSON lines, to FILE when the worker exits
(:func:`read_records` reads them back): ``catanc bench`` measures chains from
these timestamps.

``--executor A,B`` says that nodes A and B of this worker share one
single-threaded executor (the spec's ``executors``, catan-model.md section
6): their runs take turns, one at a time in the order their triggers
arrived, as a ROS executor's callbacks do; a run waiting for its turn has
not started (its record starts when its turn comes).  Each node keeps its
own thread, the one the enforcer pins and measures.

The worker exits 0 when the enforcer says stop and on SIGINT or SIGTERM
(each node says bye), 1 if a node cannot register or loses the enforcer.

Python threads share one interpreter lock, so nodes of one worker never
compute at the same time: give nodes that should run in parallel a worker
each.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import json
import math
import os
import queue
import random
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import NamedTuple

from catanc.client import ClientError, Node, Trigger
from catanc.errors import CatancError, ExitCode
from catanc.runtime.protocol import ProtocolError, check_name
from catanc.spec.speedup import threads_and_speedup

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
    executors: Sequence[Sequence[str]] = (),
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
    return (
        argv
        + _common_options(
            nodes, seed=seed, scale_after=scale_after, socket_path=socket_path, speedups=speedups, record=None
        )
        + _executor_options(nodes, executors)
    )


def workload_worker_command(
    nodes: Sequence[str],
    spec_path: str | os.PathLike[str],
    *,
    seed: int | None = None,
    clock_start_ns: int | None = None,
    record: str | os.PathLike[str] | None = None,
    socket_path: str | os.PathLike[str] | None = None,
    python: str | None = None,
    speedups: Mapping[str, Sequence[float]] | None = None,
    executors: Sequence[Sequence[str]] = (),
) -> list[str]:
    """The argv of a worker serving ``nodes`` whose compute times follow the workload model of ``spec_path``.

    ``clock_start_ns`` is the ``time.monotonic_ns()`` instant the model's time counts from;
    ``record`` the file every run is written to when the worker exits.
    """
    if not nodes:
        raise ValueError("a worker serves at least one node")
    argv = [python or sys.executable, "-m", MODULE]
    for name in nodes:
        _check_name(name)
        argv += ["--node", name]
    argv += ["--workload", os.fspath(spec_path)]
    if clock_start_ns is not None:
        argv += ["--clock-start-ns", str(_check_clock(clock_start_ns))]
    return (
        argv
        + _common_options(nodes, seed=seed, scale_after=None, socket_path=socket_path, speedups=speedups, record=record)
        + _executor_options(nodes, executors)
    )


def worker_groups(nodes: Sequence[str], executors: Mapping[str, Sequence[str]]) -> list[tuple[str, ...]]:
    """The nodes as workers serve them: an executor's nodes together in one worker, every other node alone.

    Ordered by each group's first node in ``nodes``; an executor's nodes in ``nodes`` order.
    """
    order = {name: index for index, name in enumerate(nodes)}
    groups: list[tuple[str, ...]] = []
    grouped: set[str] = set()
    for members in executors.values():
        group = tuple(sorted((name for name in members if name in order), key=order.__getitem__))
        if group:
            groups.append(group)
            grouped.update(group)
    groups += [(name,) for name in nodes if name not in grouped]
    return sorted(groups, key=lambda group: order[group[0]])


def _executor_options(nodes: Iterable[str], executors: Sequence[Sequence[str]]) -> list[str]:
    """``--executor A,B`` per executor; ValueError for a node this worker does not serve."""
    served = set(nodes)
    argv: list[str] = []
    for members in executors:
        missing = [name for name in members if name not in served]
        if missing:
            raise ValueError(f"executor {list(members)}: this worker does not serve {', '.join(missing)}")
        argv += ["--executor", ",".join(members)]
    return argv


def _common_options(
    nodes: Iterable[str],
    *,
    seed: int | None,
    scale_after: tuple[float, float] | None,
    socket_path: str | os.PathLike[str] | None,
    speedups: Mapping[str, Sequence[float]] | None,
    record: str | os.PathLike[str] | None,
) -> list[str]:
    served = set(nodes)
    argv: list[str] = []
    for name, values in sorted((speedups or {}).items()):
        if name in served and tuple(values) != (1.0,):
            argv += ["--speedup", f"{name}={_format_speedups(_check_speedups(values))}"]
    if seed is not None:
        argv += ["--seed", str(seed)]
    if scale_after is not None:
        after_s, factor = _check_scale(*scale_after)
        argv += ["--scale-after", f"{after_s!r}:{factor!r}"]
    if record is not None:
        argv += ["--record", os.fspath(record)]
    if socket_path is not None:
        argv += ["--socket", os.fspath(socket_path)]
    return argv


@dataclass(frozen=True)
class WorkerOptions:
    """The parsed command line."""

    nodes: dict[str, Modes]  # with --workload, every node's modes are () (the spec's model draws)
    speedups: dict[str, tuple[float, ...]]  # node -> speedup with 1, 2, ... threads; absent: one thread
    seed: int
    scale_after: tuple[float, float] | None
    socket_path: Path | None
    workload: Path | None = None
    clock_start_ns: int | None = None
    record: Path | None = None
    executors: tuple[tuple[str, ...], ...] = ()  # nodes whose runs take turns (one executor thread each)


class RunRecord(NamedTuple):
    """One run of a node, as ``--record`` writes it: CLOCK_MONOTONIC times, shared by every process."""

    node: str
    start_ns: int  # the trigger arrived: the run reads its inputs
    end_ns: int  # the work is done (just before the node reports done)
    cpu_ns: int  # CPU time the run used, over all the threads it burned on


def write_records(path: str | os.PathLike[str], records: Iterable[RunRecord]) -> None:
    """Write ``records`` as JSON lines, atomically (a temporary file renamed over ``path``)."""
    target = Path(path)
    partial = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    with partial.open("w", encoding="utf-8") as out:
        for record in records:
            out.write(json.dumps(record._asdict(), separators=(",", ":")) + "\n")
    partial.replace(target)


def read_records(path: str | os.PathLike[str]) -> list[RunRecord]:
    """The runs :func:`write_records` wrote; ValueError naming the line if one is not a run."""
    records = []
    for number, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), start=1):
        try:
            data = json.loads(line)
            record = RunRecord(str(data["node"]), int(data["start_ns"]), int(data["end_ns"]), int(data["cpu_ns"]))
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}:{number}: not a run record ({exc})") from None
        records.append(record)
    return records


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
    parser.add_argument(
        "--workload", type=Path, metavar="SPEC", help="draw compute times from this spec's workload model"
    )
    parser.add_argument(
        "--clock-start-ns",
        type=_clock_arg,
        metavar="NS",
        help="the CLOCK_MONOTONIC instant (ns) the workload model's time counts from (default: the worker's start)",
    )
    parser.add_argument("--record", type=Path, metavar="FILE", help="write every run's timestamps to FILE on exit")
    parser.add_argument("--seed", type=int, default=0, help="seed of the mode or workload draws (default 0)")
    parser.add_argument(
        "--scale-after", type=_scale_arg, metavar="S:FACTOR", help="multiply compute by FACTOR S s after registering"
    )
    parser.add_argument("--socket", type=Path, metavar="PATH", help="the enforcer's socket (default $CATANC_SOCKET)")
    parser.add_argument(
        "--executor",
        action="append",
        dest="executors",
        default=[],
        metavar="NAME,NAME",
        help="nodes that share one single-threaded executor: their runs take turns",
    )
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
    if args.workload is not None:
        if profiles:
            parser.error("--workload draws every compute time: give no --compute-ms or --modes with it")
        profiles = [()]
    elif args.clock_start_ns is not None:
        parser.error("--clock-start-ns goes with --workload (the workload model's time)")
    if not profiles:
        parser.error("give each node a compute time: --compute-ms MS, --modes W:MS,... or --workload SPEC")
    if len(profiles) == 1:
        profiles = profiles * len(names)
    if len(profiles) != len(names):
        parser.error(f"{len(names)} nodes but {len(profiles)} compute profiles: give one, or one per --node")
    speedups = dict(args.speedups)
    unknown = sorted(set(speedups) - set(names))
    if unknown:
        parser.error(f"--speedup for node(s) this worker does not serve: {', '.join(unknown)}")
    executors: list[tuple[str, ...]] = []
    taken: set[str] = set()
    for text in args.executors:
        members = tuple(part.strip() for part in text.split(","))
        if len(members) < 2 or len(set(members)) != len(members):
            parser.error(f"--executor {text!r}: give two or more different nodes, NAME,NAME")
        strangers = [name for name in members if name not in names]
        if strangers:
            parser.error(f"--executor {text!r}: this worker does not serve {', '.join(strangers)}")
        twice = [name for name in members if name in taken]
        if twice:
            parser.error(f"--executor {text!r}: {', '.join(twice)} already in another executor")
        taken.update(members)
        executors.append(members)
    return WorkerOptions(
        nodes=dict(zip(names, profiles, strict=True)),
        speedups=speedups,
        seed=args.seed,
        scale_after=args.scale_after,
        socket_path=args.socket,
        workload=args.workload,
        clock_start_ns=args.clock_start_ns,
        record=args.record,
        executors=tuple(executors),
    )


class Turns:
    """One executor thread's callbacks: one at a time, in the order they arrived (a ticket queue)."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._issued = 0
        self._serving = 0

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        with self._changed:
            ticket = self._issued
            self._issued += 1
            while ticket != self._serving:
                self._changed.wait()
        try:
            yield
        finally:
            with self._changed:
                self._serving += 1
                self._changed.notify_all()


def burn(compute_ms: float, since_s: float | None = None) -> None:
    """Busy-loop until this thread has used ``compute_ms`` of CPU time (since ``since_s`` on its
    ``time.thread_time()`` clock, default now)."""
    end = (time.thread_time() if since_s is None else since_s) + compute_ms / 1000.0
    while time.thread_time() < end:
        pass


HASHED_BLOCK = bytes(16 * 1024)
"""What a parallel burn hashes at a time: hashlib lets go of the interpreter lock for blocks this big."""


def burn_released(compute_ms: float, since_s: float | None = None) -> None:
    """:func:`burn`, but in C code that releases the interpreter lock, so threads really burn in parallel."""
    end = (time.thread_time() if since_s is None else since_s) + compute_ms / 1000.0
    while time.thread_time() < end:
        hashlib.sha256(HASHED_BLOCK)


def burn_parallel(compute_ms: float, threads: int, speedups: Sequence[float], since_s: float | None = None) -> int:
    """One run of a node whose single-thread compute is ``compute_ms``, on ``threads`` threads; the threads used.

    As the planner models it (``c^q = c / speedup(q)``), each of the ``q`` threads the speedup
    table makes worth using burns ``c / speedup(q)`` of CPU time, so the run takes that long.
    The calling thread is one of them: it is the one the enforcer pins and measures, and it counts
    its CPU time from ``since_s`` (:func:`burn`).
    """
    q, speedup = threads_and_speedup(speedups, threads)
    each_ms = compute_ms / speedup
    if q == 1:
        burn(each_ms, since_s)
        return 1
    helpers = [threading.Thread(target=burn_released, args=(each_ms,), daemon=True) for _ in range(q - 1)]
    for helper in helpers:
        helper.start()
    burn_released(each_ms, since_s)
    for helper in helpers:
        helper.join()
    return q


Draw = Callable[[float], float]
"""One node's compute time (ms, on one thread) for a run starting ``at_s`` seconds into the run."""


def mode_draw(modes: Modes, rng: random.Random) -> Draw:
    """Draws from weighted modes, ignoring the time."""
    weights = [weight for weight, _ in modes]
    computes = [compute for _, compute in modes]
    if len(modes) == 1:
        return lambda _at_s: computes[0]
    return lambda _at_s: rng.choices(computes, weights)[0]


def workload_draws(spec_path: Path, nodes: Iterable[str], seed: int) -> dict[str, Draw]:
    """Each node's draws from the workload model of the spec at ``spec_path``.

    Raises :class:`~catanc.errors.CatancError` (a bad spec) or ValueError (a node the spec does
    not schedule).
    """
    from catanc.core.load import load_spec  # noqa: PLC0415 - only --workload needs the spec language
    from catanc.core.workload import ComputeSampler  # noqa: PLC0415

    spec = load_spec(spec_path)
    for name in nodes:
        node = spec.nodes.get(name)
        if node is None or not node.scheduled:
            what = "has no node" if node is None else "does not schedule node"
            raise ValueError(f"{spec_path} {what} {name!r}: a worker burns scheduled nodes only")
    sampler = ComputeSampler(spec, seed)  # one stream per node: threads never share one
    return {name: functools.partial(sampler.compute_ms, name) for name in nodes}


def main(argv: Sequence[str] | None = None) -> int:
    """Run the worker until the enforcer stops it or a signal arrives; return the exit code."""
    options = parse_args(argv)
    clock_start_ns = options.clock_start_ns if options.clock_start_ns is not None else time.monotonic_ns()
    if options.workload is not None:
        try:
            draws = workload_draws(options.workload, options.nodes, options.seed)
        except (CatancError, ValueError) as exc:
            print(f"catanc worker: --workload: {exc}", file=sys.stderr)
            return int(ExitCode.BAD_INPUT)
    else:
        draws = {
            name: mode_draw(modes, random.Random(f"{options.seed}/{name}")) for name, modes in options.nodes.items()
        }
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
    records: dict[str, list[RunRecord]] = {node.name: [] for node in nodes}
    turns = {name: shared for members in options.executors for shared in [Turns()] for name in members}
    try:
        for node in nodes:
            thread = threading.Thread(
                target=_serve,
                args=(node, finished),
                kwargs={
                    "draw": draws[node.name],
                    "speedups": options.speedups.get(node.name, (1.0,)),
                    "scale_after": options.scale_after,
                    "clock_start_ns": clock_start_ns,
                    "records": records[node.name] if options.record is not None else None,
                    "turns": turns.get(node.name),
                },
                name=f"catanc-{node.name}",
                daemon=True,
            )
            thread.start()
        status = 0
        for _ in nodes:
            node, error = finished.get()
            if error is None:
                if node.lost is not None:  # the enforcer went away: the client said so
                    status = max(status, 1)
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
        if options.record is not None:  # every node thread has finished (or this is an interrupt: keep what ran)
            write_records(options.record, sorted(r for runs in records.values() for r in list(runs)))


def _serve(
    node: Node,
    finished: queue.Queue[tuple[Node, Exception | None]],
    *,
    draw: Draw,
    speedups: tuple[float, ...],
    scale_after: tuple[float, float] | None,
    clock_start_ns: int,
    records: list[RunRecord] | None,
    turns: Turns | None = None,
) -> None:
    error: Exception | None = None
    try:
        with node:
            registered_at = time.monotonic()
            for trigger in node:
                with turns.turn() if turns is not None else contextlib.nullcontext():
                    _run(
                        node,
                        trigger,
                        draw=draw,
                        speedups=speedups,
                        scale_after=scale_after,
                        clock_start_ns=clock_start_ns,
                        registered_at=registered_at,
                        records=records,
                    )
    except Exception as exc:
        error = exc
    finally:
        finished.put((node, error))


def _run(
    node: Node,
    trigger: Trigger,
    *,
    draw: Draw,
    speedups: tuple[float, ...],
    scale_after: tuple[float, float] | None,
    clock_start_ns: int,
    registered_at: float,
    records: list[RunRecord] | None,
) -> None:
    """One run: burn the drawn compute time on the threads the trigger gives, record it, report done.

    The run's own bookkeeping (the draw, the thread count) comes out of its compute time: the
    node's thread uses what the profile says from here to ``done``, as a real node would.
    """
    started_ns = time.monotonic_ns()
    cpu_before = time.thread_time_ns()
    compute_ms = draw((started_ns - clock_start_ns) / 1e9)
    if scale_after is not None and time.monotonic() - registered_at >= scale_after[0]:
        compute_ms *= scale_after[1]
    threads = burn_parallel(compute_ms, trigger.threads, speedups, since_s=cpu_before / 1e9)
    ended_ns = time.monotonic_ns()
    if records is not None:  # each helper thread burned as long as this one
        cpu_ns = (time.thread_time_ns() - cpu_before) * threads
        records.append(RunRecord(node.name, started_ns, ended_ns, cpu_ns))
    # On one thread, its CPU time (the client's default); on more, the run's wall time.
    node.done(None if trigger.threads == 1 else (ended_ns - started_ns) / 1e6)


def _check_name(name: str) -> None:
    try:
        check_name(name)
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


def _check_clock(value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"--clock-start-ns: a CLOCK_MONOTONIC time in ns (an integer >= 0), got {value!r}")
    return value


def _clock_arg(text: str) -> int:
    try:
        return _check_clock(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a CLOCK_MONOTONIC time in ns (an integer >= 0)") from None


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
