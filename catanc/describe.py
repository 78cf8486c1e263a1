"""Human-readable views of a spec's chains (``catanc chains``).

:func:`chain_listing` is pure data; :func:`chains_table` renders it with rich.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rich.table import Table

from catanc import graph
from catanc.errors import Diagnostic, format_path
from catanc.problem import Chain, Problem, collapse, spec_dag
from catanc.spec import Spec

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
