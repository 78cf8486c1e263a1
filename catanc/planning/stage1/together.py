"""Subchains that must share one core: Stage I's executor constraint (docs/explanation/model.md section 6).

Nodes of one single-threaded executor run in one thread, so they get one
core set and never overlap.  Where an executor's nodes span several
subchains, those subchains (a *unit*, :attr:`catanc.model.problem.Problem.together`)
must sit in one shared group: the group's slots run one after the other.
Stage I's estimate depends only on each subchain's option, so an allocation
is valid when its groups can be formed with every unit inside one group;
:func:`pack_groups` forms them (exactly, by backtracking: a core holds few
subchains).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Protocol

from catanc.errors import InfeasibleError
from catanc.model.problem import Problem


class Option(Protocol):
    """:class:`catanc.planning.stage1.estimate.Option` as this module reads it (estimate imports this module)."""

    @property
    def shared(self) -> bool: ...

    @property
    def size(self) -> int: ...


def respects(problem: Problem, groups: Iterable[Sequence[str]]) -> bool:
    """Whether every unit lies inside one of ``groups`` (shared groups; dedicated subchains are not in any)."""
    units = problem.together
    if not units:
        return True
    home = {name: index for index, group in enumerate(groups) for name in group}
    return all(unit[0] in home and all(home.get(name) == home[unit[0]] for name in unit) for unit in units)


def options_allowed(problem: Problem, options: Mapping[str, Option]) -> bool:
    """Whether some grouping of these options keeps every unit together."""
    if not problem.together:
        return True
    return pack_groups(problem, options) is not None


def pack_groups(problem: Problem, options: Mapping[str, Option]) -> list[tuple[str, ...]] | None:
    """Shared groups for these options with every unit inside one group, or ``None`` if none exist.

    Per group size ``m``: the items (units, and other subchains alone) in spec
    order of their first member go first-fit into groups of exactly ``m``,
    backtracking where an item does not fit.  Without units this is the
    canonical grouping (the first ``m`` sharers together, then the next).
    """
    order = {sub.name: index for index, sub in enumerate(problem.subchains)}
    unit_of = {name: unit for unit in problem.together for name in unit}
    by_size: dict[int, list[str]] = {}
    for sub in problem.subchains:
        option = options[sub.name]
        if option.shared:
            by_size.setdefault(option.size, []).append(sub.name)
        elif sub.name in unit_of:
            return None  # a unit member on cores of its own
    groups: list[tuple[str, ...]] = []
    for size, names in by_size.items():
        items: list[tuple[str, ...]] = []
        for name in names:
            unit = unit_of.get(name, (name,))
            if unit[0] == name:
                items.append(unit)
            if any(not options[member].shared or options[member].size != size for member in unit):
                return None  # a unit split across group sizes
        packed = _first_fit(items, size, len(names) // size) if len(names) % size == 0 else None
        if packed is None:
            return None
        groups.extend(tuple(sorted(group, key=order.__getitem__)) for group in packed)
    groups.sort(key=lambda group: order[group[0]])
    return groups


def _first_fit(items: list[tuple[str, ...]], size: int, count: int) -> list[list[str]] | None:
    """``items`` into ``count`` groups of exactly ``size`` members, first fit with backtracking."""
    groups: list[list[str]] = [[] for _ in range(count)]

    def place(index: int) -> bool:
        if index == len(items):
            return True
        item = items[index]
        tried_empty = False
        for group in groups:
            if len(group) + len(item) > size or (not group and tried_empty):
                continue  # empty groups are alike: trying one is enough
            tried_empty = tried_empty or not group
            group.extend(item)
            if place(index + 1):
                return True
            del group[len(group) - len(item) :]
        return False

    return groups if place(0) else None


def check_cores(problem: Problem, cores: int) -> None:
    """Raise :class:`InfeasibleError` when ``cores`` cannot all be used with every unit on one core.

    With at least as many subchains as cores every core must run one; a unit
    fills one core, and only subchains outside units can take the rest.
    """
    units = problem.together
    if not units or len(problem.subchains) < cores:
        return
    free = [sub.name for sub in problem.subchains if not any(sub.name in unit for unit in units)]
    if free or len(units) >= cores:
        return
    bound = [executor for executor in problem.executors if len(executor.subchains) >= 2]
    first = bound[0]
    where = f"{first.where}: {first.field_name}: " if first.where else f"{first.field_name}: "
    reasons = "; ".join(
        f"{'process' if e.process is not None and e.name == e.process else 'executor'} {e.name!r} runs "
        f"{', '.join(e.nodes)} in one thread (subchains {', '.join(e.subchains)})"
        for e in bound
    )
    most = len(units)
    raise InfeasibleError(
        f"{where}on {cores} cores every core must run a subchain, but all {len(problem.subchains)} subchains "
        f"must fit on {most} core{'s' if most > 1 else ''}: {reasons}; plan for at most {most} "
        f"core{'s' if most > 1 else ''}, or add a subchain outside the executors"
    )
