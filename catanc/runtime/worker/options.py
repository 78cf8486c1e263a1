"""The worker's command line: parsed and checked (argparse: a bad one exits 2 with a message)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from catanc.runtime.protocol.messages import ProtocolError, check_name
from catanc.runtime.worker.draws import Modes, check_profile, parse_modes

MODULE = "catanc.runtime.worker"


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


ROS_ARGS = "--ros-args"
ROS_ARGS_END = "--"


def without_ros_arguments(argv: Sequence[str]) -> list[str]:
    """``argv`` without its ROS sections (``--ros-args`` up to ``--`` or the end), as rcl reads a command line.

    A launcher appends one to the command of a process hosting a ROS node (its parameters file): a
    worker standing in for such a process takes it as a ROS program would, and ignores it.
    """
    kept: list[str] = []
    inside = False
    for word in argv:
        if word == ROS_ARGS:
            inside = True
        elif inside and word == ROS_ARGS_END:
            inside = False
        elif not inside:
            kept.append(word)
    return kept


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
    args = parser.parse_args(without_ros_arguments(sys.argv[1:] if argv is None else argv))
    names: list[str] = args.nodes
    profiles: list[Modes] = args.profiles or []
    for name in names:
        try:
            check_node_name(name)
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


def check_node_name(name: str) -> None:
    try:
        check_name(name)
    except ProtocolError as exc:
        raise ValueError(f"bad node name: {exc}") from None


def check_speedups(values: Sequence[float]) -> tuple[float, ...]:
    speedups = tuple(float(value) for value in values)
    if not speedups or speedups[0] != 1.0 or not all(math.isfinite(s) and s > 0 for s in speedups):
        raise ValueError(f"a speedup list starts with 1 and holds positive numbers, got {list(values)!r}")
    return speedups


def format_speedups(speedups: Sequence[float]) -> str:
    return ",".join(repr(s) for s in speedups)


def _speedup_arg(text: str) -> tuple[str, tuple[float, ...]]:
    name, _, values = text.partition("=")
    try:
        return name, check_speedups([float(v) for v in values.split(",")])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: expected NODE=S1,S2,... ({exc})") from None


def check_scale(after_s: float, factor: float) -> tuple[float, float]:
    after_s, factor = float(after_s), float(factor)
    if not (math.isfinite(after_s) and after_s >= 0):
        raise ValueError(f"--scale-after: the delay must be a number of seconds >= 0, got {after_s!r}")
    if not (math.isfinite(factor) and factor >= 0):
        raise ValueError(f"--scale-after: the factor must be a number >= 0, got {factor!r}")
    return after_s, factor


def check_clock(value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"--clock-start-ns: a CLOCK_MONOTONIC time in ns (an integer >= 0), got {value!r}")
    return value


def _clock_arg(text: str) -> int:
    try:
        return check_clock(int(text))
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
        return check_scale(*numbers)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
