"""``catanc profile``: a spec's compute times, hops and dispatches from what ``catanc run`` measured (a diff,
``--write``, ``--check``)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from catanc.cli.common import reporting, stderr_console
from catanc.errors import ExitCode


@reporting
def profile(
    log: Annotated[Path, typer.Argument(metavar="LOG", help="A `catanc run` log (JSON lines).", show_default=False)],
    spec_path: Annotated[Path, typer.Option("--spec", metavar="SPEC", help="The spec the run was planned from.")],
    write: Annotated[bool, typer.Option("--write", help="Edit the spec in place (comments and layout kept).")] = False,
    check: Annotated[
        bool,
        typer.Option(
            "--check",
            help="Exit 1 if a compute time, speedup, hop or dispatch is more than --tolerance off, or a bounded "
            "chain's p95 response from origins is over its max_response_ms.",
        ),
    ] = False,
    tolerance: Annotated[float, typer.Option(min=0.0, help="--check's relative tolerance (0.15: 15%).")] = 0.15,
) -> None:
    """Propose each node's compute_ms (the p95 the runtime plans with, modes, speedups), each hop inside a
    subchain (hops_ms, its p95) and each head's dispatch (dispatch_ms, its p95) from a run's log."""
    from catanc.artifacts.output import replace_file
    from catanc.errors import UsageError
    from catanc.runtime.logs.writer import read_log_text
    from catanc.runtime.profile.propose import profile_spec
    from catanc.spec.parse import read_spec_text

    if write and check:
        raise UsageError("--write and --check: pick one (--check after --write always passes)")
    spec_text, _ = read_spec_text(spec_path)
    result = profile_spec(spec_text, str(spec_path), read_log_text(log), str(log), tolerance=tolerance)
    if write and result.text != spec_text:
        replace_file(spec_path, result.text)
    console = stderr_console()
    for line in result.summary:
        console.print(line, markup=False)
    sys.stdout.write(result.diff)
    if check and result.off:
        for line in result.off:
            console.print(line, markup=False)
        raise typer.Exit(int(ExitCode.DRIFT))
