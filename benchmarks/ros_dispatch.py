"""catanc's delay from a trigger to an rclpy callback's start, beside a plain rclpy timer's dispatch (issue 46).

    python -m benchmarks.ros_dispatch                 # 4 rounds of 200 calls each way, 20 ms apart
    python -m benchmarks.ros_dispatch --rounds 6 --calls 300

One rclpy node process at a time, pinned to CPU 0 at SCHED_FIFO
:data:`~catanc.model.priorities.RUNNING_FIFO` as a raised subchain runs (SCHED_OTHER without root),
its callback every 20 ms:

- **plain**: ``node.create_timer(0.02, tick)``; a call's dispatch delay is its start less the time
  the timer was due (the period less ``time_until_next_call()`` read first thing in the callback,
  after rcl moved the timer on by one period);
- **catanc**: ``catanc.ros.create_timer(node, 0.02, tick)`` under this process, which plays the
  enforcer on CPU 1 (welcome, route, then a trigger datagram every 20 ms); a call's delay is its
  start less the moment before the trigger was sent, both on CLOCK_MONOTONIC.

The rounds alternate (plain, catanc, plain, ...) so the VM's speed, which moves from minute to
minute, moves both alike.  The target (issue 46): catanc's p50 at most 0.2 ms above plain's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from catanc.model.priorities import ENFORCER_FIFO, RUNNING_FIFO
from catanc.runtime.protocol.endpoints import EnforcerSocket, open_endpoint
from catanc.runtime.protocol.messages import Hello, Route, Stop, decode, trigger_datagram

ROOT = Path(__file__).resolve().parent.parent
NODE_CPU, ENFORCER_CPU = 0, 1
PERIOD_S = 0.02

NODE = """
import json, os, sys, time
mode, calls, level, cpu = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
period_s = float(sys.argv[5])
os.sched_setaffinity(0, {cpu})
if level:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(level))
import rclpy
from rclpy.executors import ExternalShutdownException
from catanc import ros as catanc_ros
rclpy.init()
node = rclpy.create_node("dispatch_" + mode)
starts, delays = [], []
timer = None
def tick():
    now = time.monotonic_ns()
    if mode == "plain":
        delays.append(period_s * 1e9 - timer.time_until_next_call())
    starts.append(now)
    if len(starts) >= calls:
        rclpy.try_shutdown()
if mode == "plain":
    timer = node.create_timer(period_s, tick)
else:
    timer = catanc_ros.create_timer(node, period_s, tick, name="head", on_loss="exit")
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
rclpy.try_shutdown()
sys.stdout.write(json.dumps({"starts": starts, "delays": delays}))
"""


def node_process(mode: str, calls: int, socket_path: Path | None) -> subprocess.Popen[str]:
    level = RUNNING_FIFO if os.geteuid() == 0 else 0
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("CATANC_SOCKET", None)
    if socket_path is not None:
        env["CATANC_SOCKET"] = str(socket_path)
    argv = [sys.executable, "-c", NODE, mode, str(calls), str(level), str(NODE_CPU), repr(PERIOD_S)]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, env=env)


def plain_round(calls: int) -> list[float]:
    """Dispatch delays of a plain rclpy timer, ms (the first call, at the timer's creation, left out)."""
    proc = node_process("plain", calls + 1, None)
    out, _ = proc.communicate(timeout=60 + calls * PERIOD_S * 4)
    return [delay / 1e6 for delay in json.loads(out)["delays"][1:]]


def catanc_round(calls: int, folder: Path) -> list[float]:
    """Trigger-to-callback delays under catanc.ros, ms: this process sends the triggers."""
    path = folder / "s.sock"
    with EnforcerSocket(path) as sock:
        proc = node_process("catanc", calls, path)
        endpoint = None
        deadline = time.monotonic() + 60
        while endpoint is None:
            assert time.monotonic() < deadline, "the node did not register"
            for received in sock.receive():
                message = decode(received.data)
                if isinstance(message, Hello) and received.sender is not None:
                    endpoint = open_endpoint(message.node, message.pid, message.tid, received.sender)
            time.sleep(0.001)
        try:
            endpoint.send(Route(endpoint.node).encode())
            time.sleep(0.5)  # the node starts its watcher once routed
            sent = []
            next_at = time.monotonic()
            for seq in range(1, calls + 1):
                next_at += PERIOD_S
                time.sleep(max(next_at - time.monotonic() - 0.001, 0.0))
                while time.monotonic() < next_at:
                    pass  # the last ms spun: this process's own wake-up must not be the delay measured
                sent.append(time.monotonic_ns())
                endpoint.send(trigger_datagram(endpoint.node, seq, 1))
            time.sleep(0.1)
            endpoint.send(Stop().encode())
            out, _ = proc.communicate(timeout=60)
        finally:
            endpoint.close()
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    starts = json.loads(out)["starts"]
    delays = []
    for trigger_ns in sent:  # the callback that started after each trigger, before the next one was due
        after = [start for start in starts if trigger_ns <= start < trigger_ns + PERIOD_S * 1e9]
        if after:
            delays.append((after[0] - trigger_ns) / 1e6)
    return delays


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args()
    if os.geteuid() == 0:
        os.sched_setaffinity(0, {ENFORCER_CPU})
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(ENFORCER_FIFO))
    plain: list[float] = []
    triggered: list[float] = []
    with tempfile.TemporaryDirectory(prefix="catanc-dispatch-") as folder:
        for round_ in range(args.rounds):
            plain_ms, catanc_ms = plain_round(args.calls), catanc_round(args.calls, Path(folder))
            plain += plain_ms
            triggered += catanc_ms
            print(f"round {round_ + 1}: plain p50 {statistics.median(plain_ms):.3f} ms, "
                  f"catanc p50 {statistics.median(catanc_ms):.3f} ms", flush=True)  # fmt: skip
    load = os.getloadavg()[0]
    print(f"\n{args.rounds} rounds of {args.calls} calls each way, every {PERIOD_S * 1000:g} ms, load {load:.1f}")
    print("| dispatch | calls | p50 ms | p95 ms | max ms |")
    print("|---|---|---|---|---|")
    for name, values in (("plain rclpy timer (start - due)", plain), ("catanc.ros (start - trigger sent)", triggered)):
        print(f"| {name} | {len(values)} | {statistics.median(values):.3f} | {percentile(values, 0.95):.3f} | "
              f"{max(values):.3f} |")  # fmt: skip
    above = statistics.median(triggered) - statistics.median(plain)
    print(f"\ncatanc's p50 above plain's: {above:.3f} ms (target: at most 0.2 ms)")


if __name__ == "__main__":
    main()
