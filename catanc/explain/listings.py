"""Human-readable views of a spec's chains (``catanc chains``).

:func:`chain_listing` is pure data; :func:`chains_table` renders it with rich.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from rich.table import Table

from catanc.errors import Diagnostic, format_path
from catanc.model import graph
from catanc.model.build import collapse, spec_dag
from catanc.model.problem import Chain, Problem
from catanc.planning.stage1 import Stage1Result
from catanc.planning.stage1.estimate import option_table
from catanc.spec.language import Spec
from catanc.text import plural

DEFAULT_CHAIN_LIMIT = 10_000


@dataclass(frozen=True)
class ChainRow:
    nodes: tuple[str, ...]
    stages: tuple[str, ...]  # subchain names; an unscheduled clock as ``odom@50Hz``
    uses: tuple[str, ...]  # e.g. ``objective[0] w=1`` or ``constraints[3] R<=25ms``
    source_to_sink: bool


@dataclass(frozen=True)
class ChainListing:
    rows: tuple[ChainRow, ...]
    total_paths: int  # source-to-sink paths in the DAG, listed or not
    warnings: tuple[Diagnostic, ...] = field(default=())


def _stage_labels(spec: Spec, chain: Chain) -> tuple[str, ...]:
    labels = []
    for stage in chain.stages:
        if stage.fixed:
            rate = spec.nodes[stage.name].rate_hz
            labels.append(f"{stage.name}@{rate:g}Hz")
        else:
            labels.append(stage.name)
    return tuple(labels)


def chain_listing(spec: Spec, problem: Problem, limit: int = DEFAULT_CHAIN_LIMIT) -> ChainListing:
    """Every source-to-sink chain (up to ``limit``), then the sub-paths the spec names."""
    uses: dict[tuple[str, ...], list[str]] = {}
    for term in problem.response_terms:
        uses.setdefault(problem.chains[term.chain].nodes, []).append(f"{format_path(term.origin)} w={term.weight:g}")
    for bound in problem.response_bounds:
        uses.setdefault(problem.chains[bound.chain].nodes, []).append(
            f"{format_path(bound.origin)} R<={bound.max_response_ms:g}ms"
        )
    membership = {node: sub.name for sub in problem.subchains for node in sub.nodes}
    paths, total = graph.all_chains(spec_dag(spec), limit)
    listed = set(paths)
    named = [chain.nodes for chain in problem.chains if chain.nodes not in listed]
    rows = []
    for nodes in [*paths, *named]:
        chain = Chain(nodes, collapse(nodes, spec, membership))
        rows.append(ChainRow(nodes, _stage_labels(spec, chain), tuple(uses.get(nodes, ())), nodes in listed))
    warnings = []
    if total > limit:
        warnings.append(
            Diagnostic(
                None,
                "edges",
                f"the DAG has {total:,} source-to-sink paths; listing the first {limit:,} "
                "(a dense DAG: name the chains that matter in the objective instead)",
            )
        )
    return ChainListing(tuple(rows), total, tuple(warnings))


def chains_table(listing: ChainListing, title: str) -> Table:
    table = Table(title=title, title_justify="left")
    table.add_column("#", justify="right")
    table.add_column("chain")
    table.add_column("subchains")
    table.add_column("used by")
    for index, row in enumerate(listing.rows):
        chain = " -> ".join(row.nodes) + ("" if row.source_to_sink else "  (sub-path)")
        table.add_row(str(index), chain, " -> ".join(row.stages) or "-", "\n".join(row.uses) or "-")
    return table


def allocation_payload(problem: Problem, result: Stage1Result, cores: int) -> dict[str, Any]:
    """Stage I's answer as plain data (``catanc allocate --json``)."""
    table = option_table(problem, cores)
    options = result.allocation.options()
    indices = result.allocation.core_indices()
    subchains = {}
    for sub in problem.subchains:
        option = options[sub.name]
        timing = table[sub.name][option]
        subchains[sub.name] = {
            "cores": list(indices[sub.name]),
            "shared": option.shared,
            "group_size" if option.shared else "dedicated_cores": option.size,
            "period_ms": round(timing.period_ms, 6),
            "latency_ms": round(timing.latency_ms, 6),
        }
    return {
        "cores": cores,
        "cores_used": result.allocation.cores_used,
        "method": result.method,
        "optimal": result.optimal,
        "gap": result.gap,
        "objective": round(result.objective, 6),
        "constraint_scale": round(result.constraint_scale, 6),
        "subchains": subchains,
    }


def allocation_table(problem: Problem, result: Stage1Result, cores: int) -> Table:
    payload = allocation_payload(problem, result, cores)
    status = "optimal" if result.optimal else f"not proven optimal (gap {_gap_text(result.gap)})"
    title = (
        f"Stage I on {plural(cores, 'core')}: objective {result.objective:.4g} ms "
        f"(estimate), {status}, by {result.method}"
    )
    table = Table(title=title, title_justify="left")
    for column in ("subchain", "cores", "how", "period ms", "latency ms"):
        table.add_column(column, justify="right" if "ms" in column else "left")
    for name, row in payload["subchains"].items():
        how = f"shared by {row['group_size']}" if row["shared"] else f"{row['dedicated_cores']} of its own"
        cores_text = ",".join(str(c) for c in row["cores"])
        table.add_row(name, cores_text, how, f"{row['period_ms']:.3f}", f"{row['latency_ms']:.3f}")
    return table


def _gap_text(gap: float | None) -> str:
    return "unknown" if gap is None else f"{gap:.2%}"
