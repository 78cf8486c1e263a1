"""Seeded random apps for the benchmarks: layered DAGs shaped like robot stacks.

Sensors feed layers of perception and planning subchains that end in one
actuator. The objective weights a few chains heavily (like nav2d's local
chain), many lightly, and every subchain's throughput at least a little;
some subchains have rate caps.
"""

from __future__ import annotations

import itertools
import random
from typing import Any

import yaml

from catanc.model.load import parse_spec
from catanc.spec.language import Spec


def layered_app(subchains: int, seed: int) -> dict[str, Any]:
    """A spec document with ``subchains`` subchains of 1-3 nodes in about sqrt(N) layers."""
    rng = random.Random(seed)
    layer_count = max(2, round(subchains**0.5))
    layers: list[list[str]] = [[] for _ in range(layer_count)]
    nodes: dict[str, Any] = {"imu": {"scheduled": False, "rate_hz": 200}, "actuator": {"scheduled": False}}
    groups: dict[str, list[str]] = {}
    edges: list[list[str]] = []
    for index in range(subchains):
        name = f"s{index}"
        members = [f"{name}n{j}" for j in range(rng.choice([1, 1, 2, 3]))]
        for member in members:
            threads = rng.choice([1, 1, 1, 2, 4])
            node: dict[str, Any] = {"compute_ms": round(rng.lognormvariate(1.5, 1.2), 2) + 0.1}
            if threads > 1:
                node["threads"] = {"max": threads}
            nodes[member] = node
        edges += [[a, b] for a, b in itertools.pairwise(members)]
        groups[name] = members
        layers[index * layer_count // subchains].append(name)
    for upper, lower in itertools.pairwise(layers):
        for name in lower:  # every subchain below the first layer reads one or two from above
            for source in rng.sample(upper, min(len(upper), rng.choice([1, 1, 2]))):
                edges.append([groups[source][-1], groups[name][0]])
    for name in layers[0]:
        edges.append(["imu", groups[name][0]])
    for name in layers[-1]:
        edges.append([groups[name][-1], "actuator"])
    objective: list[dict[str, Any]] = []
    for weight in [1.0, 0.5] + [0.005] * max(1, subchains // 5):
        path = [rng.choice(layers[0])]
        for layer in layers[1:]:
            readers = [n for n in layer if [groups[path[-1]][-1], groups[n][0]] in edges]
            if not readers:
                break
            path.append(rng.choice(readers))
        chain = [node for name in path for node in groups[name]]
        if path[-1] in layers[-1]:
            chain.append("actuator")
        objective.append({"chain": chain, "weight": weight})
    # Every subchain's throughput counts a little (as GM, GP, NC do in nav2d), some a lot.
    heavy = set(rng.sample(list(groups), max(1, subchains // 6)))
    for name in groups:
        weight = rng.choice([0.5, 0.05]) if name in heavy else 0.001
        objective.append({"node": groups[name][0], "weight": weight})
    constraints = [
        {"node": groups[name][0], "max_rate_hz": rng.choice([10, 50, 100])}
        for name in rng.sample(list(groups), max(1, subchains // 8))
    ]
    return {
        "catan": 1,
        "app": f"layered{subchains}",
        "nodes": nodes,
        "edges": edges,
        "subchains": groups,
        "objective": objective,
        "constraints": constraints,
    }


def layered_spec(subchains: int, seed: int) -> Spec:
    return parse_spec(yaml.safe_dump(layered_app(subchains, seed), sort_keys=False), f"layered{subchains}-{seed}.yaml")
