"""The orders on a shared core: its slots' inside a period, the one that makes data flow through it,
and the stealing priority of its subchains (:func:`priorities`).

docs/explanation/model.md section 4: unless the spec gives ``schedule.order``, where a
weighted chain passes from subchain A to subchain B on the same core, A's
slot should end right before B's starts (cyclically: a producer last in the
period feeds a consumer first in the next).  The order minimises the
weighted sum, over such producer -> consumer pairs, of the time from the end
of A's slot to the start of B's, modulo ``T``; ties go to the order closest
to descending weight (the fallback order, compared position by position).

The order is chosen after Stage II, from the solved slices: the model's
metrics are worst cases that no order changes, so Stage II's optimum does
not depend on it, while the time between slots does.  Every permutation is
scored up to :data:`ENUMERATE_UP_TO` subchains on a core; a larger core
keeps the fallback order.  Pure and deterministic.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

from catanc.model.problem import Problem
from catanc.spec.language import Schedule

ENUMERATE_UP_TO = 7
"""Score every order of a core with at most this many subchains (7! = 5,040 orders, a few ms)."""

TIE = 1e-9
"""Relative: costs this close are ties."""


def flow_weights(problem: Problem, members: Sequence[str]) -> dict[tuple[str, str], float]:
    """Per producer -> consumer pair on one core: the weight of the weighted chains passing from one to the other."""
    inside = set(members)
    weights: dict[tuple[str, str], float] = {}
    for term in problem.response_terms:
        if term.weight <= 0:
            continue
        stages = [stage.name for stage in problem.chains[term.chain].stages if not stage.fixed]
        for producer, consumer in itertools.pairwise(stages):
            if producer != consumer and producer in inside and consumer in inside:
                weights[producer, consumer] = weights.get((producer, consumer), 0.0) + term.weight
    return weights


def slot_starts(order: Sequence[str], slices: Mapping[str, float], switch_ms: float) -> dict[str, float]:
    """Each slot's start in the period: after the switch to it, in ``order``."""
    starts: dict[str, float] = {}
    offset = 0.0
    for name in order:
        offset += switch_ms
        starts[name] = offset
        offset += slices[name]
    return starts


def flow_cost(
    order: Sequence[str],
    slices: Mapping[str, float],
    weights: Mapping[tuple[str, str], float],
    switch_ms: float,
    length: float,
) -> float:
    """``sum w (start_B - end_A) mod T`` over the pairs: the weighted wait from a producer's slot to its consumer's."""
    starts = slot_starts(order, slices, switch_ms)
    total = 0.0
    for (producer, consumer), weight in weights.items():
        gap = (starts[consumer] - (starts[producer] + slices[producer])) % length
        total += weight * gap
    return total


def data_flow_order(
    fallback: Sequence[str],
    slices: Mapping[str, float],
    weights: Mapping[tuple[str, str], float],
    switch_ms: float,
    length: float,
) -> tuple[str, ...]:
    """The order of one core's slots (see the module's docstring); ``fallback``: by descending weight."""
    if not weights or len(fallback) > ENUMERATE_UP_TO or length <= 0 or not math.isfinite(length):
        return tuple(fallback)
    best: tuple[float, tuple[str, ...]] | None = None
    # Permutations come in lexicographic order of the fallback's positions: on a tie the first stays.
    for order in itertools.permutations(fallback):
        cost = flow_cost(order, slices, weights, switch_ms, length)
        if best is None or cost < best[0] - TIE * max(1.0, abs(best[0])):
            best = (cost, order)
    assert best is not None
    return best[1]


def priorities(problem: Problem, schedule: Schedule, importance: dict[str, float]) -> dict[str, int]:
    """Stealing priority: the spec's, else by weight (the heaviest highest); higher steals from lower."""
    if schedule.priorities:
        return {sub.name: schedule.priorities.get(sub.name, 0) for sub in problem.subchains}
    ranked = sorted(range(len(problem.subchains)), key=lambda i: (-importance[problem.subchains[i].name], i))
    count = len(ranked)
    return {problem.subchains[i].name: count - rank for rank, i in enumerate(ranked)}
