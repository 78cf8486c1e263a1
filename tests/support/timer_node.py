"""A node on its own timer, as ``catanc run --observe`` finds them: burn BURN_MS of CPU every PERIOD_MS.

``python tests/support/timer_node.py BURN_MS PERIOD_MS`` runs until killed; it never speaks to catanc.
"""

from __future__ import annotations

import sys
import time

MIN_IDLE_S = 0.008
"""Idle at least this long between runs, even when late: far longer than the observer's 1 ms poll, so runs do not
merge when a loaded machine delays a poll by a few ms (with 3 ms, a p95 of 3.95 ms was seen for 3 ms runs)."""


def main() -> None:
    burn_ms, period_ms = float(sys.argv[1]), float(sys.argv[2])
    next_run = time.monotonic()
    while True:
        end = time.thread_time() + burn_ms / 1000.0
        while time.thread_time() < end:
            pass
        next_run = max(next_run + period_ms / 1000.0, time.monotonic())  # late: the next run starts soon
        time.sleep(max(MIN_IDLE_S, next_run - time.monotonic()))


if __name__ == "__main__":
    main()
