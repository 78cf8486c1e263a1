"""Commands that plan: ``allocate`` (Stage I), ``explain`` and ``compile``."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from catanc.cli.common import (
    REPORT_WIDTH,
    CoresOpt,
    MachineOpt,
    QuietOpt,
    SolverOpt,
    SpecArg,
    Stage1Opt,
    TimeLimitOpt,
    load_problem,
    print_diagnostics,
    print_notes,
    report_console,
    reporting,
    stderr_console,
    stdout_console,
)
from catanc.errors import ExitCode
from catanc.text import plural

if TYPE_CHECKING:
    from catanc.artifacts.output import Comparison


@reporting
def allocate(
    spec_path: SpecArg,
    cores: CoresOpt,
    stage1: Stage1Opt = "auto",
    solver: SolverOpt = "highs",
    time_limit: TimeLimitOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Stage I only: which subchains get cores of their own and which share one."""
    from catanc.explain.listings import allocation_payload, allocation_table
    from catanc.planning.stage1 import allocate as allocate_cores

    _, problem = load_problem(spec_path)
    result = allocate_cores(problem, cores, method=stage1, solver=solver, time_limit_s=time_limit)
    print_notes(spec_path, result.warnings)
    if as_json:
        sys.stdout.write(json.dumps(allocation_payload(problem, result, cores), indent=2, sort_keys=True) + "\n")
        return
    stdout_console().print(allocation_table(problem, result, cores))


@reporting
def explain(
    spec_path: SpecArg,
    cores: CoresOpt,
    stage1: Stage1Opt = "auto",
    solver: SolverOpt = "highs",
    time_limit: TimeLimitOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the runtime table's plan as JSON.")] = False,
    machine: MachineOpt = None,
    width: Annotated[
        int | None,
        typer.Option(
            min=40, metavar="N", help=f"Lay the report out N columns wide (default: the terminal's or {REPORT_WIDTH})."
        ),
    ] = None,
) -> None:
    """Plan the spec and explain the plan: timelines, what binds, warnings, the baseline."""
    from catanc.artifacts.runtime_table import plan_json
    from catanc.explain.analysis import explain_plan
    from catanc.explain.terminal import render
    from catanc.planning.planner import plan_problem
    from catanc.spec.machine import apply_machine, read_machine

    spec, problem = load_problem(spec_path)
    used = None
    if machine is not None:  # raises the schedule's costs only: the problem stands
        spec, used = apply_machine(spec, read_machine(machine))
    result = plan_problem(problem, spec.schedule, cores, stage1_method=stage1, solver=solver, time_limit_s=time_limit)
    print_notes(spec_path, result.warnings)  # the report's warnings section says them too
    if as_json:
        sys.stdout.write(plan_json(result, problem, app=spec.app, cores=cores))
        return
    out = report_console(width)
    for part in render(explain_plan(spec, problem, result, used)):
        out.print(part)


@reporting
def compile_(
    specs: Annotated[list[Path], typer.Argument(metavar="SPEC...", help="Spec files.", show_default=False)],
    cores: Annotated[
        list[int], typer.Option("--cores", "-k", min=1, help="Identical CPU cores available (repeat for several).")
    ],
    out: Annotated[
        Path | None,
        typer.Option(help="Output folder (default: out/<app>/cores-<K>); only for one spec and one --cores."),
    ] = None,
    check: Annotated[
        bool, typer.Option("--check", help="Write nothing; exit 1 if the folders are not what compile would write.")
    ] = False,
    diff: Annotated[bool, typer.Option("--diff", help="Print a unified diff of every file that differs.")] = False,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Write nothing; say what would change.")] = False,
    stage1: Stage1Opt = "auto",
    solver: SolverOpt = "highs",
    time_limit: TimeLimitOpt = None,
    machine: MachineOpt = None,
    cpus: Annotated[
        str | None,
        typer.Option(
            "--cpus",
            metavar="LIST",
            help="CPUs the plan's cores run on, e.g. 2,3 (isolated CPUs, a container's cpuset); default 0,1,...",
        ),
    ] = None,
    quiet: QuietOpt = False,
) -> None:
    """Plan each spec and write its deployment folder: runtime.json, params.yaml, launch.sh, launch.py, PLAN.md."""
    from catanc.artifacts.compile import Options, check_enough_cpus, compile_checked, parse_cpus
    from catanc.artifacts.output import compare, ensure_comparable, write
    from catanc.cli.progress import tracked
    from catanc.errors import UsageError
    from catanc.model.load import read_spec

    if check and dry_run:
        raise UsageError("--check and --dry-run both write nothing: pick one")
    pairs = list(dict.fromkeys((path, k) for path in specs for k in cores))
    if out is not None and len(pairs) > 1:
        raise UsageError("--out names one folder: give one spec and one --cores with it")
    options = Options(
        stage1=stage1,
        solver=solver,
        time_limit_s=time_limit,
        machine=machine,
        cpus=parse_cpus(cpus) if cpus is not None else None,
    )
    if options.cpus is not None:
        check_enough_cpus(options.cpus, max(cores))  # before any spec is read or planned
    loaded = {path: read_spec(path) for path in dict.fromkeys(specs)}  # each spec and its problem built once
    targets = []
    planning = tracked(pairs, "planning", label=lambda pair: f"{pair[0]} on {plural(pair[1], 'core')}", quiet=quiet)
    for path, k in planning:  # plan everything before touching any folder
        target = compile_checked(loaded[path], path, k, out=out, options=options)
        print_diagnostics(target.spec_warnings, warning=True)
        print_notes(path, target.warnings)
        targets.append(target)
    folders: dict[Path, Path] = {}
    for target in targets:
        other = folders.setdefault(target.folder.absolute(), target.spec_path)
        if other != target.spec_path:
            raise UsageError(f"{other} and {target.spec_path} would both write {target.folder} (same app name)")
    console = stdout_console()
    stale = 0
    for target in targets:
        comparison = compare(target.folder, target.files, with_diffs=diff)
        if check:
            ensure_comparable(comparison)
        elif not dry_run:
            write(target.folder, target.files)
        stale += not comparison.current
        console.print(_summary(comparison, check=check, dry_run=dry_run), markup=False)
        for text in comparison.diffs.values():
            sys.stdout.write(text)
        sys.stdout.flush()
    if check and stale:
        stderr_console().print(
            f"catanc: {stale} of {len(targets)} output folder{'s are' if len(targets) > 1 else ' is'} stale: "
            "run the same command without --check and commit the result",
            markup=False,
        )
        raise typer.Exit(int(ExitCode.DRIFT))


def _summary(comparison: Comparison, *, check: bool, dry_run: bool) -> str:
    """One line per folder: what changed (or would), by file."""
    from catanc.artifacts.output import Status

    folder = comparison.folder
    if comparison.current:
        return f"{folder}: up to date"
    if not comparison.exists:
        return f"{folder}: {'would be created' if dry_run else 'created'} ({plural(len(comparison.statuses), 'file')})"
    parts = []
    for status in (Status.CHANGED, Status.MISSING, Status.EXTRA, Status.NEW):
        names = comparison.of(status)
        if names:
            parts.append(f"{status.value} {', '.join(names)}")
    if check:
        return f"{folder}: stale: {'; '.join(parts)}"
    return f"{folder}: {'would update' if dry_run else 'updated'}: {'; '.join(parts)}"
