"""Burning CPU for a synthetic run: on the calling thread, or on several threads as a speedup table says."""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Sequence

from catanc.spec.speedup import threads_and_speedup


def burn(compute_ms: float, since_s: float | None = None) -> None:
    """Busy-loop until this thread has used ``compute_ms`` of CPU time (since ``since_s`` on its
    ``time.thread_time()`` clock, default now)."""
    end = (time.thread_time() if since_s is None else since_s) + compute_ms / 1000.0
    while time.thread_time() < end:
        pass


HASHED_BLOCK = bytes(16 * 1024)
"""What a parallel burn hashes at a time: hashlib lets go of the interpreter lock for blocks this big."""


def burn_released(compute_ms: float, since_s: float | None = None) -> None:
    """:func:`burn`, but in C code that releases the interpreter lock, so threads really burn in parallel."""
    end = (time.thread_time() if since_s is None else since_s) + compute_ms / 1000.0
    while time.thread_time() < end:
        hashlib.sha256(HASHED_BLOCK)


def burn_parallel(compute_ms: float, threads: int, speedups: Sequence[float], since_s: float | None = None) -> int:
    """One run of a node whose single-thread compute is ``compute_ms``, on ``threads`` threads; the threads used.

    As the planner models it (``c^q = c / speedup(q)``), each of the ``q`` threads the speedup
    table makes worth using burns ``c / speedup(q)`` of CPU time, so the run takes that long.
    The calling thread is one of them: it is the one the enforcer pins and measures, and it counts
    its CPU time from ``since_s`` (:func:`burn`).
    """
    q, speedup = threads_and_speedup(speedups, threads)
    each_ms = compute_ms / speedup
    if q == 1:
        burn(each_ms, since_s)
        return 1
    helpers = [threading.Thread(target=burn_released, args=(each_ms,), daemon=True) for _ in range(q - 1)]
    for helper in helpers:
        helper.start()
    burn_released(each_ms, since_s)
    for helper in helpers:
        helper.join()
    return q
