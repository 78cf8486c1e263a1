"""A comparison of policies as JSON (``--json``, shared with ``catanc bench``) and as tables."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rich.table import Table

from catanc.sim.metrics import NodeResult, PolicyResult


def comparison_payload(results: Sequence[PolicyResult]) -> dict[str, Any]:
    """``{"policies": {"<policy>": {"chains": [...], "nodes": {...}, "cores": [...]}}}``."""
    return {"policies": {result.policy: result.as_dict() for result in results}}


def _cell(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _node_cell(node: NodeResult) -> str:
    promised = "" if node.planned_hz is None else f" of {node.planned_hz:.1f}"
    return f"{_cell(node.rate_hz)}{promised} ({_cell(node.staleness_ms_p95)})"


def comparison_tables(results: Sequence[PolicyResult]) -> list[Table]:
    """Chain response times, node rates and core use, one column per policy."""
    if not results:
        return []
    policies = [result.policy for result in results]
    chains = Table(title="Chain response time, ms: p95 (mean, max)", title_justify="left")
    chains.add_column("chain")
    for policy in policies:
        chains.add_column(policy, justify="right")
    for index, chain in enumerate(results[0].chains):
        label = " -> ".join(chain.nodes) + ("" if chain.named else "  (other path)")
        cells = []
        for result in results:
            response = result.chains[index].response
            cells.append("-" if response is None else f"{response.p95:.1f} ({response.mean:.1f}, {response.max:.1f})")
        chains.add_row(label, *cells)
    # A plan's subchain heads: "measured of promised" (the rate as run: docs/explanation/executor-planning.md), by the
    # plan in force at the end: where re-plans changed a rate on the way, the run's average is between.
    title = "Node rate, Hz: measured [of the last plan's rate as run] (input staleness p95, ms)"
    nodes = Table(title=title, title_justify="left")
    nodes.add_column("node")
    for policy in policies:
        nodes.add_column(policy, justify="right")
    for name in sorted(results[0].nodes):
        row = [_node_cell(r.nodes[name]) for r in results]
        nodes.add_row(name, *row)
    cores = Table(title="Core utilisation", title_justify="left")
    cores.add_column("core")
    for policy in policies:
        cores.add_column(policy, justify="right")
    for core in range(len(results[0].utilisation)):
        cores.add_row(str(core), *[f"{100 * r.utilisation[core]:.1f}%" for r in results])
    return [chains, nodes, cores]
