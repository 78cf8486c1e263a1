"""The app DAG: cycles, paths, selectors, through networkx.

A :class:`Dag` is a :class:`networkx.DiGraph` built in the spec's declaration
order (nodes, then each node's edges sorted by its neighbour's declaration
index), so networkx's searches, which follow insertion order, enumerate
deterministically.  Paths are counted (exactly, by dynamic programming over
the topological order) before they are listed, so a dense DAG is reported
with numbers instead of hanging the tool.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import networkx as nx

Path = tuple[str, ...]


@dataclass(frozen=True)
class Dag:
    """A directed graph over named nodes (it may hold cycles: :func:`find_cycles` finds them).

    ``order`` is each node's declaration index; ``graph`` holds the nodes and edges in that order.
    """

    order: dict[str, int]
    graph: nx.DiGraph

    def __iter__(self) -> Iterator[str]:
        return iter(self.order)

    def __contains__(self, node: object) -> bool:
        return node in self.order

    def successors(self, node: str) -> tuple[str, ...]:
        return tuple(self.graph.successors(node))

    def predecessors(self, node: str) -> tuple[str, ...]:
        return tuple(sorted(self.graph.predecessors(node), key=self.order.__getitem__))

    def has_edge(self, a: str, b: str) -> bool:
        return bool(self.graph.has_edge(a, b))

    def topological_order(self) -> list[str]:
        """Kahn's order, taking the earliest-declared ready node first.

        Nodes on a cycle, and every node after one, never become ready: they are left out.
        """
        blocked: set[str] = set()
        for component in nx.strongly_connected_components(self.graph):
            first = next(iter(component))
            if len(component) > 1 or self.graph.has_edge(first, first):
                blocked |= component.union(*(nx.descendants(self.graph, n) for n in component))
        ready = self.graph.subgraph(n for n in self.graph if n not in blocked) if blocked else self.graph
        return list(nx.lexicographical_topological_sort(ready, key=self.order.__getitem__))

    def ancestors(self, node: str) -> set[str]:
        """Every node with a path to ``node`` (not ``node`` itself, unless on a cycle through it)."""
        found: set[str] = nx.ancestors(self.graph, node)
        return found | {node} if _on_cycle(self.graph, node) else found

    def has_path(self, a: str, b: str) -> bool:
        return bool(nx.has_path(self.graph, a, b))


def _on_cycle(graph: nx.DiGraph, node: str) -> bool:
    return graph.has_edge(node, node) or any(nx.has_path(graph, child, node) for child in graph.successors(node))


def build_dag(nodes: Sequence[str], edges: Iterable[tuple[str, str]]) -> Dag:
    """A graph of the spec's nodes (in declaration order) and edges between them."""
    order = {name: index for index, name in enumerate(nodes)}
    graph = nx.DiGraph()
    graph.add_nodes_from(order)
    graph.add_edges_from(sorted(set(edges), key=lambda edge: (order[edge[0]], order[edge[1]])))
    return Dag(order, graph)


def find_cycles(dag: Dag) -> list[Path]:
    """One cycle per strongly connected component, as ``(a, b, ..., a)``.

    Each cycle starts at its earliest-declared node, so messages are stable.
    """
    cycles: list[Path] = []
    for component in nx.strongly_connected_components(dag.graph):
        start = min(component, key=dag.order.__getitem__)
        if len(component) == 1 and not dag.has_edge(start, start):
            continue
        cycles.append(_cycle_through(dag, start, component))
    return sorted(cycles, key=lambda c: dag.order[c[0]])


def _cycle_through(dag: Dag, start: str, component: set[str]) -> Path:
    """A shortest cycle from ``start`` back to itself inside ``component`` (ties: earliest-declared first)."""
    if dag.has_edge(start, start):
        return (start, start)
    inside = dag.graph.subgraph(component)
    # Breadth first from start, neighbours in declaration order: the first node reached that has an edge
    # back to start closes a shortest cycle.
    parent = {start: None, **{child: node for node, child in nx.bfs_edges(inside, start)}}
    closing = next(node for node in parent if inside.has_edge(node, start))
    path = [closing]
    while (before := parent[path[-1]]) is not None:
        path.append(before)
    return (*reversed(path), start)


def first_missing_edge(dag: Dag, nodes: Sequence[str]) -> tuple[str, str] | None:
    """The first consecutive pair of ``nodes`` that is not a DAG edge, if any."""
    for a, b in itertools.pairwise(nodes):
        if not dag.has_edge(a, b):
            return a, b
    return None


def sources(dag: Dag) -> list[str]:
    return [n for n in dag if not dag.graph.in_degree(n)]


def sinks(dag: Dag) -> list[str]:
    return [n for n in dag if not dag.graph.out_degree(n)]


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
        ways[node] = (1 if node in start_set else 0) + sum(ways[p] for p in dag.graph.predecessors(node))
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
    # Only nodes that lead to an end: networkx's search would otherwise walk every dead branch.
    useful = dag.graph.subgraph(end_set.union(*(nx.ancestors(dag.graph, end) for end in end_set)))
    for start in sorted(set(starts) & set(useful), key=dag.order.__getitem__):
        for path in nx.all_simple_paths(useful, start, end_set):
            yield tuple(path)


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
