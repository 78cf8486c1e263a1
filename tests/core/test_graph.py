"""DAG paths, selectors and cycles against brute force and networkx on small random graphs."""

from __future__ import annotations

import itertools

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.core import graph

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


@settings(max_examples=150, deadline=None)
@given(
    count=st.integers(1, 6),
    edges=st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5)), max_size=12),
)
def test_cycles_found_exactly_when_not_acyclic(count: int, edges: list[tuple[int, int]]) -> None:
    names = [f"n{i}" for i in range(count)]
    pairs = [(names[a], names[b]) for a, b in edges if a < count and b < count]
    g = graph.build_dag(names, pairs)
    oracle = nx.DiGraph(pairs)
    oracle.add_nodes_from(names)
    cycles = graph.find_cycles(g)
    assert (not cycles) == nx.is_directed_acyclic_graph(oracle)
    for cycle in cycles:
        assert cycle[0] == cycle[-1]
        assert all(g.has_edge(a, b) for a, b in itertools.pairwise(cycle))
        assert len(set(cycle[:-1])) == len(cycle) - 1  # a simple cycle
    # One cycle per cyclic strongly connected component, none shared.
    components = [
        c for c in nx.strongly_connected_components(oracle) if len(c) > 1 or any(oracle.has_edge(n, n) for n in c)
    ]
    assert len(cycles) == len(components)
    for cycle in cycles:  # each is a shortest cycle through its first node, the earliest declared of its component
        start = cycle[0]
        component = next(c for c in components if start in c)
        assert start == min(component, key=names.index)
        sub = oracle.subgraph(component)
        shortest = min(
            (nx.shortest_path_length(sub, start, p) + 1 for p in sub.predecessors(start) if p != start), default=1
        )
        assert len(cycle) - 1 == (1 if oracle.has_edge(start, start) else shortest)


@settings(max_examples=150, deadline=None)
@given(
    count=st.integers(1, 7),
    edges=st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6)), max_size=14),
)
def test_orders_and_reachability_match_networkx(count: int, edges: list[tuple[int, int]]) -> None:
    names = [f"n{i}" for i in reversed(range(count))]  # declaration order differs from the names' order
    pairs = [(names[a], names[b]) for a, b in edges if a < count and b < count]
    g = graph.build_dag(names, pairs)
    oracle = nx.DiGraph(pairs)
    oracle.add_nodes_from(names)
    assert list(g) == names
    for node in names:
        assert set(g.successors(node)) == set(oracle.successors(node))
        assert list(g.successors(node)) == sorted(g.successors(node), key=names.index)
        assert set(g.predecessors(node)) == set(oracle.predecessors(node))
        assert g.ancestors(node) == nx.ancestors(oracle, node) | ({node} if _on_cycle(oracle, node) else set())
        for other in names:
            assert g.has_path(node, other) == nx.has_path(oracle, node, other)
    if nx.is_directed_acyclic_graph(oracle):
        expected = list(nx.lexicographical_topological_sort(oracle, key=names.index))
        assert g.topological_order() == expected
    else:
        assert len(g.topological_order()) < count


def _on_cycle(g: nx.DiGraph, node: str) -> bool:
    return any(nx.has_path(g, child, node) for child in g.successors(node))


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
