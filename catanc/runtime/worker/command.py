"""The argv that starts a worker process (what :func:`catanc.runtime.worker.options.parse_args` reads)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Mapping, Sequence

from catanc.runtime.worker.draws import Profile, check_profile, format_modes
from catanc.runtime.worker.options import (
    MODULE,
    check_clock,
    check_node_name,
    check_scale,
    check_speedups,
    format_speedups,
)


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
        check_node_name(name)
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
        check_node_name(name)
        argv += ["--node", name]
    argv += ["--workload", os.fspath(spec_path)]
    if clock_start_ns is not None:
        argv += ["--clock-start-ns", str(check_clock(clock_start_ns))]
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
            argv += ["--speedup", f"{name}={format_speedups(check_speedups(values))}"]
    if seed is not None:
        argv += ["--seed", str(seed)]
    if scale_after is not None:
        after_s, factor = check_scale(*scale_after)
        argv += ["--scale-after", f"{after_s!r}:{factor!r}"]
    if record is not None:
        argv += ["--record", os.fspath(record)]
    if socket_path is not None:
        argv += ["--socket", os.fspath(socket_path)]
    return argv
