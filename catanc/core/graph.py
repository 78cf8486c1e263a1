"""The app DAG: cycles, paths, selectors.

A :class:`Dag` keeps its nodes in the spec's declaration order and every
node's neighbours in that order too, so every enumeration here is
deterministic.  Paths are counted (exactly, by dynamic programming) before
they are listed, so a dense DAG is reported with numbers instead of hanging
the tool.

The graphs are a spec's (tens of nodes), and ``catanc validate`` checks them
on every call: a few dozen lines here cost nothing to import, where
networkx's ~200 ms would be a fifth of the command (tests compare these
functions with networkx's on random graphs).
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

Path = tuple[str, ...]


@dataclass(frozen=True)
class Dag:
    """A directed graph over named nodes (it may hold cycles: :func:`find_cycles` finds them).

    ``order`` is each node's declaration index; ``succ`` and ``pred`` list each node's
    neighbours in declaration order, each once.
    """

    order: dict[str, int]
    succ: dict[str, tuple[str, ...]]
    pred: dict[str, tuple[str, ...]]

    def __iter__(self) -> Iterator[str]:
        return iter(self.order)

    def __contains__(self, node: object) -> bool:
        return node in self.order

    def successors(self, node: str) -> tuple[str, ...]:
        return self.succ[node]

    def predecessors(self, node: str) -> tuple[str, ...]:
        return self.pred[node]

    def has_edge(self, a: str, b: str) -> bool:
        return a in self.succ and b in self.succ[a]

    def topological_order(self) -> list[str]:
        """Kahn's order, taking the earliest-declared ready node first (a cycle's nodes are left out)."""
        waiting = {node: len(self.pred[node]) for node in self.order}
        ready = [(self.order[node], node) for node, count in waiting.items() if count == 0]
        heapq.heapify(ready)
        found: list[str] = []
        while ready:
            _, node = heapq.heappop(ready)
            found.append(node)
            for child in self.succ[node]:
                waiting[child] -= 1
                if waiting[child] == 0:
                    heapq.heappush(ready, (self.order[child], child))
        return found

    def ancestors(self, node: str) -> set[str]:
        """Every node with a path to ``node`` (not ``node`` itself, unless on a cycle through it)."""
        return _reach(node, self.pred)

    def has_path(self, a: str, b: str) -> bool:
        return a == b or b in _reach(a, self.succ)


def _reach(node: str, neighbours: dict[str, tuple[str, ...]]) -> set[str]:
    seen: set[str] = set()
    stack = list(neighbours[node])
    while stack:
        current = stack.pop()
        if current not in seen:
            seen.add(current)
            stack.extend(neighbours[current])
    return seen


def build_dag(nodes: Sequence[str], edges: Iterable[tuple[str, str]]) -> Dag:
    """A graph of the spec's nodes (in declaration order) and edges between them."""
    order = {name: index for index, name in enumerate(nodes)}
    succ: dict[str, set[str]] = {name: set() for name in order}
    pred: dict[str, set[str]] = {name: set() for name in order}
    for a, b in edges:
        succ[a].add(b)
        pred[b].add(a)

    def by_order(names: set[str]) -> tuple[str, ...]:
        return tuple(sorted(names, key=order.__getitem__))

    return Dag(order, {n: by_order(s) for n, s in succ.items()}, {n: by_order(p) for n, p in pred.items()})


