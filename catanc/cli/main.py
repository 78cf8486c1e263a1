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

from catanc.cli.init_command import init
from catanc.errors import CatancError, Diagnostic, ExitCode, SpecError
from catanc.text import plural

if TYPE_CHECKING:
    from catanc.artifacts.output import Comparison
    from catanc.core.problem import Problem
    from catanc.sim.metrics import PolicyResult
    from catanc.spec.language import Spec

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


PIPED_WIDTH = 160
"""Table width when stdout is not a terminal (rich would assume 80 and wrap every chain)."""

REPORT_WIDTH = 100
"""``explain``'s width when stdout is not a terminal: its tables wrap their text to fit, so a file reads well."""


def _stdout() -> Console:
    width = None if sys.stdout.isatty() else PIPED_WIDTH
    return Console(highlight=False, soft_wrap=True, width=width)


def _report_out(width: int | None) -> Console:
    """A console whose text wraps at ``width``: the terminal's by default, else :data:`REPORT_WIDTH`."""
    if width is None and not sys.stdout.isatty():
        width = REPORT_WIDTH
    return Console(highlight=False, soft_wrap=False, width=width)


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
    from catanc.core.load import read_spec

    loaded = read_spec(spec_path)
    _print_diagnostics(loaded.problem.warnings, warning=True)
    return loaded.spec, loaded.problem


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


app.command(name="init")(_reporting(init))


