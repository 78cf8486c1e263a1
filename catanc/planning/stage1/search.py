"""A deterministic local search over Stage I allocations: the MILP's first incumbent.

Large apps give HiGHS a tight bound quickly but a good solution late, so the
MILP starts from this search's answer and, if its time limit strikes first,
returns it with the MILP's proven gap.  Moves keep the allocation valid (every
core used while ``N >= K``): move a subchain between groups, promote one to a
core of its own or demote it into a group, shift a core between dedicated
subchains, swap a dedicated and a shared subchain, merge or split groups.
Every candidate is scored exactly by :func:`catanc.planning.stage1.estimate.evaluate`;
the search is bounded by a count of evaluations, not by time, so it gives the
same answer on every machine.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

from catanc.model.problem import Problem
from catanc.planning.stage1.estimate import Option, OptionTable, evaluate
from catanc.planning.stage1.together import respects

MAX_EVALUATIONS = 6_000


@dataclass
class _State:
    dedicated: dict[str, int] = field(default_factory=dict)
    groups: list[list[str]] = field(default_factory=list)

    def copy(self) -> _State:
        return _State(dict(self.dedicated), [list(g) for g in self.groups])

    def options(self) -> dict[str, Option]:
        found = {name: Option(False, k) for name, k in self.dedicated.items()}
        found.update({name: Option(True, len(g)) for g in self.groups for name in g})
        return found

    def normalise(self) -> _State:
        """A group of one is a subchain on one core of its own; empty groups vanish."""
        kept = []
        for group in self.groups:
            if len(group) == 1:
                self.dedicated[group[0]] = 1
            elif group:
                kept.append(group)
        self.groups = kept
        return self


def local_search(
    problem: Problem,
    table: OptionTable,
    cores: int,
    start: Mapping[str, Mapping[Option, float]] | None = None,
    budget: int = MAX_EVALUATIONS,
) -> dict[str, Option]:
    """A good allocation, as options per subchain (not necessarily optimal).

    ``start`` weighs each subchain's options (an LP relaxation's values):
    each subchain is rounded to its heaviest option and the result repaired
    into a valid allocation.  Without it, everything starts in one group.
    """
    names = [sub.name for sub in problem.subchains]
    left = [budget]

    def score(state: _State) -> tuple[float, float]:
        left[0] -= 1
        options = state.options()
        if any(option not in table[name] for name, option in options.items()):
            return (math.inf, math.inf)  # a step on the way, not an allocation (a group too big)
        if not respects(problem, state.groups):
            return (math.inf, math.inf)  # an executor's subchains apart: a step on the way
        evaluation = evaluate(problem, table, options)
        return (evaluation.scale, evaluation.objective)  # meet the bounds first, then optimise

    state = _rounded(names, start) if start is not None else _State(groups=[list(names)]).normalise()
    must_use = len(names) >= cores
    best = score(state)
    while True:  # match the number of cores: fewer if over, more if under
        used = sum(state.dedicated.values()) + len(state.groups)
        if used > cores:
            candidates = list(_shrink(state))
        elif used < cores:
            candidates = list(_grow(state))
        else:
            break
        if not candidates:
            break
        value, index = min((score(c), index) for index, c in enumerate(candidates))
        if used < cores and not must_use and value >= best:
            break  # with fewer subchains than cores, idle cores are allowed
        best, state = value, candidates[index]
    improved = True
    while improved and left[0] > 0:  # then first-improvement local search
        improved = False
        for candidate in _neighbours(state):
            if left[0] <= 0:
                break
            value = score(candidate)
            if value < best:
                best, state, improved = value, candidate, True
                break
    return state.options()


def _rounded(names: list[str], weights: Mapping[str, Mapping[Option, float]]) -> _State:
    """Each subchain on its heaviest option; shared subchains chunked into groups of their size."""
    state = _State()
    sharing: dict[int, list[tuple[float, str]]] = {}
    for name in names:
        option, weight = max(weights[name].items(), key=lambda item: (item[1], item[0]))
        if option.shared:
            sharing.setdefault(option.size, []).append((-weight, name))
        else:
            state.dedicated[name] = option.size
    for size in sorted(sharing, reverse=True):
        members = [name for _, name in sorted(sharing[size])]
        groups = [members[i : i + size] for i in range(0, len(members), size)]
        if len(groups) > 1 and len(groups[-1]) < size:
            groups[-2].extend(groups.pop())  # a short last group joins the one before
        state.groups.extend(groups)
    return state.normalise()


def _shrink(state: _State) -> Iterator[_State]:
    """Ways to free one core."""
    for name, k in state.dedicated.items():
        if k >= 2:
            new = state.copy()
            new.dedicated[name] -= 1
            yield new
        else:
            for b in range(len(state.groups)):
                new = state.copy()
                del new.dedicated[name]
                new.groups[b].append(name)
                yield new
            others = [other for other, j in state.dedicated.items() if other != name and j == 1]
            if others:  # two single-core subchains start sharing one core
                new = state.copy()
                del new.dedicated[name], new.dedicated[others[0]]
                new.groups.append([name, others[0]])
                yield new
    for a in range(len(state.groups)):
        for b in range(a + 1, len(state.groups)):
            new = state.copy()
            new.groups[a].extend(new.groups[b])
            del new.groups[b]
            yield new


def _grow(state: _State) -> Iterator[_State]:
    """Ways to put one more core to use."""
    for group_index, group in enumerate(state.groups):
        for name in group:  # promote a shared subchain onto the new core
            new = state.copy()
            new.groups[group_index].remove(name)
            new.dedicated[name] = 1
            yield new.normalise()
        if len(group) >= 4:  # or split the group in two
            new = state.copy()
            new.groups[group_index] = group[::2]
            new.groups.append(group[1::2])
            yield new.normalise()
    for name in state.dedicated:  # or give it to a dedicated subchain
        new = state.copy()
        new.dedicated[name] += 1
        yield new


def _neighbours(state: _State) -> Iterator[_State]:
    groups, dedicated = state.groups, state.dedicated
    donors = [name for name, k in dedicated.items() if k >= 2]
    for a, group in enumerate(groups):
        for name in group:
            for b in range(len(groups)):  # move between groups
                if b != a:
                    new = state.copy()
                    new.groups[a].remove(name)
                    new.groups[b].append(name)
                    yield new.normalise()
            for donor in donors:  # promote, taking a core from a dedicated subchain
                new = state.copy()
                new.groups[a].remove(name)
                new.dedicated[donor] -= 1
                new.dedicated[name] = 1
                yield new.normalise()
            for other, k in dedicated.items():  # swap roles with a dedicated subchain
                new = state.copy()
                new.groups[a][new.groups[a].index(name)] = other
                del new.dedicated[other]
                new.dedicated[name] = k
                yield new.normalise()
    for name, k in dedicated.items():
        for other in dedicated:  # shift one core
            if other != name and k >= 2:
                new = state.copy()
                new.dedicated[name] -= 1
                new.dedicated[other] += 1
                yield new
        if k == 1:
            for b in range(len(groups)):  # demote into a group; its core goes to another
                for other in dedicated:
                    if other != name:
                        new = state.copy()
                        del new.dedicated[name]
                        new.groups[b].append(name)
                        new.dedicated[other] += 1
                        yield new.normalise()
    for a in range(len(groups)):  # merge two groups; the freed core goes to a dedicated subchain
        for b in range(a + 1, len(groups)):
            for other in dedicated:
                new = state.copy()
                new.groups[a].extend(new.groups[b])
                del new.groups[b]
                new.dedicated[other] += 1
                yield new.normalise()
