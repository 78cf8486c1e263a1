"""The comparison tables ``simulate`` and ``bench`` print: a head's rate beside the rate its plan promises."""

from __future__ import annotations

import io

from rich.console import Console

from catanc.sim.comparison import comparison_payload, comparison_tables
from catanc.sim.metrics import NodeResult, PolicyResult


def result(policy: str, nodes: dict[str, NodeResult]) -> PolicyResult:
    return PolicyResult(policy=policy, duration_s=1.0, chains=(), nodes=nodes, utilisation=(0.5,), replans=0)


def test_a_heads_cell_shows_the_rate_its_plan_promises() -> None:
    catan = result("catan", {"GL": NodeResult(38.94, 18.04, 39.19), "LP": NodeResult(106.9, None)})
    baseline = result("baseline", {"GL": NodeResult(46.5, 19.6), "LP": NodeResult(10.0, 2.0)})
    console = Console(file=io.StringIO(), width=200, highlight=False)
    for table in comparison_tables([catan, baseline]):
        console.print(table)
    output = console.file
    assert isinstance(output, io.StringIO)
    lines = output.getvalue().splitlines()
    gl = next(line for line in lines if line.startswith("│ GL "))
    assert " 38.9 of 39.2 (18.0) │ 46.5 (19.6) " in gl
    lp = next(line for line in lines if line.startswith("│ LP "))
    assert " 106.9 (-) │  10.0 (2.0) " in lp
    nodes = comparison_payload([catan, baseline])["policies"]
    assert nodes["catan"]["nodes"]["GL"] == {"rate_hz": 38.94, "staleness_ms_p95": 18.04, "planned_hz": 39.19}
    assert "planned_hz" not in nodes["baseline"]["nodes"]["GL"]
