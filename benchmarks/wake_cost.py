"""What a slot switch costs from Python at the least, beside the C floor (issue 31; root for SCHED_FIFO).

    python -m benchmarks.wake_cost                      # 800 Hz, 5 s a loop, CPU 0
    python -m benchmarks.wake_cost --rate 400 --seconds 10 --cpu 1

Three loops, each at SCHED_FIFO 4 pinned to one CPU, waking at ``--rate`` on an absolute
CLOCK_MONOTONIC grid, one after the other, alone and then beside a process that keeps that CPU
busy (at SCHED_OTHER, as an app's threads between slices):

- **C**: ``benchmarks/wake_cost.c``, ``clock_nanosleep(TIMER_ABSTIME)`` and nothing else (the
  floor issue 31 measures the enforcer against);
- **Python, wake only**: ``select.select`` on a datagram socket and a pipe (what the enforcer's
  loop waits on) until the due time, then nothing;
- **Python, a switch**: the same, then what the least slot switch does: two ``sched_setscheduler``
  calls on another process's thread (the previous owner lowered, the next one raised) and one
  trigger datagram sent (and drained).

Each loop's CPU is its thread's CPU time (``CLOCK_THREAD_CPUTIME_ID``) over its wake-ups.  A loop
that does no more than this is the least any Python event loop can cost per wake-up: the ratio to
the C floor bounds what a Python enforcer can reach.
"""

from __future__ import annotations

import argparse
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from catanc.core.priorities import ENFORCER_FIFO

ROOT = Path(__file__).resolve().parent.parent
TRIGGER = b"catanc1 trigger LM 123456 1"


def python_loop(rate_hz: float, seconds: float, cpu: int, *, switch: bool) -> float:
    """CPU per wake-up (us) of a Python loop, in a child process so that its priority dies with it."""
    read_end, write_end = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover - the measuring child
        os.close(read_end)
        try:
            per_wake = _loop(rate_hz, seconds, cpu, switch=switch)
            os.write(write_end, f"{per_wake}".encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end) as answer:
        text = answer.read()
    os.waitpid(child, 0)
    return float(text)


def _loop(rate_hz: float, seconds: float, cpu: int, *, switch: bool) -> float:
    os.sched_setaffinity(0, {cpu})
    target = os.fork()  # a sleeping process whose priority the switches change
    if target == 0:  # pragma: no cover
        signal.pause()
        os._exit(0)
    sender, receiver = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    receiver.setblocking(False)
    wake_r, _wake_w = os.pipe()
    fds = [receiver.fileno(), wake_r]
    low, high = os.sched_param(1), os.sched_param(2)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(ENFORCER_FIFO))
    try:
        period_ns = int(1e9 / rate_hz)
        wakes = int(rate_hz * seconds)
        due = time.monotonic_ns() + period_ns
        started = time.thread_time_ns()
        for _ in range(wakes):
            timeout = (due - time.monotonic_ns()) / 1e9
            select.select(fds, [], [], timeout if timeout > 0 else 0)
            if switch:
                os.sched_setscheduler(target, os.SCHED_FIFO, high)
                os.sched_setscheduler(target, os.SCHED_FIFO, low)
                sender.send(TRIGGER)
                receiver.recv(64)
            due += period_ns
        return (time.thread_time_ns() - started) / wakes / 1000.0
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        os.kill(target, signal.SIGKILL)
        os.waitpid(target, 0)


def build_c_loop(folder: Path, program: str) -> Path:
    """``benchmarks/wake_cost.c`` compiled into ``folder``; exits naming ``program`` without a C compiler."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        sys.exit(f"{program}: needs a C compiler (cc) for benchmarks/wake_cost.c, the floor")
    binary = folder / "wake_cost"
    subprocess.run([compiler, "-O2", str(ROOT / "benchmarks" / "wake_cost.c"), "-o", str(binary)], check=True)
    return binary


def c_loop_argv(binary: Path, rate_hz: float, seconds: float, cpu: int) -> list[str]:
    """The C loop's command line: ``rate_hz`` wake-ups a second for ``seconds``, SCHED_FIFO 4 on ``cpu``."""
    return [str(binary), repr(rate_hz), repr(seconds), str(ENFORCER_FIFO), str(cpu)]


def parsed_per_wake_us(line: str) -> float:
    """The CPU per wake-up (us) in the C loop's line of output."""
    return float(line.split(":", 1)[1].split(maxsplit=1)[0])


def c_loop(binary: Path, rate_hz: float, seconds: float, cpu: int) -> tuple[float, str]:
    """CPU per wake-up (us) of the C loop at ``rate_hz``, SCHED_FIFO 4 on ``cpu``; and its line of output."""
    out = subprocess.run(
        c_loop_argv(binary, rate_hz, seconds, cpu), capture_output=True, text=True, check=True, timeout=seconds + 30
    ).stdout.strip()
    return parsed_per_wake_us(out), out


def busy(cpu: int) -> subprocess.Popen[bytes]:
    """A process keeping ``cpu`` busy at SCHED_OTHER until killed."""
    code = f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass\n"
    return subprocess.Popen([sys.executable, "-c", code])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=800.0, help="wake-ups a second (nav2d's plan: ~800)")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--cpu", type=int, default=0)
    args = parser.parse_args()
    if os.geteuid() != 0:
        sys.exit("benchmarks.wake_cost: needs root (SCHED_FIFO)")
    with tempfile.TemporaryDirectory() as folder:
        binary = build_c_loop(Path(folder), "benchmarks.wake_cost")
        print(f"load average {os.getloadavg()}; {args.rate:g} wake-ups a second, {args.seconds:g} s a loop")
        print("| where | C | Python, wake only | Python, a switch | ratios to C |")
        print("|---|---|---|---|---|")
        for beside in (False, True):
            hog = busy(args.cpu) if beside else None
            try:
                time.sleep(0.2 if beside else 0.0)
                c = c_loop(binary, args.rate, args.seconds, args.cpu)[0]
                wake = python_loop(args.rate, args.seconds, args.cpu, switch=False)
                switch = python_loop(args.rate, args.seconds, args.cpu, switch=True)
            finally:
                if hog is not None:
                    hog.kill()
                    hog.wait()
            where = "beside a busy process" if beside else "alone"
            print(
                f"| {where} | {c:.1f} us | {wake:.1f} us | {switch:.1f} us | {wake / c:.2f}x / {switch / c:.2f}x |",
                flush=True,
            )


if __name__ == "__main__":
    main()
