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
from catanc.errors import Diagnostic, UsageError
from catanc.model.load import SpecFile, read_spec
from catanc.planning.planner import plan_problem
from catanc.spec.machine import apply_machine, read_machine

DEFAULT_OUT = Path("out")
DEFAULT_STAGE1 = "auto"
DEFAULT_SOLVER = "highs"
MAX_CPU = 8191
"""The highest CPU number Linux can have (CONFIG_NR_CPUS is at most 8192)."""


@dataclass(frozen=True)
class Options:
    """What shapes a plan beyond the spec and the core count (non-defaults go into the header's command)."""

    stage1: str = DEFAULT_STAGE1
    solver: str = DEFAULT_SOLVER
    time_limit_s: float | None = None
    machine: Path | None = None  # a machine profile (catanc.spec.machine) whose measured costs the plan covers
    cpus: tuple[int, ...] | None = None  # the CPUs plan cores 0, 1, ... run on, ascending (None: CPUs 0, 1, ...)


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
    """``out/<app>/cores-<K>`` (docs/guide/deploying.md)."""
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
    if options.cpus is not None:
        check_enough_cpus(options.cpus, cores)
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
        files=emit(spec, problem, result, provenance, used, cpus=options.cpus),
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
    if options.cpus is not None:
        words += ["--cpus", cpu_text(options.cpus)]
    return shlex.join(words)


def parse_cpus(text: str) -> tuple[int, ...]:
    """``--cpus 3,2`` -> ``(2, 3)``: the CPUs plan cores run on, core ``i`` on the ``i``-th lowest.

    Only what no machine could have is refused here (negative, duplicate or non-integer numbers, or
    above Linux's highest CPU number): the compiling machine need not be the robot, so whether these
    CPUs exist and may be used is checked where the plan runs (launch.sh, catanc run, catanc doctor).
    """
    cpus: list[int] = []
    for word in text.split(","):
        item = word.strip()
        if not item.isdigit() or not item.isascii():
            what = "an empty entry" if not item else f"{item!r} is not a CPU number"
            raise UsageError(f"--cpus {text}: {what} (expected CPU numbers separated by commas, e.g. 2,3)")
        cpu = int(item)
        if cpu > MAX_CPU:
            raise UsageError(f"--cpus {text}: CPU {cpu} cannot exist (Linux numbers CPUs 0 to {MAX_CPU})")
        if cpu in cpus:
            raise UsageError(f"--cpus {text}: CPU {cpu} is given twice (each plan core needs a CPU of its own)")
        cpus.append(cpu)
    return tuple(sorted(cpus))


def check_enough_cpus(cpus: tuple[int, ...], cores: int) -> None:
    """:class:`UsageError` unless there is a CPU for each of ``cores`` plan cores."""
    if len(cpus) < cores:
        raise UsageError(
            f"--cpus {cpu_text(cpus)}: {len(cpus)} CPU{'s' if len(cpus) > 1 else ''} for {cores} cores: "
            f"give at least {cores}, or compile for fewer (--cores)"
        )


def cpu_text(cpus: tuple[int, ...]) -> str:
    return ",".join(str(cpu) for cpu in cpus)


def display_path(path: Path) -> str:
    """``path`` relative to the working folder, with ``/``: no absolute path ever reaches a header."""
    relative = os.path.relpath(path.absolute(), Path.cwd())
    return PurePath(relative).as_posix()
