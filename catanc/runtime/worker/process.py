"""The worker process: a :class:`catanc.client.Node` loop per node thread, until the enforcer says stop."""

from __future__ import annotations

import contextlib
import queue
import random
import signal
import sys
import threading
import time
import traceback
from collections.abc import Iterator, Sequence
from types import FrameType

from catanc.client import ClientError, Node, Trigger
from catanc.errors import CatancError, ExitCode
from catanc.runtime.worker.burn import burn_parallel
from catanc.runtime.worker.draws import Draw, mode_draw, workload_draws
from catanc.runtime.worker.options import parse_args
from catanc.runtime.worker.records import RunRecord, write_records


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
    cpu_ns = (time.thread_time_ns() - cpu_before) * threads  # each helper thread burned as long as this one
    # On one thread, its CPU time (the client's default); on more, the run's wall time.
    node.done(None if trigger.threads == 1 else (ended_ns - started_ns) / 1e6)
    if records is not None:
        records.append(RunRecord(node.name, started_ns, ended_ns, cpu_ns, cpu_before, time.thread_time_ns()))
