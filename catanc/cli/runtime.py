"""Commands of the runtime: ``run`` (the enforcer), ``doctor``, ``calibrate``, ``set-cores``, ``report`` (a log)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from catanc.cli.common import (
    LoopOpt,
    loop_option,
    reporting,
    stdout_console,
)
from catanc.errors import ExitCode
from catanc.text import plural


@reporting
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
    socket: Annotated[
        Path | None,
        typer.Option(help="The enforcer's socket (default: /run/catanc/<app>.sock as root, else a folder of yours)."),
    ] = None,
    start: Annotated[
        str, typer.Option(help="First plan: bootstrap (every node 5 ms, as the paper) or spec (the table's).")
    ] = "bootstrap",
    cores: Annotated[int | None, typer.Option(min=1, help="Plan for this many cores instead of the table's.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", help="No live status; a summary at the end.")] = False,
    loop: LoopOpt = "auto",
    observe: Annotated[
        bool,
        typer.Option(
            "--observe",
            help="Schedule nothing: measure --attach/--launch nodes on their own timers (for catanc profile).",
        ),
    ] = False,
) -> None:
    """Enforce a plan on this machine: trigger subchains, run per-core slices, measure and re-solve."""
    if observe:
        observe_(table_path, launch=launch, attach=attach or [], demo=demo, duration=duration, log=log, quiet=quiet)
        return
    from catanc.artifacts.runtime_table import load_table
    from catanc.errors import UsageError
    from catanc.model.priorities import ENFORCER_FIFO
    from catanc.runtime.enforcer.processes import (
        MIDDLEWARE_CHECK_S,
        Children,
        MiddlewareWatch,
        parse_attach,
        start_demo,
        start_launch,
    )
    from catanc.runtime.enforcer.run import Enforcer
    from catanc.runtime.enforcer.status import status_view
    from catanc.runtime.linux.sched import Restorer, check_fifo_allowed, threads_of
    from catanc.runtime.linux.watchdog import Watchdog
    from catanc.runtime.protocol.endpoints import default_socket_path

    if demo + launch > 1:
        raise UsageError("--demo and --launch both start the app: pick one")
    if start not in ("bootstrap", "spec"):
        raise UsageError(f"--start {start!r}: expected bootstrap or spec")
    loop_choice = loop_option(loop)
    table = load_table(table_path)
    attached = parse_attach(attach or [], table.spec)
    if not no_rt:
        check_fifo_allowed(ENFORCER_FIFO)
    socket_path = str(socket or default_socket_path(table.app))
    log_path = log or Path(f"catanc-run-{table.app}.jsonl")
    children = Children()
    restorer = Restorer(Watchdog().start()) if not no_rt else Restorer()
    try:
        enforcer = Enforcer(
            table,
            socket_path=socket_path,
            rt=not no_rt,
            start="bootstrap" if start == "bootstrap" else "spec",
            log_path=log_path,
            cores=cores,
            restorer=restorer,
            loop=loop_choice,
        )
    except BaseException:
        restorer.close()  # nothing was raised yet: the watchdog goes without a word
        raise

    def begin(running: Enforcer) -> None:
        for node, pid in attached.items():
            running.attach(node, pid, threads_of(pid))
        if demo:
            start_demo(children, table.spec, socket_path)
        elif launch:
            # Plan core i runs on the table's i-th CPU, and in this run on its i-th usable one.
            table_cpus = table.cpus if table.cpus is not None else range(table.cores)
            start_launch(
                children,
                table.processes,
                socket_path,
                table.path.parent,
                dict(zip(table_cpus, running.replanning.cpu_ids, strict=False)),
            )

    live = None
    if not quiet and sys.stdout.isatty():
        from rich.live import Live

        # Refreshed by the enforcer's loop once a second: no rendering thread takes the interpreter lock meanwhile.
        live = Live(console=stdout_console(), auto_refresh=False, transient=False)
        live.start()

    middleware = MiddlewareWatch()

    def tick(running: Enforcer) -> None:
        if launch and running.elapsed_s() < MIDDLEWARE_CHECK_S:
            cpu_ids = running.replanning.cpu_ids
            scheduled = {cpu_ids[core] for run in running.schedule.subchains.values() for core in run.cores}
            for line in middleware.check(children, scheduled):
                print(f"catanc run: {line}", file=sys.stderr, flush=True)
        if live is not None:
            live.update(
                status_view(table.app, running.schedule.cores, running.status(), running.events, running.elapsed_s()),
                refresh=True,
            )

    try:
        enforcer.run(duration, on_start=begin, on_tick=tick)
    except KeyboardInterrupt:
        pass
    finally:
        if live is not None:
            live.stop()
        for line in children.stop():
            print(f"catanc run: {line}", file=sys.stderr, flush=True)
        restorer.close()  # done by the run unless it failed before taking it over (its socket in use)
    stdout_console().print(
        status_view(
            table.app,
            enforcer.schedule.cores,
            enforcer.final or enforcer.status(),
            enforcer.events,
            enforcer.elapsed_s(),
        )
    )
    stdout_console().print(f"log: {log_path}", markup=False)


def observe_(
    table_path: Path,
    *,
    launch: bool,
    attach: list[str],
    demo: bool,
    duration: float | None,
    log: Path | None,
    quiet: bool,
) -> None:
    """``catanc run --observe``: measure the nodes' runs on their own timers; no SCHED_FIFO, no pinning, no trigger."""
    from catanc.artifacts.runtime_table import load_table
    from catanc.cli.progress import progress
    from catanc.errors import UsageError
    from catanc.runtime.enforcer.observe import Observer, launched_nodes
    from catanc.runtime.enforcer.processes import Children, parse_attach, start_launch

    if demo:
        raise UsageError("--observe with --demo: the demo workers wait for triggers; observe --launch or --attach")
    if not launch and not attach:
        raise UsageError("--observe measures nodes on their own timers: give --launch or --attach NODE=PID")
    table = load_table(table_path)
    attached = parse_attach(attach, table.spec)
    log_path = log or Path(f"catanc-run-{table.app}.jsonl")
    children = Children()
    observer = Observer(attached, log_path)
    console = stdout_console()

    def begin(running: Observer) -> None:
        if not launch:
            return
        start_launch(children, table.processes, None, table.path.parent)
        nodes_of = {str(process.get("key")): list(process.get("nodes", [])) for process in table.processes}
        found, shared = launched_nodes((nodes_of.get(key, []), process.pid) for key, process in children.processes)
        for node, pid in found.items():
            if node not in attached:
                running.observe(node, pid)
        for nodes in shared:
            console.print(f"not observed: {', '.join(nodes)} share one process (attach each on its own)", markup=False)

    # Seconds of a bounded run, else just the time and the runs so far.
    with progress("observing", duration, unit="s" if duration else "", quiet=quiet) as bar:

        def tick(running: Observer) -> None:
            elapsed = running.elapsed_s()
            bar.update(min(elapsed, duration) if duration else elapsed, f"{sum(running.counts.values())} runs")

        try:
            observer.run(duration, on_start=begin, on_tick=tick)
        finally:
            children.stop()
    counts = ", ".join(f"{node} {count}" for node, count in sorted(observer.counts.items()))
    console.print(f"observed {observer.elapsed_s():.1f} s, runs per node: {counts or 'none'}", markup=False)
    console.print(f"log: {log_path}", markup=False)


