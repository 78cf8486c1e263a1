"""``catanc compile`` without the command line: spec file -> plan -> the output folder's files.

:func:`compile_spec` reads one spec and returns a :class:`Target`: where its
folder goes and the files for it, in memory.  :func:`compile_checked` does the
same for a spec already read, so one spec compiled for several core counts
is read, checked and built into its problem once.  The CLI then writes,
dry-runs or checks them with :mod:`catanc.artifacts.output`.
"""

from __future__ import annotations

import os
import shlex
from dataclasses import dataclass
from pathlib import Path, PurePath

from catanc import __version__
from catanc.artifacts.emit import emit
from catanc.artifacts.provenance import Provenance
from catanc.core.load import SpecFile, read_spec
from catanc.errors import Diagnostic
from catanc.planning.planner import plan_problem
from catanc.spec.machine import apply_machine, read_machine

DEFAULT_OUT = Path("out")
DEFAULT_STAGE1 = "auto"
DEFAULT_SOLVER = "highs"


@dataclass(frozen=True)
class Options:
    """What shapes a plan beyond the spec and the core count (non-defaults go into the header's command)."""

    stage1: str = DEFAULT_STAGE1
    solver: str = DEFAULT_SOLVER
    time_limit_s: float | None = None
    machine: Path | None = None  # a machine profile (catanc.spec.machine) whose measured costs the plan covers


@dataclass(frozen=True)
class Target:
    spec_path: Path
    app: str
    cores: int
    folder: Path
    files: dict[str, str]
    warnings: tuple[str, ...]  # the planner's
    spec_warnings: tuple[Diagnostic, ...] = ()  # the spec's, with their places


def default_folder(app: str, cores: int, root: Path = DEFAULT_OUT) -> Path:
    """``out/<app>/cores-<K>`` (interfaces.md)."""
    return root / app / f"cores-{cores}"


def compile_spec(spec_path: Path, cores: int, *, out: Path | None = None, options: Options = Options()) -> Target:
    """Plan ``spec_path`` on ``cores`` cores and emit its folder's files."""
    return compile_checked(read_spec(spec_path), spec_path, cores, out=out, options=options)


def compile_checked(
    loaded: SpecFile, spec_path: Path, cores: int, *, out: Path | None = None, options: Options = Options()
) -> Target:
    """:func:`compile_spec` for a spec already read (from ``spec_path``): its problem is not built again.

    A machine profile raises the schedule's costs only, which the problem does not hold: the spec's
    problem stands for the profiled spec too.
    """
    spec, problem = loaded.spec, loaded.problem
    used = None
    if options.machine is not None:
        spec, used = apply_machine(spec, read_machine(options.machine))
    result = plan_problem(
        problem,
        spec.schedule,
        cores,
        stage1_method=options.stage1,
        solver=options.solver,
        time_limit_s=options.time_limit_s,
    )
    provenance = Provenance(
        version=__version__,
        command=normalised_command(spec_path, cores, out, options),
        spec_name=spec_path.name,
        spec_sha256=loaded.sha256,
    )
    return Target(
        spec_path=spec_path,
        app=spec.app,
        cores=cores,
        folder=out if out is not None else default_folder(spec.app, cores),
        files=emit(spec, problem, result, provenance, used),
        warnings=result.warnings,
        spec_warnings=tuple(problem.warnings),
    )


def normalised_command(spec_path: Path, cores: int, out: Path | None, options: Options) -> str:
    """The command that regenerates a folder: paths relative to the working folder, options in a fixed order."""
    words = ["catanc", "compile", display_path(spec_path), "--cores", str(cores)]
    if out is not None:
        words += ["--out", display_path(out)]
    if options.stage1 != DEFAULT_STAGE1:
        words += ["--stage1", options.stage1]
    if options.solver != DEFAULT_SOLVER:
        words += ["--solver", options.solver]
    if options.time_limit_s is not None:
        words += ["--time-limit", f"{options.time_limit_s:g}"]
    if options.machine is not None:
        words += ["--machine", display_path(options.machine)]
    return shlex.join(words)


def display_path(path: Path) -> str:
    """``path`` relative to the working folder, with ``/``: no absolute path ever reaches a header."""
    relative = os.path.relpath(path.absolute(), Path.cwd())
    return PurePath(relative).as_posix()
