"""Chains measured from origins (issue 46): ``catanc report``'s chain table and JSON, ``catanc profile --check``.

Each ``compute`` sample's ``age_ms`` is its run's end less the run's origin; a chain's response is the age of
its last scheduled node's runs (catanc.control.run_summary).  Logs are made by hand with known ages; the
percentiles are worked by hand (linear interpolation between closest ranks).
"""

from __future__ import annotations

import io
import json
from typing import Any

import pytest
from rich.console import Console

from catanc.control.run_summary import Quantiles, chain_response, summarise
from catanc.runtime.logs.report import render_summary, summary_payload
from catanc.runtime.profile.propose import MIN_SAMPLES, profile_spec
from tests.support.run_logs import SPEC, every_node, log_text

PLAN: dict[str, Any] = {
    "objective": 1.0,
    "subchains": {"main": {"cores": [0], "shared": False, "period_ms": 20.0}},
    "chains": [
        # the whole chain: ages at its last scheduled node, plan
        {
            "nodes": ["cam", "det", "plan", "motor"],
            "last_scheduled": "plan",
            "response_ms": 30.0,
            "max_response_ms": 40.0,
        },
        # det reports no ages: measured at cam, the node before it that does (part of the chain)
        {"nodes": ["cam", "det"], "last_scheduled": "det", "response_ms": 12.0, "max_response_ms": None},
        # nothing of it reports ages
        {"nodes": ["x", "y"], "last_scheduled": "y", "response_ms": 5.0, "max_response_ms": None},
    ],
}


def compute(t: float, node: str, age: float | None) -> dict[str, Any]:
    return {"t": t, "event": "compute", "node": node, "ms": 1.0, "age_ms": age}


def events() -> list[dict[str, Any]]:
    stale = {**PLAN, "chains": [{**PLAN["chains"][0], "response_ms": 99.0}]}
    found: list[dict[str, Any]] = [{"t": 0.0, "event": "start", "format": 1, "cores": 1, "plan": stale}]
    found += [compute(1.0 + i / 100, "plan", 10.0 + i) for i in range(10)]  # 10, 11, ..., 19 ms
    found += [compute(1.0, "cam", age) for age in (3.0, 1.0, 2.0)]
    found += [compute(1.5, "det", None), compute(1.6, "det", -1.0)]  # no origin; a bad age is skipped
    found.append({"t": 2.0, "event": "resolve", "reason": "stage2", "plan": PLAN})  # the last plan's chains count
    found.append({"t": 3.0, "event": "stop", "summary": {}})
    return found


def figures(response: Quantiles | None) -> tuple[float, ...]:
    assert response is not None
    return (response.count, response.p50_ms, response.p95_ms, response.max_ms)


def test_a_chains_response_is_the_age_of_its_last_scheduled_nodes_runs() -> None:
    chains = summarise(events()).chains
    assert [chain.nodes for chain in chains] == [("cam", "det", "plan", "motor"), ("cam", "det"), ("x", "y")]
    whole, part, none = chains
    # 10..19: p50 halfway between ranks 4 and 5 (14.5); p95 at rank 0.95 * 9 = 8.55: 18 + 0.55.
    assert (whole.at, whole.whole, whole.planned_ms, whole.bound_ms) == ("plan", True, 30.0, 40.0)
    assert figures(whole.response) == pytest.approx((10, 14.5, 18.55, 19.0))
    # cam's 1, 2, 3: p50 2, p95 at rank 1.9: 2 + 0.9.
    assert (part.at, part.whole) == ("cam", False)
    assert figures(part.response) == pytest.approx((3, 2.0, 2.9, 3.0))
    assert (none.at, none.response) == (None, None)


def test_a_chain_past_its_last_scheduled_node_is_not_measured_there() -> None:
    ages = {"a": [1.0], "b": [2.0], "c": [3.0]}
    assert chain_response(["a", "b", "c"], "b", ages) == ("b", True, Quantiles(1, 2.0, 2.0, 2.0))
    assert chain_response(["a", "b", "c"], None, ages) == (None, False, None)


def test_report_shows_each_chain_beside_the_plans_response_and_in_json() -> None:
    summary = summarise(events())
    payload = json.loads(json.dumps(summary_payload(summary)))
    assert payload["chains"][0] == {
        "nodes": ["cam", "det", "plan", "motor"],
        "planned_ms": 30.0,
        "max_response_ms": 40.0,
        "measured_at": "plan",
        "whole_chain": True,
        "measured_ms": {"count": 10, "p50": 14.5, "p95": 18.55, "max": 19.0},
    }
    assert payload["chains"][1]["measured_at"] == "cam"
    assert payload["chains"][1]["whole_chain"] is False
    assert payload["chains"][2]["measured_ms"] is None
    out = io.StringIO()
    console = Console(file=out, width=200, highlight=False)
    for table in render_summary(summary):
        console.print(table)
    text = out.getvalue()
    assert "chains: response from origins (ms)" in text
    row = next(line for line in text.splitlines() if "cam -> det -> plan -> motor" in line)
    assert [cell.strip() for cell in row.split("│")[2:9]] == [
        "plan",
        "10",
        "14.500",
        "18.550",
        "19.000",
        "30.000",
        "40.000",
    ]
    assert "cam (part of it)" in text


BOUNDED = SPEC.replace(
    "objective:\n", "constraints:\n  - {chain: [cam, det, plan, motor], max_response_ms: 40}\nobjective:\n"
)


def _chain_off(ages: dict[str, list[float]]) -> list[str]:
    result = profile_spec(BOUNDED, "demo.yaml", log_text(*every_node(), ages=ages), "run.jsonl", tolerance=10.0)
    return [line for line in result.off if "chain" in line]


def test_profile_check_fails_where_a_bounded_chains_p95_from_origins_is_over_its_bound() -> None:
    # 20 runs at plan, 30, 31, ..., 49 ms: p95 at rank 0.95 * 19 = 18.05: 48.05 ms > 40.
    over = _chain_off({"plan": [30.0 + i for i in range(20)]})
    assert over == [
        "demo.yaml:13:5: constraints[0]: chain cam -> det -> plan -> motor: p95 48.05 ms from origins "
        "(at plan, 20 runs) over its max_response_ms 40"
    ]
    # 20, ..., 39: p95 38.05, within (the maximum, 39, too).
    assert _chain_off({"plan": [20.0 + i for i in range(20)]}) == []
    # One run at 90 ms among 19 at 20: the p95 (rank 18.05, 20 + 0.05 * 70 = 23.5) holds; a maximum would not.
    assert _chain_off({"plan": [20.0] * 19 + [90.0]}) == []
    # Too few runs to say.
    assert _chain_off({"plan": [90.0] * (MIN_SAMPLES - 1)}) == []


def test_a_chain_measured_only_part_way_fails_only_when_even_that_part_is_over() -> None:
    assert _chain_off({"det": [10.0] * 20}) == []
    (line,) = _chain_off({"det": [45.0] * 20})
    assert "at det, 20 runs, part of the chain: its last scheduled node reports no origins" in line
