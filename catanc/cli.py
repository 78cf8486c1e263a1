"""The ``catanc`` command line: parse options, call the core, map errors to exit codes.

Every command reports a :class:`~catanc.errors.CatancError` as a short
message with its exit code; anything else is a bug and exits with
``ExitCode.INTERNAL`` (set ``CATANC_DEBUG=1`` for the traceback).
"""

from __future__ import annotations

import functools
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ParamSpec, TypeVar

import typer
from rich.console import Console

from catanc.errors import CatancError, Diagnostic, ExitCode, SpecError

if TYPE_CHECKING:
    from catanc.problem import Problem
    from catanc.spec import Spec

P = ParamSpec("P")
R = TypeVar("R")

app = typer.Typer(
    name="catanc",
    help="Compile semantic specs of robotics and XR task graphs into CPU schedules.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

SpecArg = Annotated[Path, typer.Argument(metavar="SPEC", help="A spec file (YAML).", show_default=False)]
CoresOpt = Annotated[int, typer.Option("--cores", "-k", min=1, help="Identical CPU cores available.")]
Stage1Opt = Annotated[
    str, typer.Option(help="Stage I method: auto (enumerate small apps, else MILP), milp or exhaustive.")
]
SolverOpt = Annotated[str, typer.Option(help="MILP solver: highs or cbc.")]
TimeLimitOpt = Annotated[float | None, typer.Option(min=0.01, help="Stage I time limit in seconds (default 2.5).")]


PIPED_WIDTH = 160
"""Table width when stdout is not a terminal (rich would assume 80 and wrap every chain)."""


def _stdout() -> Console:
    width = None if sys.stdout.isatty() else PIPED_WIDTH
    return Console(highlight=False, soft_wrap=True, width=width)


def _stderr() -> Console:
    return Console(stderr=True, highlight=False, soft_wrap=True)


def _print_diagnostics(diagnostics: Sequence[Diagnostic], *, warning: bool = False) -> None:
    console = _stderr()
    for diagnostic in diagnostics:
        text = str(diagnostic)
        if warning:
            where = f"{diagnostic.location}: " if diagnostic.location else ""
            what = f"{diagnostic.field}: " if diagnostic.field else ""
            text = f"{where}warning: {what}{diagnostic.message}"
        console.print(text, markup=False)


def _load_problem(spec_path: Path) -> tuple[Spec, Problem]:
    """The spec and its planning problem, with the problem's warnings printed."""
    from catanc.load import load_spec
    from catanc.problem import build_problem

    spec = load_spec(spec_path)
    problem = build_problem(spec)
    _print_diagnostics(problem.warnings, warning=True)
    return spec, problem


def _print_notes(spec_path: Path, notes: Sequence[str]) -> None:
    for note in notes:
        _stderr().print(f"{spec_path}: warning: {note}", markup=False)


def _reporting(command: Callable[P, R]) -> Callable[P, R]:
    """Turn catanc errors into messages and exit codes; never show a traceback for them."""

    @functools.wraps(command)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return command(*args, **kwargs)
        except typer.Exit:
            raise
        except SpecError as exc:
            _print_diagnostics(exc.diagnostics)
            raise typer.Exit(int(exc.exit_code)) from None
        except CatancError as exc:
            _stderr().print(f"catanc: {exc}", markup=False)
            raise typer.Exit(int(exc.exit_code)) from None
        except Exception as exc:
            if os.environ.get("CATANC_DEBUG"):
                raise
            _stderr().print(
                f"catanc: internal error: {type(exc).__name__}: {exc}\n"
                "This is a bug in catanc; rerun with CATANC_DEBUG=1 for the traceback and report it.",
                markup=False,
            )
            raise typer.Exit(int(ExitCode.INTERNAL)) from None

    return wrapper


@app.command()
@_reporting
def validate(
    specs: Annotated[list[Path], typer.Argument(metavar="SPEC...", help="Spec files.", show_default=False)],
) -> None:
    """Check specs: YAML, fields, names, the DAG, subchains, objective and constraints."""
    from catanc.load import load_spec
    from catanc.problem import build_problem

    failed = False
    out = _stdout()
    for path in specs:
        try:
            spec = load_spec(path)
        except SpecError as exc:
            _print_diagnostics(exc.diagnostics)
            failed = True
            continue
        problem = build_problem(spec)
        _print_diagnostics(problem.warnings, warning=True)
        out.print(
            f"{path}: ok: app {spec.app}, {len(spec.nodes)} nodes, {len(problem.subchains)} subchains, "
            f"{len(problem.chains)} chains in the objective and constraints",
            markup=False,
        )
    if failed:
        raise typer.Exit(int(ExitCode.BAD_INPUT))


@app.command()
@_reporting
def chains(
    spec_path: SpecArg,
    limit: Annotated[int, typer.Option(min=1, help="List at most this many source-to-sink chains.")] = 10_000,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """List the app's chains, their subchain sequences and the terms that use them."""
    from catanc.describe import chain_listing, chains_table
    from catanc.load import load_spec
    from catanc.problem import build_problem

    spec = load_spec(spec_path)
    problem = build_problem(spec)
    listing = chain_listing(spec, problem, limit)
    _print_diagnostics([*problem.warnings, *listing.warnings], warning=True)
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
    _stdout().print(chains_table(listing, f"{spec.app}: {listing.total_paths} source-to-sink chains"))


@app.command()
@_reporting
def allocate(
    spec_path: SpecArg,
    cores: CoresOpt,
    stage1: Stage1Opt = "auto",
    solver: SolverOpt = "highs",
    time_limit: TimeLimitOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Stage I only: which subchains get cores of their own and which share one."""
    from catanc.describe import allocation_payload, allocation_table
    from catanc.stage1 import allocate as allocate_cores

    _, problem = _load_problem(spec_path)
    result = allocate_cores(problem, cores, method=stage1, solver=solver, time_limit_s=time_limit)
    _print_notes(spec_path, result.warnings)
    if as_json:
        sys.stdout.write(json.dumps(allocation_payload(problem, result, cores), indent=2, sort_keys=True) + "\n")
        return
    _stdout().print(allocation_table(problem, result, cores))


@app.command()
@_reporting
def explain(
    spec_path: SpecArg,
    cores: CoresOpt,
    stage1: Stage1Opt = "auto",
    solver: SolverOpt = "highs",
    time_limit: TimeLimitOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the runtime table's plan as JSON.")] = False,
) -> None:
    """Plan the spec and explain the plan: timelines, what binds, warnings, the baseline."""
    from catanc.explain import explain_plan, render
    from catanc.planner import plan
    from catanc.table import plan_json

    spec, problem = _load_problem(spec_path)
    result = plan(spec, cores, stage1_method=stage1, solver=solver, time_limit_s=time_limit)
    if as_json:  # the text shows them in its own warnings section
        _print_notes(spec_path, result.warnings)
        sys.stdout.write(plan_json(result, problem, app=spec.app, cores=cores))
        return
    out = _stdout()
    for part in render(explain_plan(spec, problem, result)):
        out.print(part)


@app.command()
@_reporting
def schema() -> None:
    """Print the JSON Schema of the spec language (for editors)."""
    from catanc.spec import json_schema_text

    sys.stdout.write(json_schema_text())


@app.command()
def version() -> None:
    """Print catanc's version."""
    from catanc import __version__

    sys.stdout.write(f"catanc {__version__}\n")


def main() -> None:
    """Console-script entry point."""
    app()
