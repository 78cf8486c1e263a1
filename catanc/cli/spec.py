"""Commands that read a spec: ``validate``, ``chains``, ``schema`` (none of them loads a solver)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from catanc.cli.common import (
    SpecArg,
    print_diagnostics,
    print_line,
    reporting,
    stdout_console,
)
from catanc.errors import ExitCode, SpecError
from catanc.text import plural


@reporting
def validate(
    specs: Annotated[list[Path], typer.Argument(metavar="SPEC...", help="Spec files.", show_default=False)],
) -> None:
    """Check specs: YAML, fields, names, the DAG, subchains, objective and constraints."""
    from catanc.model.load import read_spec

    failed = False
    for path in specs:
        try:
            loaded = read_spec(path)
        except SpecError as exc:
            print_diagnostics(exc.diagnostics)
            failed = True
            continue
        spec, problem = loaded.spec, loaded.problem
        print_diagnostics(problem.warnings, warning=True)
        print_line(
            f"{path}: ok: app {spec.app}, {plural(len(spec.nodes), 'node')}, "
            f"{plural(len(problem.subchains), 'subchain')}, "
            f"{plural(len(problem.chains), 'chain')} in the objective and constraints"
        )
    if failed:
        raise typer.Exit(int(ExitCode.BAD_INPUT))


@reporting
def chains(
    spec_path: SpecArg,
    limit: Annotated[int, typer.Option(min=1, help="List at most this many source-to-sink chains.")] = 10_000,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """List the app's chains, their subchain sequences and the terms that use them."""
    from catanc.explain.listings import chain_listing, chains_table
    from catanc.model.load import read_spec

    loaded = read_spec(spec_path)
    spec, problem = loaded.spec, loaded.problem
    listing = chain_listing(spec, problem, limit)
    print_diagnostics([*problem.warnings, *listing.warnings], warning=True)
    if as_json:
        rows: list[dict[str, Any]] = [
            {
                "nodes": list(r.nodes),
                "subchains": list(r.stages),
                "used_by": list(r.uses),
                "source_to_sink": r.source_to_sink,
            }
            for r in listing.rows
        ]
        payload = {"app": spec.app, "total_source_to_sink": listing.total_paths, "chains": rows}
        sys.stdout.write(json.dumps(payload, indent=2, sort_keys=True) + "\n")
        return
    stdout_console().print(chains_table(listing, f"{spec.app}: {plural(listing.total_paths, 'source-to-sink chain')}"))


@reporting
def schema(
    markdown: Annotated[
        bool, typer.Option("--markdown", help="Every field as a Markdown page (docs/reference/spec-fields.md).")
    ] = False,
) -> None:
    """Print the JSON Schema of the spec language (for editors), or its fields as Markdown."""
    from catanc.spec.language import json_schema, json_schema_text

    if markdown:
        from catanc.spec.schema_page import schema_page

        sys.stdout.write(schema_page(json_schema()))
        return
    sys.stdout.write(json_schema_text())
