"""The runtime table's ``plan``: its shape, its bytes, and its numbers recomputed from the JSON alone."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.artifacts.runtime_table import plan_json, plan_payload
from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.model.problem import Problem
from catanc.planning.planner import plan
from catanc.planning.types import Plan
from catanc.spec.language import ChainsTerm, ChainTerm, NodeTerm, Spec
from tests.support.strategies import spec_documents, spec_of

SPECS = Path(__file__).parents[2] / "specs"
EXAMPLES = sorted(path.stem for path in SPECS.glob("*.yaml"))
ROUNDING = 5e-7  # half of the last printed digit of a time (6 decimals)


@cache
def planned(name: str, cores: int) -> tuple[Spec, Problem, Plan]:
    spec = load_spec(SPECS / f"{name}.yaml")
    return spec, build_problem(spec), plan(spec, cores)


# -- an independent reading of the table: section 2 of docs/explanation/model.md over the JSON's numbers


def stage_timings(payload: Mapping[str, Any], chain: Mapping[str, Any]) -> list[tuple[float, float]]:
    """(period, latency) per stage: a subchain's from its row, a clock's (p, p), a batch head's observed period."""
    stages = []
    for index, name in enumerate(chain["subchains"]):
        if name in payload["subchains"]:
            row = payload["subchains"][name]
            period, latency = row["period_ms"], row["latency_ms"]
            if index == 0 and chain["head_period_ms"] is not None:
                period = chain["head_period_ms"]
        else:
            period = latency = payload["clocks"][name]["period_ms"]
        stages.append((period, latency))
    return stages


def response(payload: Mapping[str, Any], chain: Mapping[str, Any]) -> tuple[float, float, float]:
    stages = stage_timings(payload, chain)
    if not stages:
        return 0.0, 0.0, 0.0
    latency = stages[0][1] + sum(p + lat for p, lat in stages[1:])
    period = max(p for p, _ in stages)
    return latency, period, latency + period


def selected(spec: Spec, term: ChainsTerm, nodes: list[str]) -> bool:
    """Does a full DAG path ``nodes`` match the selector? (sources and sinks read off the spec's edges)."""
    heads = {b for _, b in spec.edge_pairs}
    tails = {a for a, _ in spec.edge_pairs}
    selector = term.chains
    starts = nodes[0] == selector.from_ if selector.from_ is not None else nodes[0] not in heads
    ends = nodes[-1] == selector.to if selector.to is not None else nodes[-1] not in tails
    return starts and ends and all(node in nodes for node in selector.through_nodes)


def recomputed_objective(spec: Spec, payload: Mapping[str, Any]) -> tuple[float, float]:
    """The objective from the spec's weights and the JSON's numbers, and how far rounding may move it."""
    total, slack = 0.0, ROUNDING
    chains = payload["chains"]
    for term in spec.objective:
        if isinstance(term, NodeTerm):
            owner = next(row for row in payload["subchains"].values() if term.node in row["nodes"])
            total += term.weight * owner["period_ms"]
            slack += term.weight * ROUNDING
            continue
        if isinstance(term, ChainTerm):
            matched = [chain for chain in chains if chain["nodes"] == term.chain]
            assert len(matched) == 1
        else:
            matched = [chain for chain in chains if selected(spec, term, chain["nodes"])]
            assert matched
        for chain in matched:
            total += term.weight * response(payload, chain)[2]
            slack += term.weight * ROUNDING * (2 * len(chain["subchains"]) + 1)
    return total, slack


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("name", EXAMPLES)
def test_objective_is_recomputed_from_the_printed_numbers(name: str, cores: int) -> None:
    spec, problem, result = planned(name, cores)
    payload = plan_payload(result, problem)
    for chain in payload["chains"]:
        latency, period, total = response(payload, chain)
        assert chain["latency_ms"] == pytest.approx(latency, abs=ROUNDING * 1.01, rel=1e-12)
        assert chain["period_ms"] == pytest.approx(period, abs=ROUNDING * 1.01, rel=1e-12)
        assert chain["response_ms"] == pytest.approx(total, abs=ROUNDING * 1.01, rel=1e-12)
    objective, slack = recomputed_objective(spec, payload)
    assert payload["objective"] == pytest.approx(objective, abs=ROUNDING * 1.01, rel=1e-12)
    # ... and it is the plan's own objective, up to the rounding.
    assert abs(payload["objective"] - result.objective) <= slack + 1e-12 * result.objective