@app.command()
@_reporting
def validate(
    specs: Annotated[list[Path], typer.Argument(metavar="SPEC...", help="Spec files.", show_default=False)],
) -> None:
    """Check specs: YAML, fields, names, the DAG, subchains, objective and constraints."""
    from catanc.core.load import read_spec

    failed = False
    out = _stdout()
    for path in specs:
        try:
            loaded = read_spec(path)
        except SpecError as exc:
            _print_diagnostics(exc.diagnostics)
            failed = True
            continue
        spec, problem = loaded.spec, loaded.problem
        _print_diagnostics(problem.warnings, warning=True)
        out.print(
            f"{path}: ok: app {spec.app}, {plural(len(spec.nodes), 'node')}, "
            f"{plural(len(problem.subchains), 'subchain')}, "
            f"{plural(len(problem.chains), 'chain')} in the objective and constraints",
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
    from catanc.core.load import read_spec
    from catanc.explain.listings import chain_listing, chains_table

    loaded = read_spec(spec_path)
    spec, problem = loaded.spec, loaded.problem
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
    _stdout().print(chains_table(listing, f"{spec.app}: {plural(listing.total_paths, 'source-to-sink chain')}"))


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
    from catanc.explain.listings import allocation_payload, allocation_table
    from catanc.planning.stage1 import allocate as allocate_cores

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

    spec, problem = _load_problem(spec_path)
    used = None
    if machine is not None:  # raises the schedule's costs only: the problem stands
        spec, used = apply_machine(spec, read_machine(machine))
    result = plan_problem(problem, spec.schedule, cores, stage1_method=stage1, solver=solver, time_limit_s=time_limit)
    _print_notes(spec_path, result.warnings)  # the report's warnings section says them too
    if as_json:
        sys.stdout.write(plan_json(result, problem, app=spec.app, cores=cores))
        return
    out = _report_out(width)
    for part in render(explain_plan(spec, problem, result, used)):
        out.print(part)


@app.command(name="compile")
@_reporting
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
    quiet: QuietOpt = False,
) -> None:
    """Plan each spec and write its deployment folder: runtime.json, params.yaml, launch.sh, launch.py, PLAN.md."""
    from catanc.artifacts.compile import Options, compile_checked
    from catanc.artifacts.output import compare, ensure_comparable, write
    from catanc.cli.progress import tracked
    from catanc.core.load import read_spec
    from catanc.errors import UsageError

    if check and dry_run:
        raise UsageError("--check and --dry-run both write nothing: pick one")
    pairs = list(dict.fromkeys((path, k) for path in specs for k in cores))
    if out is not None and len(pairs) > 1:
        raise UsageError("--out names one folder: give one spec and one --cores with it")
    options = Options(stage1=stage1, solver=solver, time_limit_s=time_limit, machine=machine)
    loaded = {path: read_spec(path) for path in dict.fromkeys(specs)}  # each spec and its problem built once
    targets = []
    planning = tracked(pairs, "planning", label=lambda pair: f"{pair[0]} on {plural(pair[1], 'core')}", quiet=quiet)
    for path, k in planning:  # plan everything before touching any folder
        target = compile_checked(loaded[path], path, k, out=out, options=options)
        _print_diagnostics(target.spec_warnings, warning=True)
        _print_notes(path, target.warnings)
        targets.append(target)
    folders: dict[Path, Path] = {}
    for target in targets:
        other = folders.setdefault(target.folder.absolute(), target.spec_path)
        if other != target.spec_path:
            raise UsageError(f"{other} and {target.spec_path} would both write {target.folder} (same app name)")
    console = _stdout()
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
        _stderr().print(
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


@app.command(name="run")
@_reporting
def run_(
    table_path: Annotated[
        Path, typer.Argument(metavar="RUNTIME_JSON", help="A runtime table (out/<app>/cores-<K>/runtime.json).")
    ],
    launch: Annotated[bool, typer.Option("--launch", help="Start the spec's deploy commands.")] = False,
    attach: Annotated[
        list[str] | None, typer.Option("--attach", metavar="NODE=PID", help="Pin a running process as NODE's.")
    ] = None,
    demo: Annotated[bool, typer.Option("--demo", help="Start one synthetic worker per scheduled node.")] = False,
    duration: Annotated[float | None, typer.Option(min=0.1, help="Stop after this many seconds.")] = None,
    no_rt: Annotated[bool, typer.Option("--no-rt", help="Rates and affinities only: no SCHED_FIFO.")] = False,
    log: Annotated[Path | None, typer.Option(help="JSON-lines log (default: catanc-run-<app>.jsonl).")] = None,
    socket: Annotated[Path | None, typer.Option(help="The enforcer's socket (default: in /tmp).")] = None,
    start: Annotated[
        str, typer.Option(help="First plan: bootstrap (every node 5 ms, as the paper) or spec (the table's).")
    ] = "bootstrap",
    cores: Annotated[int | None, typer.Option(min=1, help="Plan for this many cores instead of the table's.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", help="No live status; a summary at the end.")] = False,
) -> None:
    """Enforce a plan on this machine: trigger subchains, run per-core slices, measure and re-solve."""
    from catanc.artifacts.runtime_table import load_table
    from catanc.core.priorities import ENFORCER_FIFO
    from catanc.errors import UsageError
    from catanc.runtime.enforcer import Enforcer
    from catanc.runtime.processes import Children, parse_attach, start_demo, start_launch
    from catanc.runtime.sched import Restorer, check_fifo_allowed, threads_of
    from catanc.runtime.status import status_view
    from catanc.runtime.watchdog import Watchdog

    if demo + launch > 1:
        raise UsageError("--demo and --launch both start the app: pick one")
    if start not in ("bootstrap", "spec"):
        raise UsageError(f"--start {start!r}: expected bootstrap or spec")
    table = load_table(table_path)
    attached = parse_attach(attach or [], table.spec)
    if not no_rt:
        check_fifo_allowed(ENFORCER_FIFO)
    socket_path = str(socket or Path(f"/tmp/catanc-{os.getuid()}-{table.app}.sock"))
    log_path = log or Path(f"catanc-run-{table.app}.jsonl")
    children = Children()
    restorer = Restorer(Watchdog().start()) if not no_rt else Restorer()
    enforcer = Enforcer(
        table,
        socket_path=socket_path,
        rt=not no_rt,
        start="bootstrap" if start == "bootstrap" else "spec",
        log_path=log_path,
        cores=cores,
        restorer=restorer,
    )

    def begin(running: Enforcer) -> None:
        for node, pid in attached.items():
            running.attach(node, pid, threads_of(pid))
        if demo:
            start_demo(children, table.spec, socket_path)
        elif launch:
            start_launch(children, table.processes, socket_path)

    live = None
    if not quiet and sys.stdout.isatty():
        from rich.live import Live

        live = Live(console=_stdout(), refresh_per_second=4, transient=False)
        live.start()

    def tick(running: Enforcer) -> None:
        if live is not None:
            live.update(
                status_view(table.app, running.schedule.cores, running.status(), running.events, running.elapsed_s())
            )

    try:
        enforcer.run(duration, on_start=begin, on_tick=tick)
    except KeyboardInterrupt:
        pass
    finally:
        if live is not None:
            live.stop()
        children.stop()
    _stdout().print(
        status_view(table.app, enforcer.schedule.cores, enforcer.status(), enforcer.events, enforcer.elapsed_s())
    )
    _stdout().print(f"log: {log_path}", markup=False)


@app.command()
@_reporting
def doctor(
    table_path: Annotated[
        Path | None,
        typer.Argument(
            metavar="[RUNTIME_JSON]",
            help="A runtime table: check for its plan (default: what `catanc run` needs for any plan).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Check this machine for what a plan needs (privileges, real-time budgets, CPUs, tools); say how to fix each."""
    from catanc.artifacts.runtime_table import load_table
    from catanc.doctor import ENFORCER_ONLY, Verdict, diagnose, inspect_machine, needs_of, render

    if table_path is None:
        needs, title = ENFORCER_ONLY, "catanc doctor: what `catanc run` needs for any plan"
    else:
        table = load_table(table_path)
        needs = needs_of(table)
        title = f"catanc doctor: {table_path} ({table.app}, {table.cores} core{'s' if table.cores > 1 else ''})"
    findings = diagnose(needs, inspect_machine(needs))
    sys.stdout.write(render(findings, title))
    if any(finding.verdict is Verdict.FAIL for finding in findings):
        raise typer.Exit(int(ExitCode.MACHINE))


@app.command(name="set-cores")
@_reporting
def set_cores_(
    cores: Annotated[int, typer.Argument(min=1, help="Cores the running app may use from now on.")],
    socket: Annotated[Path, typer.Option(help="The enforcer's socket (as given to catanc run --socket).")],
) -> None:
    """Tell a running `catanc run` to re-plan for another number of cores (Stage I again, then re-pinning)."""
    from catanc.client import set_cores

    set_cores(cores, str(socket))


@app.command()
@_reporting
def report(
    log: Annotated[Path, typer.Argument(metavar="LOG", help="A `catanc run` log (JSON lines).", show_default=False)],
    plot: Annotated[Path | None, typer.Option(metavar="FILE.png", help="Also draw a timeline plot (PNG).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Summarise a `catanc run` log: rates, latencies, compute times, re-plans; optionally plot a timeline."""
    from catanc.runtime.log_summary import report_command

    report_command(log, plot, as_json)


@app.command()
@_reporting
def simulate(
    spec_path: SpecArg,
    cores: CoresOpt,
    policy: Annotated[
        list[str] | None,
        typer.Option(
            help="catan, baseline, fifo-static, static-fullrun or static-20s (repeat for several; default: all)."
        ),
    ] = None,
    duration: Annotated[float, typer.Option(min=0.1, help="Simulated seconds.")] = 60.0,
    seed: WorkloadSeedOpt = 0,
    as_json: TablesJsonOpt = False,
    plot: PlotDirOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Simulate the app on K cores under catanc's plan and the baselines; compare response times and rates."""
    from catanc.cli.progress import tracked
    from catanc.sim.simulate import POLICIES, Setup, check_policies, simulate

    spec, _ = _load_problem(spec_path)
    chosen = check_policies(policy or list(POLICIES))
    setup = Setup(spec, cores, duration, seed)
    results = [simulate(setup, name) for name in tracked(chosen, "simulating", quiet=quiet)]
    title = f"{spec.app}, {plural(cores, 'core')}, {duration:g} s simulated, seed {seed}"
    _show_comparison(spec, results, title, plot, as_json)


def _show_comparison(spec: Spec, results: Sequence[PolicyResult], title: str, plot: Path | None, as_json: bool) -> None:
    """simulate's and bench's output: plots first (if asked), then the JSON or the tables, then the plot paths."""
    from catanc.sim.comparison import comparison_payload, comparison_tables

    written: list[Path] = []
    if plot is not None:
        from catanc.sim.plots import write_plots

        scheduled = [name for name, node in spec.nodes.items() if node.scheduled]
        written = write_plots(results, plot, title=title, nodes=scheduled)
    if as_json:
        sys.stdout.write(json.dumps(comparison_payload(results), indent=2, sort_keys=True) + "\n")
    else:
        out = _stdout()
        for table in comparison_tables(results):
            out.print(table)
    for path in written:
        (_stderr() if as_json else _stdout()).print(f"plot: {path}", markup=False)


@app.command()
@_reporting
def bench(
    spec_path: SpecArg,
    cores: CoresOpt,
    policy: Annotated[
        list[str] | None,
        typer.Option(
            help="catan, baseline, fifo-static, static-fullrun or static-20s (repeat for several; "
            "default: catan, baseline and fifo-static)."
        ),
    ] = None,
    duration: Annotated[float, typer.Option(min=0.5, help="Measured seconds per policy.")] = 20.0,
    seed: WorkloadSeedOpt = 0,
    as_json: TablesJsonOpt = False,
    plot: PlotDirOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Run the app's synthetic workers on this machine under catanc's plan and the baselines; compare them."""
    from catanc.cli.progress import progress
    from catanc.realbench.bench import DEFAULT_POLICIES, BenchSetup, bench_policies

    spec, _ = _load_problem(spec_path)
    setup = BenchSetup(spec_path, spec, cores, duration, seed)
    chosen = policy or list(DEFAULT_POLICIES)
    err = _stderr()
    try:
        with progress("benchmarking", len(chosen), quiet=quiet) as bar:
            # a bar on a terminal; elsewhere (CI logs) a line per policy as it starts, as before; --quiet: nothing
            step = bar.start if bar.shown or quiet else (lambda text: err.print(text, markup=False))
            results = bench_policies(setup, chosen, progress=step)
    except KeyboardInterrupt:
        err.print("catanc: interrupted; every worker stopped", markup=False)
        raise typer.Exit(130) from None
    title = f"{spec.app}, {plural(cores, 'core')}, {duration:g} s measured, seed {seed}"
    _show_comparison(spec, results, title, plot, as_json)


@app.command()
@_reporting
def schema() -> None:
    """Print the JSON Schema of the spec language (for editors)."""
    from catanc.spec.language import json_schema_text

    sys.stdout.write(json_schema_text())


@app.command()
def version() -> None:
    """Print catanc's version."""
    from catanc import __version__

    sys.stdout.write(f"catanc {__version__}\n")


def main() -> None:
    """Console-script entry point."""
    app()
