"""CPU time one sleep/wake-up costs on this machine, from Python (the enforcer's floor: benchmarks/RESULTS.md).

    python -m benchmarks.wake_cost

For the same without Python: ``cc -O2 benchmarks/wake_cost.c -o /tmp/wake_cost && /tmp/wake_cost``.
"""

from __future__ import annotations

import resource
import threading
import time
from collections.abc import Callable

WAKES = 2000
SLEEP_S = 0.002


def thread_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_THREAD)
    return usage.ru_utime + usage.ru_stime


def per_wake_us(sleep: Callable[[float], object]) -> float:
    before = thread_cpu_s()
    for _ in range(WAKES):
        sleep(SLEEP_S)
    return (thread_cpu_s() - before) / WAKES * 1e6


def main() -> None:
    never = threading.Event()
    print(f"time.sleep:  {per_wake_us(time.sleep):.1f} us of CPU per wake-up")
    print(f"Event.wait:  {per_wake_us(never.wait):.1f} us of CPU per wake-up")


if __name__ == "__main__":
    main()