def _components(dag: Dag) -> list[list[str]]:
    """The strongly connected components (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    for root in dag:
        if root in index:
            continue
        work: list[tuple[str, Iterator[str]]] = [(root, iter(dag.succ[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(dag.succ[child])))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                found.append(component)
    return found


def find_cycles(dag: Dag) -> list[Path]:
    """One cycle per strongly connected component, as ``(a, b, ..., a)``.

    Each cycle starts at its earliest-declared node, so messages are stable.
    """
    cycles: list[Path] = []
    for component in _components(dag):
        start = min(component, key=dag.order.__getitem__)
        if len(component) == 1 and not dag.has_edge(start, start):
            continue
        cycles.append(_cycle_through(dag, start, set(component)))
    return sorted(cycles, key=lambda c: dag.order[c[0]])


def _cycle_through(dag: Dag, start: str, component: set[str]) -> Path:
    """A shortest cycle from ``start`` back to itself inside ``component`` (ties: earliest-declared first)."""
    if dag.has_edge(start, start):
        return (start, start)
    parent: dict[str, str | None] = {start: None}
    queue = deque([start])
    while queue:  # breadth first, neighbours in declaration order: the first way back is a shortest one
        node = queue.popleft()
        for child in dag.succ[node]:
            if child == start:
                path = [node]
                while (before := parent[path[-1]]) is not None:
                    path.append(before)
                return (*reversed(path), start)
            if child in component and child not in parent:
                parent[child] = node
                queue.append(child)
    raise AssertionError("a non-trivial strongly connected component has a cycle through each node")


def first_missing_edge(dag: Dag, nodes: Sequence[str]) -> tuple[str, str] | None:
    """The first consecutive pair of ``nodes`` that is not a DAG edge, if any."""
    for a, b in itertools.pairwise(nodes):
        if not dag.has_edge(a, b):
            return a, b
    return None


def sources(dag: Dag) -> list[str]:
    return [n for n in dag if not dag.pred[n]]


def sinks(dag: Dag) -> list[str]:
    return [n for n in dag if not dag.succ[n]]


def _segments(
    dag: Dag, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]
) -> list[tuple[list[str], list[str]]] | None:
    """Split a selector into consecutive (starts, ends) segments at its waypoints.

    Waypoints are visited in the DAG's own order; ``None`` when two of them
    cannot both lie on one path.
    """
    position = {node: index for index, node in enumerate(dag.topological_order())}
    waypoints = sorted(set(through), key=position.__getitem__)
    for a, b in itertools.pairwise(waypoints):
        if not dag.has_path(a, b):
            return None
    stops = [list(starts), *[[w] for w in waypoints], list(ends)]
    return list(itertools.pairwise(stops))


def _count_between(dag: Dag, starts: Sequence[str], ends: Sequence[str]) -> int:
    """Number of paths from any of ``starts`` to any of ``ends`` (a one-node path counts)."""
    ways: dict[str, int] = {}
    start_set = set(starts)
    for node in dag.topological_order():
        ways[node] = (1 if node in start_set else 0) + sum(ways[p] for p in dag.predecessors(node))
    return sum(ways[e] for e in set(ends))


def count_paths(dag: Dag, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]) -> int:
    """How many paths start in ``starts``, visit every node of ``through`` and end in ``ends``."""
    segments = _segments(dag, starts, through, ends)
    if segments is None:
        return 0
    total = 1
    for seg_starts, seg_ends in segments:
        total *= _count_between(dag, seg_starts, seg_ends)
        if total == 0:
            return 0
    return total


def _paths_between(dag: Dag, starts: Sequence[str], ends: Sequence[str]) -> Iterator[Path]:
    """Every path from ``starts`` to ``ends``, depth first in declaration order."""
    end_set = set(ends)
    useful = set(end_set)
    for end in end_set:
        useful |= dag.ancestors(end)
    for start in sorted(set(starts), key=dag.order.__getitem__):
        if start not in useful:
            continue
        stack: list[tuple[Path, Iterator[str]]] = [((start,), iter(dag.succ[start]))]
        if start in end_set:
            yield (start,)
        while stack:
            path, children = stack[-1]
            child = next(children, None)
            if child is None:
                stack.pop()
                continue
            if child not in useful:
                continue
            extended = (*path, child)
            if child in end_set:
                yield extended
            stack.append((extended, iter(dag.succ[child])))


def iter_paths(dag: Dag, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]) -> Iterator[Path]:
    """The paths :func:`count_paths` counts, in a deterministic order."""
    segments = _segments(dag, starts, through, ends)
    if segments is None:
        return
    (first_starts, first_ends), *later = segments
    # Later segments are listed in full (each has at most as many paths as the
    # whole selector); the first is streamed so a listing can stop early.
    tails = [list(_paths_between(dag, seg_starts, seg_ends)) for seg_starts, seg_ends in later]
    for head in _paths_between(dag, first_starts, first_ends):
        for combo in itertools.product(*tails):
            joined: list[str] = list(head)
            for piece in combo:
                joined.extend(piece[1:])  # each piece starts where the previous ended
            yield tuple(joined)


def all_chains(dag: Dag, limit: int) -> tuple[list[Path], int]:
    """Up to ``limit`` source-to-sink paths, and how many there are in all."""
    starts, ends = sources(dag), sinks(dag)
    total = count_paths(dag, starts, [], ends)
    return list(itertools.islice(iter_paths(dag, starts, [], ends), limit)), total
