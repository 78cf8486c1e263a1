"""A small rclpy app on catanc.ros, run as a process by the tests here (and by benchmarks/ros_dispatch.py).

``python tests/ros/ros_app.py ROLE [options] [--ros-args ...]``:

- ``head``: a ROS node whose timer (``catanc_ros.create_timer``) burns ``--burn-ms`` of CPU and
  publishes a ``geometry_msgs/PointStamped`` stamped with the time it started;
- ``sub``: a ROS node whose subscription (``catanc_ros.reported``) burns ``--burn-ms`` per message;
- ``plain``: a head on a plain ``node.create_timer`` (the benchmark's baseline).

``--busy-ms B --busy-period-ms P``: also a plain rclpy timer in the same executor, no DAG node's, that
burns ``B`` ms of CPU every ``P`` ms (other work of the executor's thread: an odometry callback).

Each callback prints one JSON line to stdout: ``{"event": "tick" | "message", "tid": its thread,
"main": the spinning thread, "mono_ns": CLOCK_MONOTONIC at its start, "expected_ns": when a plain
timer was due}``, so the tests read what ran where and when without asking catanc.  The DAG node
name comes from ``--ros-args -p catan.node:=NAME`` as params.yaml gives it, or ``--name``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from typing import Any

import rclpy
from geometry_msgs.msg import PointStamped
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from catanc import ros as catanc_ros

TOPIC = "catanc_test_points"


def burn(ms: float) -> None:
    start = time.thread_time()
    while time.thread_time() - start < ms / 1000.0:
        pass


def say(**fields: Any) -> None:
    sys.stdout.write(json.dumps(fields) + "\n")
    sys.stdout.flush()


class App(Node):  # type: ignore[misc]
    def __init__(self, options: argparse.Namespace, main: int) -> None:
        super().__init__(f"catanc_test_{options.role}")
        self.options = options
        self.main = main
        self.expected_ns = 0
        self.ticks = 0
        if options.role == "sub":
            callback = catanc_ros.reported(self, self.on_point, name=options.name)
            self.create_subscription(PointStamped, TOPIC, callback, 10)
            return
        if options.busy_ms > 0:
            self.busy_timer = self.create_timer(options.busy_period_ms / 1000.0, self.busy)
        self.publisher = self.create_publisher(PointStamped, TOPIC, 10)
        period_s = options.period_ms / 1000.0
        if options.role == "plain":
            self.timer = self.create_timer(period_s, self.tick)
        else:
            self.timer = catanc_ros.create_timer(self, period_s, self.tick, name=options.name, on_loss=options.on_loss)

    def tick(self) -> None:
        now = time.monotonic_ns()
        message = PointStamped()
        message.header.stamp = self.get_clock().now().to_msg()  # sensed now: the run's origin downstream
        period_ns = int(self.options.period_ms * 1e6)
        if self.options.role == "plain":  # when the timer was due: its last call's due time plus a period
            due = self.expected_ns + period_ns if self.expected_ns else now
            self.expected_ns = due if now - due < period_ns else now
        say(event="tick", tid=threading.get_native_id(), main=self.main, mono_ns=now, expected_ns=self.expected_ns)
        burn(self.options.burn_ms)
        self.publisher.publish(message)
        self.ticks += 1
        if self.ticks == self.options.shutdown_after:
            rclpy.try_shutdown()  # from inside the callback, as a node that is done would

    def busy(self) -> None:
        say(event="busy", mono_ns=time.monotonic_ns())
        burn(self.options.busy_ms)

    def on_point(self, message: PointStamped) -> None:
        stamp_ns = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        say(event="message", tid=threading.get_native_id(), main=self.main, stamp_ns=stamp_ns, real_ns=time.time_ns())
        burn(self.options.burn_ms)


def signal_thread_done(timeout_s: float = 1.0) -> None:
    """Wait, after a KeyboardInterrupt, until rclpy's signal thread has shut the context down. That thread
    triggers every executor's SIGINT guard condition first, through raw pointers: an executor destroyed before
    it is done is a use-after-free in rclpy (a SIGSEGV 1 run in 3 here, when the executor's thread, woken by
    catanc's trigger, reaches the KeyboardInterrupt before the signal thread gets the CPU)."""
    deadline = time.monotonic() + timeout_s
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.002)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=["head", "sub", "plain"])
    parser.add_argument("--name", default=None)
    parser.add_argument("--period-ms", type=float, default=20.0)
    parser.add_argument("--burn-ms", type=float, default=1.0)
    parser.add_argument("--on-loss", default="timer")
    parser.add_argument("--busy-ms", type=float, default=0.0, help="CPU a plain timer of the same executor burns")
    parser.add_argument("--busy-period-ms", type=float, default=50.0)
    parser.add_argument("--shutdown-after", type=int, default=0, help="ticks, then rclpy.try_shutdown()")
    parser.add_argument("--executor", choices=["single", "multi"], default="single")
    parser.add_argument("--cpu", type=int, default=None, help="run every thread on this CPU (as a launch pins it)")
    options = parser.parse_args(rclpy.utilities.remove_ros_args(sys.argv)[1:])
    if options.cpu is not None:
        os.sched_setaffinity(0, {options.cpu})  # before rclpy makes its threads: they inherit it
    rclpy.init(args=sys.argv)
    main_tid = threading.get_native_id()
    node = App(options, main_tid)
    executor = SingleThreadedExecutor() if options.executor == "single" else MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    say(event="spinning", main=main_tid)
    try:
        executor.spin()
    except KeyboardInterrupt:
        signal_thread_done()
    except ExternalShutdownException:
        pass
    except catanc_ros.CatancRosError as exc:
        say(event="error", text=str(exc))
        return 3
    finally:
        executor.shutdown()
        node.destroy_node()
        try:
            rclpy.try_shutdown()
        except RuntimeError:  # rclpy's signal thread shut it down between try_shutdown's check and its shutdown
            if rclpy.ok():
                raise
    say(event="exit")
    return 0


if __name__ == "__main__":
    sys.exit(main())
