"""How a node's compute scales with threads (stdlib only: the synthetic worker uses it too)."""

from __future__ import annotations

from collections.abc import Sequence


def best_speedup(speedups: Sequence[float], threads: int) -> float:
    """Best speedup with *at most* ``threads`` threads: more threads are never forced."""
    return max(speedups[: max(1, min(threads, len(speedups)))])


def threads_used(speedups: Sequence[float], threads: int) -> int:
    """How many threads a node runs with when allowed ``threads``: the fewest reaching :func:`best_speedup`."""
    best = best_speedup(speedups, threads)
    return next(q for q, speedup in enumerate(speedups, start=1) if speedup >= best)


def threads_and_speedup(speedups: Sequence[float], threads: int) -> tuple[int, float]:
    """:func:`threads_used` and the speedup those threads give."""
    used = threads_used(speedups, threads)
    return used, speedups[used - 1]
