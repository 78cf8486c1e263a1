"""Hypothesis strategies for random apps (shared by the solver tests)."""

from __future__ import annotations

import itertools
from typing import Any

from hypothesis import strategies as st

from catanc.model.load import check_text, parse_spec
from catanc.model.problem import Problem
from catanc.spec.language import Spec


@st.composite
def spec_documents(
    draw: st.DrawFn,
    max_subchains: int = 7,
    with_bounds: bool = True,
    max_threads: int = 3,
    *,
    with_executors: bool = False,
    fixed_rates: bool = False,
) -> dict[str, Any]:
    """A random app: a layered DAG of subchains (1-3 nodes each), terms, caps and bounds (and executors,
    fixed rates)."""
    count = draw(st.integers(1, max_subchains))
    subchains: dict[str, list[str]] = {}
    nodes: dict[str, Any] = {}
    for s in range(count):
        length = draw(st.integers(1, 3))
        members = [f"s{s}n{j}" for j in range(length)]
        subchains[f"s{s}"] = members
        for name in members:
            node: dict[str, Any] = {"compute_ms": draw(st.floats(0.5, 50, allow_nan=False).map(lambda v: round(v, 2)))}
            threads = draw(st.integers(1, max_threads))
            if threads > 1:
                gains = draw(st.lists(st.floats(0.0, 1.0), min_size=threads - 1, max_size=threads - 1))
                speedup = [1.0]
                for gain in gains:
                    speedup.append(round(speedup[-1] + gain, 3))
                node["threads"] = {"max": threads, "speedup": speedup}
            nodes[name] = node
    edges = [[a, b] for members in subchains.values() for a, b in itertools.pairwise(members)]
    # Edges between subchains: from a subchain's last node to a later subchain's first node.
    names = list(subchains)
    for a, b in itertools.combinations(range(count), 2):
        if draw(st.booleans()):
            edges.append([subchains[names[a]][-1], subchains[names[b]][0]])
    clock = draw(st.booleans())
    if clock:
        nodes["clock"] = {"scheduled": False, "rate_hz": draw(st.sampled_from([10, 50, 200]))}
        edges.append(["clock", subchains[names[0]][0]])
    nodes["sink"] = {"scheduled": False}
    edges.append([subchains[names[-1]][-1], "sink"])
    objective: list[dict[str, Any]] = [{"chains": {"to": "sink"}, "weight": draw(st.floats(0.01, 1.0))}]
    for name in draw(st.lists(st.sampled_from(names), max_size=3, unique=True)):
        objective.append({"node": subchains[name][0], "weight": draw(st.floats(0.0, 1.0))})
    if draw(st.booleans()):
        objective.append({"chains": {"from": subchains[names[0]][0]}, "weight": draw(st.floats(0.0, 0.5))})
    constraints: list[dict[str, Any]] = []
    capped = draw(st.lists(st.sampled_from(names), max_size=2, unique=True))
    for name in capped:
        constraints.append({"node": subchains[name][0], "max_rate_hz": draw(st.sampled_from([5, 20, 100, 500]))})
    if with_bounds and draw(st.booleans()):
        constraints.append({"chains": {"to": "sink"}, "max_response_ms": draw(st.floats(5, 2000))})
    fixable = [name for name in names if name not in capped]
    if fixed_rates:  # up to two: on one core they may have no common T (then the least scale)
        for name in draw(st.lists(st.sampled_from(fixable), max_size=2, unique=True)) if fixable else []:
            constraints.append({"node": subchains[name][0], "rate_hz": draw(st.sampled_from([20, 50, 120]))})
            capped.append(name)
    floorable = [name for name in names if name not in capped]
    if with_bounds and floorable and draw(st.booleans()):
        name = draw(st.sampled_from(floorable))
        constraints.append({"node": subchains[name][0], "min_rate_hz": draw(st.sampled_from([1, 10, 40]))})
    document = {
        "catan": 1,
        "app": "random",
        "nodes": nodes,
        "edges": edges,
        "subchains": subchains,
        "objective": objective,
        "constraints": constraints,
    }
    if with_executors:
        scheduled = [node for members in subchains.values() for node in members]
        chosen = draw(st.lists(st.sampled_from(scheduled), min_size=0, max_size=min(6, len(scheduled)), unique=True))
        executors: dict[str, list[str]] = {}
        while len(chosen) >= 2:  # disjoint executors of 2-3 nodes
            size = min(len(chosen), draw(st.integers(2, 3)))
            executors[f"e{len(executors)}"], chosen = chosen[:size], chosen[size:]
        if executors:
            document["executors"] = executors
    return document


def spec_text(document: dict[str, Any]) -> str:
    """The document as a spec file: ``yaml.safe_dump``'s text, written by libyaml's emitter where PyYAML has it
    (the same text, ~4x faster; the spec's own loader then reads it as any file)."""
    import yaml

    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return str(yaml.dump(document, Dumper=dumper, sort_keys=False))


def spec_of(document: dict[str, Any]) -> Spec:
    return parse_spec(spec_text(document), "random.yaml")


@st.composite
def problems(draw: st.DrawFn, max_subchains: int = 7, with_bounds: bool = True) -> Problem:
    _, problem = check_text(spec_text(draw(spec_documents(max_subchains, with_bounds))), "random.yaml")
    return problem  # the problem the check built: building it again would give the same
