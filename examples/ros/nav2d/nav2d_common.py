"""What the nav2d example's processes share: the spec's compute draws, run records, stamps and spinning.

Every node burns, per run, the CPU time its compute profile in ``nav2d.yaml`` draws (catanc's own
workload model: modes, jitter, growth, spikes), so the app loads the CPU as the paper's nav2d does
without a robot.  With ``$NAV2D_RECORD_DIR`` set, each process appends one JSON line per run to
``<dir>/<process>.jsonl`` (the benchmark and the tests read them), and ``<dir>/<process>.exit`` when it shuts
down cleanly; without it nothing is written.
"""

from __future__ import annotations

import gc
import json
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from catanc.runtime.worker.burn import burn
from catanc.runtime.worker.draws import workload_draws

SPEC = Path(__file__).resolve().with_name("nav2d.yaml")
RECORD_ENV = "NAV2D_RECORD_DIR"
SEED_ENV = "NAV2D_SEED"
NEWEST = 1
"""Subscription depth: a run reads its inputs' newest message (docs/explanation/model.md section 1), no backlog."""


class Work:
    """One process's nodes: their compute draws (seeded, so runs repeat) and the burn."""

    def __init__(self, nodes: Iterable[str]) -> None:
        self.draws = workload_draws(SPEC, nodes, int(os.environ.get(SEED_ENV, "0")))
        self.started_s = time.monotonic()

    def burn(self, node: str) -> None:
        """Busy for this run's compute time of ``node`` (CPU time of the calling thread)."""
        burn(self.draws[node](time.monotonic() - self.started_s))


class Records:
    """Run records of one process as JSON lines, each written when its run ends (a SIGKILL loses none)."""

    def __init__(self, process: str) -> None:
        folder = os.environ.get(RECORD_ENV)
        self.file = None if folder is None else (Path(folder) / f"{process}.jsonl").open("a", buffering=1)
        self.exit_path = None if folder is None else Path(folder) / f"{process}.exit"

    def exited(self) -> None:
        """The process shut down cleanly, now (CLOCK_REALTIME ns into ``<process>.exit``): its last words."""
        if self.exit_path is not None:
            self.exit_path.write_text(json.dumps({"exit_ns": time.time_ns()}) + "\n")

    def run(self, node: str, start_ns: int, origin_ns: int | None, **inputs: int | None) -> None:
        """Node ``node`` ran from ``start_ns`` to now (CLOCK_REALTIME, as ROS stamps) on data sensed at
        ``origin_ns``; ``inputs`` are the origins of its other inputs."""
        if self.file is not None:
            row = {"node": node, "start_ns": start_ns, "end_ns": time.time_ns(), "origin_ns": origin_ns, **inputs}
            self.file.write(json.dumps(row) + "\n")


def stamp_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def stamp_of(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def period_s(rate_hz: float) -> float:
    return 1.0 / rate_hz


def spin(make_node: Callable[[], Node]) -> None:
    """Spin one node in a single-threaded executor until Ctrl-C, SIGTERM or shutdown; exit quietly."""
    rclpy.init()
    node = None
    try:
        node = make_node()
        # Everything made so far lives until the end: out of the collector's sight, no collection walks it,
        # neither in a callback nor at exit (where walking it took ~2 s of Ctrl-C on a loaded CPU, 0.3 s frozen).
        gc.freeze()
        rclpy.spin(node)
    except KeyboardInterrupt:
        signal_thread_done()
    except ExternalShutdownException:
        pass
    except RuntimeError:  # rclpy's RCLError, or a take that Ctrl-C's shutdown cut short
        # A signal shut the context down while the node was being made, or is shutting it down while the
        # executor takes a message (seen once in CI: "Unable to convert call argument '0'" in take_message,
        # in a launch.sh run that Ctrl-C ends): give rclpy's signal thread its time before calling it an error.
        signal_thread_done()
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        shut_down()
    records = getattr(node, "records", None)
    if isinstance(records, Records):
        records.exited()


def signal_thread_done(timeout_s: float = 1.0) -> None:
    """Wait, after Ctrl-C, until rclpy's signal thread has shut the context down: it triggers the executors'
    SIGINT guard conditions first, through raw pointers, and a node or executor destroyed before it is done
    is a use-after-free in rclpy (a SIGSEGV at exit, more likely when catanc's trigger wakes the executor
    before that thread gets the CPU)."""
    deadline = time.monotonic() + timeout_s
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.002)


def shut_down() -> None:
    """``rclpy.try_shutdown()``, where rclpy's signal thread may shut the context down between its check and its
    shutdown (Ctrl-C: an RCLError, "rcl_shutdown already called")."""
    try:
        rclpy.try_shutdown()
    except RuntimeError:
        if rclpy.ok():
            raise


def latest(into: dict[str, Any], key: str) -> Callable[[Any], None]:
    """A subscription callback that keeps the newest message under ``key``."""

    def keep(message: Any) -> None:
        into[key] = message

    return keep
