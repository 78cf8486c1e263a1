"""Every Stage I allocation, scored: the MILP's test oracle, and a method for small apps.

Allocations are set partitions of the subchains (a block of two or more is
a shared group on one core; a singleton is dedicated) times the ways to hand
the remaining cores to the dedicated singletons.  With ``N >= K`` subchains
every core is used; with fewer, cores may stay idle.  Partitions that split
an executor's subchains are skipped (:mod:`catanc.planning.stage1.together`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence

from catanc.errors import UsageError
from catanc.model.problem import Problem
from catanc.planning.stage1.estimate import (
    SCALE_SLACK,
    Allocation,
    Option,
    allocation_from_options,
    evaluate,
    option_table,
    tie_rank,
)
from catanc.planning.stage1.result import Stage1Result
from catanc.planning.stage1.together import check_cores, respects

MAX_EXHAUSTIVE_ALLOCATIONS = 2_000_000
"""Refuse to enumerate more allocations than this (roughly a minute of scoring)."""


def set_partitions(items: Sequence[str], most_blocks: int | None = None) -> Iterator[list[list[str]]]:
    """Every partition of ``items`` into non-empty blocks, at most ``most_blocks`` of them.

    Each item joins an existing block or opens a new one (restricted growth),
    so partitions with too many blocks are never built: 20 subchains on 4
    cores must not walk Bell(20) = 5e13 partitions to find the few thousand
    that fit.
    """
    blocks: list[list[str]] = []

    def place(index: int) -> Iterator[list[list[str]]]:
        if index == len(items):
            yield [list(block) for block in blocks]
            return
        for block in blocks:
            block.append(items[index])
            yield from place(index + 1)
            block.pop()
        if most_blocks is None or len(blocks) < most_blocks:
            blocks.append([items[index]])
            yield from place(index + 1)
            blocks.pop()

    yield from place(0)


def _spreads(extra: int, bins: int, exact: bool) -> Iterator[tuple[int, ...]]:
    """Ways to add ``extra`` cores (all of them if ``exact``, else up to) to ``bins`` subchains."""
    totals = [extra] if exact else range(extra + 1)
    for total in totals:
        if bins == 0:
            if total == 0:
                yield ()
            continue
        # Stars and bars: choose bins - 1 dividers among total + bins - 1 places.
        for dividers in itertools.combinations(range(total + bins - 1), bins - 1):
            bounds = (-1, *dividers, total + bins - 1)
            yield tuple(b - a - 1 for a, b in itertools.pairwise(bounds))


def _layouts(problem: Problem, cores: int) -> Iterator[tuple[list[str], list[list[str]], tuple[int, ...]]]:
    """Every (dedicated singles, shared groups, extra cores per single) that fits ``cores``."""
    names = [sub.name for sub in problem.subchains]
    every_core_used = len(names) >= cores
    for partition in set_partitions(names, most_blocks=cores):
        singles = [block[0] for block in partition if len(block) == 1]
        groups = [block for block in partition if len(block) > 1]
        extra = cores - len(singles) - len(groups)
        if extra < 0 or not respects(problem, groups):
            continue
        for spread in _spreads(extra, len(singles), exact=every_core_used):
            yield singles, groups, spread


def allocations(problem: Problem, cores: int) -> Iterator[dict[str, Option]]:
    """Every distinct allocation as Stage I sees it: options per subchain (partners do not matter)."""
    names = [sub.name for sub in problem.subchains]
    seen: set[tuple[Option, ...]] = set()
    for singles, groups, spread in _layouts(problem, cores):
        options = {name: Option(False, 1 + more) for name, more in zip(singles, spread, strict=True)}
        options.update({name: Option(True, len(group)) for group in groups for name in group})
        key = tuple(options[name] for name in names)
        if key not in seen:  # partitions that differ only in partners score the same
            seen.add(key)
            yield options


def every_allocation(problem: Problem, cores: int) -> Iterator[Allocation]:
    """Every allocation with its partners: who shares a core with whom matters to Stage II.

    Groups keep spec order inside and are ordered by first member, as
    :func:`~catanc.planning.stage1.estimate.allocation_from_options` orders them, so
    equal allocations compare equal.
    """
    order = {sub.name: index for index, sub in enumerate(problem.subchains)}
    for singles, groups, spread in _layouts(problem, cores):
        dedicated = sorted(
            ((name, 1 + more) for name, more in zip(singles, spread, strict=True)), key=lambda d: order[d[0]]
        )
        shared = sorted((tuple(sorted(group, key=order.__getitem__)) for group in groups), key=lambda g: order[g[0]])
        yield Allocation(tuple(dedicated), tuple(shared))


def solve_exhaustive(problem: Problem, cores: int) -> Stage1Result:
    """The best allocation by scoring every one (exact, for small apps)."""
    check_cores(problem, cores)
    table = option_table(problem, cores)
    names = [sub.name for sub in problem.subchains]
    scored: list[tuple[float, float, float, tuple[Option, ...]]] = []  # scale, objective, tie rank, options
    for count, options in enumerate(allocations(problem, cores)):
        if count >= MAX_EXHAUSTIVE_ALLOCATIONS:
            raise UsageError(f"more than {MAX_EXHAUSTIVE_ALLOCATIONS:,} Stage I allocations to enumerate: use the MILP")
        evaluation = evaluate(problem, table, options)
        key = tuple(options[name] for name in names)
        scored.append((evaluation.scale, evaluation.objective, tie_rank(problem, options, cores), key))
    least_scale = min(entry[0] for entry in scored)
    allowed = least_scale * (1 + SCALE_SLACK) if least_scale > 1 else 1.0
    feasible = [entry for entry in scored if entry[0] <= allowed]
    best_value = min(entry[1] for entry in feasible)
    ties = [entry for entry in feasible if entry[1] <= best_value * (1 + 1e-12) + 1e-12]
    scale, value, _, key = min(ties, key=lambda entry: entry[2])
    return Stage1Result(
        allocation=allocation_from_options(problem, dict(zip(names, key, strict=True))),
        objective=value,
        constraint_scale=scale,
        optimal=True,
        gap=0.0,
        method="exhaustive",
        candidates=len(scored),
    )
