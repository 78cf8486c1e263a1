"""What every command shares: its options' types, its consoles, and errors turned into exit codes.

Every command reports a :class:`~catanc.errors.CatancError` as a short
message with its exit code; anything else is a bug and exits with
``ExitCode.INTERNAL`` (set ``CATANC_DEBUG=1`` for the traceback).

One-line messages (diagnostics, warnings, errors) are plain text, written
as they are: rich would read ``:name:`` in a user's file name or key as an
emoji code, and importing it costs ``catanc validate`` a tenth of its time.
Tables, reports and progress use rich's consoles, imported when made.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, ParamSpec, TypeVar

import typer

from catanc.errors import CatancError, Diagnostic, ExitCode, SpecError, UsageError

if TYPE_CHECKING:
    from rich.console import Console

    from catanc.model.problem import Problem
    from catanc.runtime.compiled.ready import LoopChoice
    from catanc.spec.language import Spec

P = ParamSpec("P")
R = TypeVar("R")

SpecArg = Annotated[Path, typer.Argument(metavar="SPEC", help="A spec file (YAML).", show_default=False)]
CoresOpt = Annotated[int, typer.Option("--cores", "-k", min=1, help="Identical CPU cores available.")]
Stage1Opt = Annotated[
    str, typer.Option(help="Stage I method: auto (enumerate small apps, else MILP), milp or exhaustive.")
]
SolverOpt = Annotated[str, typer.Option(help="MILP solver: highs or cbc.")]
TimeLimitOpt = Annotated[float | None, typer.Option(min=0.01, help="Stage I time limit in seconds (default 2.5).")]
MachineOpt = Annotated[
    Path | None,
    typer.Option(
        "--machine",
        metavar="FILE",
        help="A machine profile (catanc calibrate): plan with switch_ms and slack raised to its measured costs.",
    ),
]
# simulate and bench: the same comparison, simulated or measured.
WorkloadSeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Seed of the workload's random draws.")]
TablesJsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar (there is none off a terminal).")]
PlotDirOpt = Annotated[
    Path | None,
    typer.Option(
        "--plot",
        metavar="DIR",
        help="Also write PNG plots into DIR (created if missing): responses-cdf.png, timeline.png, rates.png.",
    ),
]


# run and bench: the enforcer's loop.
LOOPS = ("auto", "compiled", "python")
LoopOpt = Annotated[
    str,
    typer.Option(
        help="The enforcer's loop: compiled (numba: less CPU), python, or auto: compiled where it is built on "
        "this machine, else python while a child builds it for the next run.",
    ),
]


def loop_option(text: str) -> LoopChoice:
    """``--loop``'s value checked (a usage error, exit 2, names the choices)."""
    if text == "auto":
        return "auto"
    if text == "compiled":
        return "compiled"
    if text == "python":
        return "python"
    raise UsageError(f"--loop {text!r}: expected {', '.join(LOOPS)}")


PIPED_WIDTH = 160
"""Table width when stdout is not a terminal (rich would assume 80 and wrap every chain)."""

REPORT_WIDTH = 80
"""``explain``'s width when stdout is not a terminal: its tables wrap their text to fit, so a file reads well."""


def stdout_console() -> Console:
    from rich.console import Console

    width = None if sys.stdout.isatty() else PIPED_WIDTH
    return Console(highlight=False, soft_wrap=True, width=width)


def report_console(width: int | None) -> Console:
    """A console whose text wraps at ``width``: the terminal's by default, else :data:`REPORT_WIDTH`."""
    from rich.console import Console

    if width is None and not sys.stdout.isatty():
        width = REPORT_WIDTH
    return Console(highlight=False, soft_wrap=False, width=width)


def stderr_console() -> Console:
    from rich.console import Console

    return Console(stderr=True, highlight=False, soft_wrap=True)


def print_line(text: str, *, stderr: bool = False) -> None:
    """One line of plain text on stdout (or stderr), as it is."""
    (sys.stderr if stderr else sys.stdout).write(f"{text}\n")


def print_diagnostics(diagnostics: Sequence[Diagnostic], *, warning: bool = False) -> None:
    for diagnostic in diagnostics:
        text = str(diagnostic)
        if warning:
            where = f"{diagnostic.location}: " if diagnostic.location else ""
            what = f"{diagnostic.field}: " if diagnostic.field else ""
            text = f"{where}warning: {what}{diagnostic.message}"
        print_line(text, stderr=True)


def load_problem(spec_path: Path) -> tuple[Spec, Problem]:
    """The spec and its planning problem, with the problem's warnings printed."""
    from catanc.model.load import read_spec

    loaded = read_spec(spec_path)
    print_diagnostics(loaded.problem.warnings, warning=True)
    return loaded.spec, loaded.problem


def print_notes(spec_path: Path, notes: Sequence[str]) -> None:
    for note in notes:
        print_line(f"{spec_path}: warning: {note}", stderr=True)


def reporting(command: Callable[P, R]) -> Callable[P, R]:
    """Turn catanc errors into messages and exit codes; never show a traceback for them."""

    @functools.wraps(command)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return command(*args, **kwargs)
        except typer.Exit:
            raise
        except SpecError as exc:
            print_diagnostics(exc.diagnostics)
            raise typer.Exit(int(exc.exit_code)) from None
        except CatancError as exc:
            print_line(f"catanc: {exc}", stderr=True)
            raise typer.Exit(int(exc.exit_code)) from None
        except Exception as exc:
            if os.environ.get("CATANC_DEBUG"):
                raise
            print_line(
                f"catanc: internal error: {type(exc).__name__}: {exc}\n"
                "This is a bug in catanc; rerun with CATANC_DEBUG=1 for the traceback and report it.",
                stderr=True,
            )
            raise typer.Exit(int(ExitCode.INTERNAL)) from None

    return wrapper