@reporting
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
        title = f"catanc doctor: {table_path} ({table.app}, {plural(table.cores, 'core')})"
    findings = diagnose(needs, inspect_machine(needs))
    sys.stdout.write(render(findings, title))
    if any(finding.verdict is Verdict.FAIL for finding in findings):
        raise typer.Exit(int(ExitCode.MACHINE))


@reporting
def calibrate(
    out: Annotated[Path, typer.Option("--out", help="Where to write the machine profile (YAML).")] = Path(
        "machine.yaml"
    ),
    duration: Annotated[float, typer.Option(min=1.0, help="Seconds of measuring.")] = 6.0,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress bar.")] = False,
) -> None:
    """Measure the enforcer's own costs on this machine (a few seconds of a synthetic app) into a machine profile."""
    from catanc.artifacts.output import replace_file
    from catanc.cli.progress import progress
    from catanc.model.priorities import ENFORCER_FIFO
    from catanc.runtime.linux.sched import Restorer, check_fifo_allowed
    from catanc.runtime.linux.watchdog import Watchdog
    from catanc.runtime.profile.calibrate import calibrate as measure
    from catanc.spec.machine import profile_text

    check_fifo_allowed(ENFORCER_FIFO)
    # Drawn from the enforcer's real-time loop once a second: no drawing thread competes with what is measured.
    with progress("calibrate", duration, unit="s", quiet=quiet, drawing_thread=False) as bar:
        phase = ""

        def tell(step: str, detail: str) -> None:
            nonlocal phase
            phase = f"{step} {detail}"
            bar.update(0.0, phase)

        profile = measure(
            duration_s=duration,
            restorer=Restorer(Watchdog().start()),
            progress=tell,
            each_second=lambda elapsed: bar.update(min(elapsed, duration), phase),
        )
    replace_file(out, profile_text(profile))
    stdout_console().print(
        f"{out}: switch {profile.switch_ms:.4f} ms, hop {profile.hop_ms:.4f} ms (p95), "
        f"enforcer {profile.wake_ms:.4f} ms per wake-up, "
        f"overhead {max(profile.overhead):.2%} of a core, RT limit {profile.rt.share:.0%}",
        markup=False,
    )


@reporting
def set_cores_(
    cores: Annotated[int, typer.Argument(min=1, help="Cores the running app may use from now on.")],
    socket: Annotated[Path, typer.Option(help="The enforcer's socket (as given to catanc run --socket).")],
) -> None:
    """Tell a running `catanc run` to re-plan for another number of cores (Stage I again, then re-pinning)."""
    from catanc.client import ClientError, set_cores
    from catanc.errors import UsageError

    try:
        set_cores(cores, str(socket))
    except ClientError as exc:
        raise UsageError(str(exc)) from None


@reporting
def report(
    log: Annotated[Path, typer.Argument(metavar="LOG", help="A `catanc run` log (JSON lines).", show_default=False)],
    plot: Annotated[Path | None, typer.Option(metavar="FILE.png", help="Also draw a timeline plot (PNG).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Summarise a `catanc run` log: rates, latencies, compute times, re-plans; optionally plot a timeline."""
    from catanc.extras import require
    from catanc.runtime.logs.report import report_command

    if plot is not None:
        require("matplotlib", "catanc report --plot")
    report_command(log, plot, as_json)
