"""DAG paths, selectors, cycles and orders against brute force on small random graphs (catanc.model.graph is
networkx, so networkx is no oracle here)."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.model import graph

Edges = list[tuple[str, str]]


@st.composite
def dags(draw: st.DrawFn, max_nodes: int = 6) -> tuple[list[str], Edges]:
    """A random DAG: edges only go from a lower to a higher index; names shuffled."""
    count = draw(st.integers(1, max_nodes))
    names = draw(st.permutations([f"n{i}" for i in range(count)]))
    pairs = [(a, b) for a, b in itertools.combinations(range(count), 2)]
    chosen = draw(st.lists(st.sampled_from(pairs), unique=True)) if pairs else []
    return list(names), [(names[a], names[b]) for a, b in chosen]


def brute_force_paths(
    nodes: list[str], edges: Edges, starts: set[str], through: set[str], ends: set[str]
) -> set[tuple[str, ...]]:
    """Every sequence of distinct nodes joined by edges, filtered by the selector."""
    edge_set = set(edges)
    found = set()
    for length in range(1, len(nodes) + 1):
        for seq in itertools.permutations(nodes, length):
            if all(pair in edge_set for pair in itertools.pairwise(seq)) and (
                seq[0] in starts and seq[-1] in ends and through <= set(seq)
            ):
                found.add(seq)
    return found


@settings(max_examples=150, deadline=None)
@given(dag=dags(), data=st.data())
def test_selector_paths_match_brute_force(dag: tuple[list[str], Edges], data: st.DataObject) -> None:
    nodes, edges = dag
    g = graph.build_dag(nodes, edges)
    start = data.draw(st.sampled_from([None, *nodes]))
    end = data.draw(st.sampled_from([None, *nodes]))
    through = data.draw(st.lists(st.sampled_from(nodes), max_size=2, unique=True))
    starts = [start] if start else graph.sources(g)
    ends = [end] if end else graph.sinks(g)
    expected = brute_force_paths(nodes, edges, set(starts), set(through), set(ends))
    listed = list(graph.iter_paths(g, starts, through, ends))
    assert graph.count_paths(g, starts, through, ends) == len(expected)
    assert len(listed) == len(set(listed))
    assert set(listed) == expected
    # Deterministic order: lexicographic by declaration index.
    index = {name: i for i, name in enumerate(nodes)}
    assert listed == sorted(listed, key=lambda path: [index[n] for n in path])


@settings(max_examples=100, deadline=None)
@given(dag=dags())
def test_all_chains_are_source_to_sink(dag: tuple[list[str], Edges]) -> None:
    nodes, edges = dag
    g = graph.build_dag(nodes, edges)
    paths, total = graph.all_chains(g, limit=3)
    expected = brute_force_paths(nodes, edges, set(graph.sources(g)), set(), set(graph.sinks(g)))
    assert total == len(expected)
    assert len(paths) == min(3, total)
    assert set(paths) <= expected


def reachable(names: list[str], pairs: Edges) -> dict[str, set[str]]:
    """Warshall's closure: every node each node reaches by one edge or more."""
    reach = {n: {b for a, b in pairs if a == n} for n in names}
    for via in names:
        for n in names:
            if via in reach[n]:
                reach[n] |= reach[via]
    return reach


def shortest_cycle_length(names: list[str], pairs: Edges, start: str) -> int | None:
    """By brute force: the fewest edges of a closed walk through distinct nodes from ``start`` back to it."""
    edge_set = set(pairs)
    others = [n for n in names if n != start]
    for length in range(len(names)):
        for middle in itertools.permutations(others, length):
            if all(pair in edge_set for pair in itertools.pairwise((start, *middle, start))):
                return length + 1
    return None


@settings(max_examples=150, deadline=None)
@given(
    count=st.integers(1, 6),
    edges=st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5)), max_size=12),
)
def test_cycles_found_exactly_when_not_acyclic(count: int, edges: list[tuple[int, int]]) -> None:
    names = [f"n{i}" for i in range(count)]
    pairs = [(names[a], names[b]) for a, b in edges if a < count and b < count]
    g = graph.build_dag(names, pairs)
    reach = reachable(names, pairs)
    cycles = graph.find_cycles(g)
    assert (not cycles) == all(n not in reach[n] for n in names)
    for cycle in cycles:
        assert cycle[0] == cycle[-1]
        assert all(g.has_edge(a, b) for a, b in itertools.pairwise(cycle))
        assert len(set(cycle[:-1])) == len(cycle) - 1  # a simple cycle
    # One cycle per cyclic strongly connected component (nodes that reach each other), none shared.
    components = {frozenset({n} | {m for m in reach[n] if n in reach[m]}) for n in names if n in reach[n]}
    assert len(cycles) == len(components)
    for cycle in cycles:  # each is a shortest cycle through its first node, the earliest declared of its component
        start = cycle[0]
        component = next(c for c in components if start in c)
        assert start == min(component, key=names.index)
        assert len(cycle) - 1 == shortest_cycle_length(names, pairs, start)


@settings(max_examples=150, deadline=None)
@given(
    count=st.integers(1, 7),
    edges=st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6)), max_size=14),
)
def test_orders_and_reachability_match_brute_force(count: int, edges: list[tuple[int, int]]) -> None:
    names = [f"n{i}" for i in reversed(range(count))]  # declaration order differs from the names' order
    pairs = [(names[a], names[b]) for a, b in edges if a < count and b < count]
    g = graph.build_dag(names, pairs)
    reach = reachable(names, pairs)
    assert list(g) == names
    for node in names:
        assert set(g.successors(node)) == {b for a, b in pairs if a == node}
        assert list(g.successors(node)) == sorted(g.successors(node), key=names.index)
        assert set(g.predecessors(node)) == {a for a, b in pairs if b == node}
        assert list(g.predecessors(node)) == sorted(g.predecessors(node), key=names.index)
        assert g.ancestors(node) == {n for n in names if node in reach[n]}
        for other in names:
            assert g.has_path(node, other) == (node == other or other in reach[node])
    # Kahn's order with the earliest-declared ready node first is the least topological order by declaration
    # index; a node on a cycle or after one never becomes ready.
    blocked = {n for n in names if any(c in reach[c] and (c == n or n in reach[c]) for c in names)}
    ready = [n for n in names if n not in blocked]
    orders = (
        order
        for order in itertools.permutations(ready)
        if all(order.index(a) < order.index(b) for a, b in pairs if a in ready and b in ready)
    )
    assert g.topological_order() == list(min(orders, key=lambda order: [names.index(n) for n in order]))


def test_dense_dag_is_counted_not_enumerated() -> None:
    # 40 layers of 4 fully connected nodes: 4**40 paths. Counting must be exact and
    # listing a few must stop early (walking every path would never finish).
    layers = [[f"l{i}_{j}" for j in range(4)] for i in range(40)]
    edges = [(a, b) for upper, lower in itertools.pairwise(layers) for a in upper for b in lower]
    g = graph.build_dag([n for layer in layers for n in layer], edges)
    paths, total = graph.all_chains(g, limit=5)
    assert total == 4**40
    assert paths[0] == tuple(layer[0] for layer in layers)
    assert len(paths) == 5


def test_first_missing_edge() -> None:
    g = graph.build_dag(["a", "b", "c"], [("a", "b")])
    assert graph.first_missing_edge(g, ["a", "b"]) is None
    assert graph.first_missing_edge(g, ["a", "b", "c"]) == ("b", "c")
    assert graph.first_missing_edge(g, ["a"]) is None
