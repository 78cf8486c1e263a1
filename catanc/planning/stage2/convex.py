"""Sums of maxima of pieces ``a x + b / x + c`` (``a, b, c >= 0``) in one variable ``x > 0``.

Such a sum is convex in ``x``.  Between consecutive breakpoints (where two
pieces of one maximum cross) each maximum is a single piece, and there a
bound ``piece <= limit`` holds on an interval (between the roots of a
quadratic), a piece is least at ``sqrt(b / a)``, and a maximum of pieces is
least where one is stationary, two cross, or at an end.
:func:`optimum_point` and :func:`least_scale_point` search the segments
so for :class:`~catanc.planning.stage2.onebatch.OneBatchRuns`; where the
optimum is not one attained point they answer :data:`OPEN`.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from enum import Enum
from typing import Final

Piece = tuple[float, float, float]
"""``(a, b, c)`` of ``a x + b / x + c``."""


class Open(Enum):
    """The closed form has no unique attained optimum here: solve the relaxation instead."""

    OPEN = "open"


OPEN: Final = Open.OPEN

FLAT = 1e-12
"""An objective piece whose terms in ``x`` are this small against its value counts as flat in ``x``."""


@dataclass(frozen=True)
class Convex:
    """A sum of maxima of pieces: the maxima of two or more pieces, and the single pieces summed."""

    maxima: tuple[tuple[Piece, ...], ...]
    base: Piece

    def at(self, x: float) -> Piece:
        """The one piece this equals around ``x``, for ``x`` strictly between breakpoints."""
        a, b, c = self.base
        for pieces in self.maxima:
            top = pieces[0]
            highest = top[0] * x + top[1] / x + top[2]
            for piece in pieces[1:]:
                value = piece[0] * x + piece[1] / x + piece[2]
                if value > highest:
                    top, highest = piece, value
            a, b, c = a + top[0], b + top[1], c + top[2]
        return a, b, c

    def value(self, x: float) -> float:
        a, b, c = self.at(x)
        return a * x + b / x + c

    @functools.cached_property
    def breakpoints(self) -> tuple[float, ...]:
        """Where two pieces of a maximum cross, ascending (each once): computed once, as the closed form asks
        for the edges above several ``least``."""
        crossings: set[float] = set()
        for pieces in self.maxima:
            for i, first in enumerate(pieces):
                for second in pieces[i + 1 :]:
                    crossings.update(_crossings(first, second))
        return tuple(sorted(crossings))

    def edges(self, least: float) -> list[float]:
        """``least``, the breakpoints above it (where two pieces of a maximum cross), then infinity."""
        return [least, *(x for x in self.breakpoints if x > least), math.inf]

    def scaled(self, factor: float) -> Convex:
        def times(piece: Piece) -> Piece:
            return piece[0] * factor, piece[1] * factor, piece[2] * factor

        return Convex(tuple(tuple(times(piece) for piece in pieces) for pieces in self.maxima), times(self.base))


def _inside(low: float, high: float) -> float:
    """A point strictly inside ``(low, high)``, ``0 <= low < high <= inf``."""
    if math.isfinite(high):
        return math.sqrt(low * high) if low > 0 else high / 2
    return 2 * low if low > 0 else 1.0


def _minimisers(objective: Convex, least: float) -> tuple[float, float]:
    """Where ``objective`` is least on ``[least, inf)``: one point, or a segment where it is flat.

    Convexity orders the segments: a binary search for the one whose piece is stationary
    inside it, or the breakpoint between one that falls and one that rises.  An end at 0 or
    infinity means the least value is approached, not attained.
    """
    edges = objective.edges(least)
    first, last = 0, len(edges) - 2
    while first <= last:
        k = (first + last) // 2
        low, high = edges[k], edges[k + 1]
        a, b, _ = objective.at(_inside(low, high))
        if a == 0 and b == 0:
            return low, high
        stationary = math.sqrt(b / a) if a > 0 and b > 0 else (0.0 if a > 0 else math.inf)
        if stationary < low:
            last = k - 1
        elif stationary > high:
            first = k + 1
        else:
            return stationary, stationary
    return edges[first], edges[first]


def _sublevel(bound: Convex, limit: float, least: float) -> tuple[float, float] | None:
    """Where ``bound <= limit`` on ``[least, inf)``: an interval, by convexity (None: nowhere)."""
    edges = bound.edges(least)
    low, high = math.inf, -math.inf
    for start, end in itertools.pairwise(edges):
        allowed = _at_most(bound.at(_inside(start, end)), limit)
        if allowed is not None and max(start, allowed[0]) <= min(end, allowed[1]):
            low, high = min(low, max(start, allowed[0])), max(high, min(end, allowed[1]))
    return (low, high) if low <= high else None


def optimum_point(
    objective: Convex, bounds: list[Convex], limits: list[float], least: float, most: float = math.inf
) -> float | Open | None:
    """The objective's least ``x`` in ``[least, most]`` where every bound holds (None: nowhere; OPEN: not
    one attained point).

    On an interval a convex function is least at its unconstrained minimiser clipped to it.
    """
    low, high = least, most
    for bound, limit in zip(bounds, limits, strict=True):
        allowed = _sublevel(bound, limit, least)
        if allowed is None:
            return None
        low, high = max(low, allowed[0]), min(high, allowed[1])
        if low > high:
            return None
    first, last = _minimisers(objective, least)
    x = min(max(first, low), high)
    if min(max(last, low), high) != x or not 0 < x < math.inf:
        return OPEN
    return x


def least_scale_point(bounds: list[Convex], least: float, most: float = math.inf) -> float | Open:
    """The ``x`` in ``[least, most]`` needing the least scale: ``max(1, max_j bound_j)``, least (bounds
    divided by their limits).

    On each segment every bound is one piece, and the maximum of convex pieces is least where
    one is stationary, two cross (the constant 1 among them), or at an end.  A least value
    approached at ``x = 0`` or ``x = inf`` is not attained: OPEN.
    """
    crossings = {x for bound in bounds for x in bound.edges(least)[1:-1] if x < most}
    edges = [least, *sorted(crossings), most]
    best: tuple[float, float] | None = None
    limits: list[float] = []  # the least scale approached at x = 0 (where no slice bounds x), then at inf
    last: list[Piece] = []
    for low, high in itertools.pairwise(edges):
        sample = _inside(low, high)
        last = [bound.at(sample) for bound in bounds] + [(0.0, 0.0, 1.0)]
        if low == 0:
            limits.append(math.inf if any(b > 0 for _, b, _ in last) else max(c for _, _, c in last))
        candidates = [low, high, sample]
        for i, (a, b, _) in enumerate(last):
            if a > 0 and b > 0:
                candidates.append(math.sqrt(b / a))
            for other in last[i + 1 :]:
                candidates += _crossings(last[i], other)
        for x in candidates:
            if low <= x <= high and 0 < x < math.inf:
                needed = max(a * x + b / x + c for a, b, c in last)
                if best is None or needed < best[0]:
                    best = (needed, x)
    assert best is not None  # the last segment's sample is a candidate
    if math.isinf(most):  # where no bound grows with x on the last segment, the least scale may lie at x = inf
        limits.append(math.inf if any(a > 0 for a, _, _ in last) else max(c for _, _, c in last))
    needed, x = best
    return OPEN if limits and needed > min(limits) * (1 + FLAT) else x


def _crossings(first: Piece, second: Piece) -> list[float]:
    """Where two pieces are equal, for ``x > 0``: the positive roots of ``da x^2 + dc x + db``."""
    da, db, dc = first[0] - second[0], first[1] - second[1], first[2] - second[2]
    if da == 0:
        return [-db / dc] if dc != 0 and -db / dc > 0 else []
    discriminant = dc * dc - 4 * da * db
    if discriminant < 0:
        return []
    q = -0.5 * (dc + math.copysign(math.sqrt(discriminant), dc))  # the stable pair of roots
    roots = [q / da] + ([db / q] if q != 0 else [])
    return [x for x in roots if x > 0]


def _at_most(piece: Piece, limit: float) -> tuple[float, float] | None:
    """Where ``a x + b / x + c <= limit`` for ``x > 0`` (an interval; None: nowhere)."""
    a, b, c = piece
    room = limit - c  # a x^2 - room x + b <= 0
    if room < 0 or (room == 0 and b > 0):
        return None
    discriminant = room * room - 4 * a * b
    if discriminant < 0:
        return None
    root = math.sqrt(discriminant)
    least = 2 * b / (room + root) if b > 0 else 0.0
    most = (room + root) / (2 * a) if a > 0 else math.inf
    return least, most