@pytest.mark.parametrize("name", EXAMPLES)
def test_subchain_rows_agree_with_the_plan_and_the_spec(name: str) -> None:
    spec, problem, result = planned(name, 1)
    payload = plan_payload(result, problem)
    assert set(payload["subchains"]) == set(spec.subchains)
    for sub_name, row in payload["subchains"].items():
        chosen = result.subchains[sub_name]
        assert row["nodes"] == spec.subchains[sub_name]
        assert row["period_ms"] == pytest.approx(chosen.period_ms, abs=ROUNDING)
        assert row["latency_ms"] == pytest.approx(chosen.latency_ms, abs=ROUNDING)
        assert row["rate_hz"] == pytest.approx(1000 / row["period_ms"], abs=1e-6)
        if row["shared"]:
            compute = sum(spec.nodes[node].mean_compute_ms for node in spec.subchains[sub_name])
            assert row["slice_ms"] == pytest.approx(row["fraction"] * compute, abs=1e-6)
        else:
            assert row["slice_ms"] is None
    clocks = {n: 1000 / node.rate_hz for n, node in spec.nodes.items() if node.rate_hz is not None}
    assert {n: c["period_ms"] for n, c in payload["clocks"].items()} == pytest.approx(clocks, abs=ROUNDING)


REQUIRED = {
    "plan": {"objective", "constraint_scale", "subchains", "cores", "chains"},
    "subchain": {"nodes", "cores", "shared", "threads", "period_ms", "fraction", "priority"},
    "extra": {"latency_ms", "rate_hz", "slice_ms"},
    "core": {"core", "period_ms", "order"},
    "chain": {"nodes", "subchains", "latency_ms", "period_ms", "response_ms"},
}


def check_shape(payload: Mapping[str, Any], spec: Spec, cores: int) -> None:
    """runtime.json's ``plan`` (docs/reference/runtime-json.md), field by field."""
    assert REQUIRED["plan"] <= set(payload)
    assert isinstance(payload["objective"], float)
    assert payload["constraint_scale"] >= 1.0
    for row in payload["subchains"].values():
        assert REQUIRED["subchain"] | REQUIRED["extra"] <= set(row)
        assert all(isinstance(node, str) and spec.nodes[node].scheduled for node in row["nodes"])
        assert all(isinstance(core, int) and 0 <= core < cores for core in row["cores"])
        assert isinstance(row["shared"], bool)
        assert isinstance(row["threads"], int)
        assert isinstance(row["priority"], int)
        assert row["period_ms"] > 0
        assert row["fraction"] > 0
    for core in payload["cores"]:
        assert set(core) == REQUIRED["core"]
        assert core["period_ms"] > 0
        for name in core["order"]:
            assert payload["subchains"][name]["shared"]
            assert core["core"] in payload["subchains"][name]["cores"]
    for chain in payload["chains"]:
        assert REQUIRED["chain"] <= set(chain)
        assert chain["response_ms"] >= chain["latency_ms"]


@pytest.mark.parametrize("name", EXAMPLES)
def test_shape_and_bytes(name: str) -> None:
    spec, problem, result = planned(name, 2)
    text = plan_json(result, problem, app=spec.app, cores=2)
    check_shape(json.loads(text)["plan"], spec, 2)
    # The same plan gives the same bytes, whatever Problem object describes it.
    assert plan_json(result, build_problem(spec), app=spec.app, cores=2) == text
    assert text.endswith("}\n")
    assert json.dumps(json.loads(text), indent=2, sort_keys=True) + "\n" == text  # sorted keys, fixed layout


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=spec_documents(max_subchains=4), cores=st.integers(1, 2))
def test_random_plans_recompute_from_their_table(document: dict[str, Any], cores: int) -> None:
    spec = spec_of(document)
    problem = build_problem(spec)
    result = plan(spec, cores)
    payload = plan_payload(result, problem)
    check_shape(payload, spec, cores)
    objective, slack = recomputed_objective(spec, payload)
    assert payload["objective"] == pytest.approx(objective, abs=ROUNDING * 1.01, rel=1e-12)
    assert math.isclose(payload["objective"], result.objective, rel_tol=1e-12, abs_tol=slack)
