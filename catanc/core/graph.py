"""The app DAG: cycles, paths, selectors (networkx).

Pure functions over a :class:`networkx.DiGraph` whose nodes carry their spec
declaration index as ``order``; every enumeration follows that order, so
results are deterministic.  Paths are counted (exactly, by dynamic
programming) before they are listed, so a dense DAG is reported with numbers
instead of hanging the tool.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence

import networkx as nx

Path = tuple[str, ...]


def build_dag(nodes: Sequence[str], edges: Iterable[tuple[str, str]]) -> nx.DiGraph:
    """A digraph of the spec's nodes (in declaration order) and edges."""
    dag = nx.DiGraph()
    for index, name in enumerate(nodes):
        dag.add_node(name, order=index)
    dag.add_edges_from(edges)
    return dag


def _order(dag: nx.DiGraph, node: str) -> int:
    return int(dag.nodes[node]["order"])


def _successors(dag: nx.DiGraph, node: str) -> list[str]:
    return sorted(dag.successors(node), key=lambda n: _order(dag, n))


def find_cycles(dag: nx.DiGraph) -> list[Path]:
    """One cycle per strongly connected component, as ``(a, b, ..., a)``.

    Each cycle starts at its earliest-declared node, so messages are stable.
    """
    cycles: list[Path] = []
    for component in nx.strongly_connected_components(dag):
        start = min(component, key=lambda n: _order(dag, n))
        if len(component) == 1 and not dag.has_edge(start, start):
            continue
        cycle = _cycle_through(dag, start, component)
        cycles.append(cycle)
    return sorted(cycles, key=lambda c: _order(dag, c[0]))


def _cycle_through(dag: nx.DiGraph, start: str, component: set[str]) -> Path:
    """A shortest cycle from ``start`` back to itself inside ``component``."""
    if dag.has_edge(start, start):
        return (start, start)
    sub = dag.subgraph(component)
    best: list[str] | None = None
    for pred in sorted(sub.predecessors(start), key=lambda n: _order(dag, n)):
        path = nx.shortest_path(sub, start, pred)
        if best is None or len(path) < len(best):
            best = path
    assert best is not None  # a non-trivial SCC has a predecessor of start inside it
    return (*best, start)


def first_missing_edge(dag: nx.DiGraph, nodes: Sequence[str]) -> tuple[str, str] | None:
    """The first consecutive pair of ``nodes`` that is not a DAG edge, if any."""
    for a, b in itertools.pairwise(nodes):
        if not dag.has_edge(a, b):
            return a, b
    return None


def sources(dag: nx.DiGraph) -> list[str]:
    return sorted((n for n in dag if dag.in_degree(n) == 0), key=lambda n: _order(dag, n))


def sinks(dag: nx.DiGraph) -> list[str]:
    return sorted((n for n in dag if dag.out_degree(n) == 0), key=lambda n: _order(dag, n))


def _segments(
    dag: nx.DiGraph, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]
) -> list[tuple[list[str], list[str]]] | None:
    """Split a selector into consecutive (starts, ends) segments at its waypoints.

    Waypoints are visited in the DAG's own order; ``None`` when two of them
    cannot both lie on one path.
    """
    position = {
        node: index for index, node in enumerate(nx.lexicographical_topological_sort(dag, key=lambda n: _order(dag, n)))
    }
    waypoints = sorted(set(through), key=position.__getitem__)
    for a, b in itertools.pairwise(waypoints):
        if not nx.has_path(dag, a, b):
            return None
    stops = [list(starts), *[[w] for w in waypoints], list(ends)]
    return list(itertools.pairwise(stops))


def _count_between(dag: nx.DiGraph, starts: Sequence[str], ends: Sequence[str]) -> int:
    """Number of paths from any of ``starts`` to any of ``ends`` (a one-node path counts)."""
    ways: dict[str, int] = {}
    start_set = set(starts)
    for node in nx.topological_sort(dag):
        ways[node] = (1 if node in start_set else 0) + sum(ways[p] for p in dag.predecessors(node))
    return sum(ways[e] for e in set(ends))


def count_paths(dag: nx.DiGraph, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]) -> int:
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


def _paths_between(dag: nx.DiGraph, starts: Sequence[str], ends: Sequence[str]) -> Iterator[Path]:
    """Every path from ``starts`` to ``ends``, depth first in declaration order."""
    end_set = set(ends)
    useful = set(end_set)
    for end in end_set:
        useful |= nx.ancestors(dag, end)
    for start in sorted(set(starts), key=lambda n: _order(dag, n)):
        if start not in useful:
            continue
        stack: list[tuple[Path, Iterator[str]]] = [((start,), iter(_successors(dag, start)))]
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
            stack.append((extended, iter(_successors(dag, child))))


def iter_paths(dag: nx.DiGraph, starts: Sequence[str], through: Sequence[str], ends: Sequence[str]) -> Iterator[Path]:
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


def all_chains(dag: nx.DiGraph, limit: int) -> tuple[list[Path], int]:
    """Up to ``limit`` source-to-sink paths, and how many there are in all."""
    starts, ends = sources(dag), sinks(dag)
    total = count_paths(dag, starts, [], ends)
    return list(itertools.islice(iter_paths(dag, starts, [], ends), limit)), total
