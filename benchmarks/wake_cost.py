"""What a slot switch costs from Python at the least, beside the C floor (issue 31; root for SCHED_FIFO).

    python -m benchmarks.wake_cost                      # 800 Hz, 5 s a loop, CPU 0
    python -m benchmarks.wake_cost --rate 400 --seconds 10 --cpu 1

Four loops, each at SCHED_FIFO 4 pinned to one CPU, waking at ``--rate`` on an absolute
CLOCK_MONOTONIC grid, one after the other, alone and then beside a process that keeps that CPU
busy (at SCHED_OTHER, as an app's threads between slices):

- **C**: ``benchmarks/wake_cost.c``, ``clock_nanosleep(TIMER_ABSTIME)`` and nothing else (the
  floor issue 31 measures the enforcer against);
- **Python, wake only**: ``select.select`` on a datagram socket and a pipe (what the enforcer's
  loop waits on) until the due time, then nothing;
- **Python, a switch**: the same, then what the least slot switch does: two ``sched_setscheduler``
  calls on another process's thread (the previous owner lowered, the next one raised) and one
  trigger datagram sent (and drained);
- **numba, a switch**: the same switch compiled (numba's nopython mode calling libc's ``ppoll``,
  ``sched_setscheduler``, ``send`` and ``recv`` through ctypes, as a compiled hot loop of the
  enforcer would): what a switch costs without the interpreter (needs the ``sim`` extra).

Each loop's CPU is its thread's CPU time (``CLOCK_THREAD_CPUTIME_ID``) over its wake-ups.  A loop
that does no more than this is the least any Python event loop can cost per wake-up: the ratio to
the C floor bounds what a Python enforcer can reach.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from catanc.extras import require
from catanc.model.priorities import ENFORCER_FIFO

ROOT = Path(__file__).resolve().parent.parent
TRIGGER = b"catanc1 trigger LM 123456 1"


def python_loop(rate_hz: float, seconds: float, cpu: int, *, switch: bool, compiled: bool = False) -> float:
    """CPU per wake-up (us) of a Python (or numba) loop, in a child process so that its priority dies with it."""
    read_end, write_end = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover - the measuring child
        os.close(read_end)
        try:
            per_wake = _loop(rate_hz, seconds, cpu, switch=switch, compiled=compiled)
            os.write(write_end, f"{per_wake}".encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end) as answer:
        text = answer.read()
    os.waitpid(child, 0)
    return float(text)


def _loop(rate_hz: float, seconds: float, cpu: int, *, switch: bool, compiled: bool) -> float:
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
    period_ns = int(1e9 / rate_hz)
    wakes = int(rate_hz * seconds)
    compiled_loop = _compiled_switches(target, sender.fileno(), fds) if compiled else None
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(ENFORCER_FIFO))
    try:
        if compiled_loop is not None:
            started = time.thread_time_ns()
            compiled_loop(wakes, period_ns)
            return (time.thread_time_ns() - started) / wakes / 1000.0
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


def _compiled_switches(target: int, sender: int, fds: list[int]) -> Callable[[int, int], None]:
    """The Python switch loop compiled by numba, its system calls made through libc; warmed up (compiled) here."""
    require("numba", "benchmarks.wake_cost's compiled loop")
    import numba  # noqa: PLC0415 (the sim extra: only this loop needs it)
    import numpy as np  # noqa: PLC0415

    libc = ctypes.CDLL(None, use_errno=True)
    signatures: dict[str, tuple[type, list[type]]] = {
        "clock_gettime": (ctypes.c_int, [ctypes.c_int, ctypes.c_void_p]),
        "ppoll": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_void_p, ctypes.c_void_p]),
        "sched_setscheduler": (ctypes.c_int, [ctypes.c_int, ctypes.c_int, ctypes.c_void_p]),
        "send": (ctypes.c_ssize_t, [ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]),
        "recv": (ctypes.c_ssize_t, [ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]),
    }
    for name, (restype, argtypes) in signatures.items():
        getattr(libc, name).restype, getattr(libc, name).argtypes = restype, argtypes
    clock_gettime, ppoll, setscheduler = libc.clock_gettime, libc.ppoll, libc.sched_setscheduler
    send, recv = libc.send, libc.recv
    polled = np.zeros(2 * len(fds), dtype=np.int32)  # struct pollfd: int fd; short events, revents
    polled[0::2] = fds
    polled.view(np.int16)[2::4] = select.POLLIN
    times = np.zeros(2, dtype=np.int64)  # a struct timespec
    param = np.zeros(1, dtype=np.int32)  # a struct sched_param
    message = np.frombuffer(TRIGGER, dtype=np.uint8).copy()
    drained = np.zeros(64, dtype=np.uint8)
    receiver, count, fifo, nonblocking = fds[0], len(fds), os.SCHED_FIFO, socket.MSG_DONTWAIT
    monotonic = time.CLOCK_MONOTONIC

    @numba.njit(nogil=True)  # type: ignore[untyped-decorator]
    def run(  # noqa: PLR0917 (numba takes the arrays one by one)
        wakes: int, period_ns: int, times: Any, param: Any, polled: Any, message: Any, drained: Any
    ) -> None:
        # Arrays are arguments: numba freezes the ones a function closes over as read-only constants.
        clock_gettime(monotonic, times.ctypes.data)
        due = times[0] * 1_000_000_000 + times[1] + period_ns
        for _ in range(wakes):
            clock_gettime(monotonic, times.ctypes.data)
            rest = max(due - (times[0] * 1_000_000_000 + times[1]), 0)
            times[0], times[1] = rest // 1_000_000_000, rest % 1_000_000_000
            ppoll(polled.ctypes.data, count, times.ctypes.data, 0)
            param[0] = 2
            setscheduler(target, fifo, param.ctypes.data)
            param[0] = 1
            setscheduler(target, fifo, param.ctypes.data)
            send(sender, message.ctypes.data, message.size, nonblocking)
            recv(receiver, drained.ctypes.data, drained.size, nonblocking)
            due += period_ns

    def switches(wakes: int, period_ns: int) -> None:
        run(wakes, period_ns, times, param, polled, message, drained)

    switches(2, 1_000_000)  # compiled now, outside the measured loop
    return switches


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
        print("| where | C | Python, wake only | Python, a switch | numba, a switch | ratios to C |")
        print("|---|---|---|---|---|---|")
        for beside in (False, True):
            hog = busy(args.cpu) if beside else None
            try:
                time.sleep(0.2 if beside else 0.0)
                c = c_loop(binary, args.rate, args.seconds, args.cpu)[0]
                wake = python_loop(args.rate, args.seconds, args.cpu, switch=False)
                switch = python_loop(args.rate, args.seconds, args.cpu, switch=True)
                compiled = python_loop(args.rate, args.seconds, args.cpu, switch=True, compiled=True)
            finally:
                if hog is not None:
                    hog.kill()
                    hog.wait()
            where = "beside a busy process" if beside else "alone"
            print(
                f"| {where} | {c:.1f} us | {wake:.1f} us | {switch:.1f} us | {compiled:.1f} us "
                f"| {wake / c:.2f}x / {switch / c:.2f}x / {compiled / c:.2f}x |",
                flush=True,
            )


if __name__ == "__main__":
    main()
