"""Commands that compare catanc's plan with the baselines: ``simulate`` (simulated) and ``bench`` (measured)."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from catanc.cli.common import (
    CoresOpt,
    LoopOpt,
    MachineOpt,
    PlotDirOpt,
    QuietOpt,
    SpecArg,
    TablesJsonOpt,
    WorkloadSeedOpt,
    load_problem,
    loop_option,
    reporting,
    stderr_console,
    stdout_console,
)
from catanc.text import plural

if TYPE_CHECKING:
    from catanc.sim.metrics import PolicyResult
    from catanc.spec.language import Spec


@reporting
def simulate(
    spec_path: SpecArg,
    cores: CoresOpt,
    policy: Annotated[
        list[str] | None,
        typer.Option(
            help="catan, catan-nosteal, baseline, fifo-static, static-fullrun or static-20s "
            "(repeat for several; default: all)."
        ),
    ] = None,
    duration: Annotated[float, typer.Option(min=0.1, help="Simulated seconds.")] = 60.0,
    seed: WorkloadSeedOpt = 0,
    as_json: TablesJsonOpt = False,
    plot: PlotDirOpt = None,
    quiet: QuietOpt = False,
    machine: MachineOpt = None,
) -> None:
    """Simulate the app on K cores under catanc's plan and the baselines; compare response times and rates."""
    from catanc.cli.progress import tracked
    from catanc.extras import require
    from catanc.sim.simulate import POLICIES, Setup, check_policies, simulate
    from catanc.spec.machine import apply_machine, read_machine

    require("numba", "catanc simulate")
    if plot is not None:
        require("matplotlib", "catanc simulate --plot")
    spec, _ = load_problem(spec_path)
    if machine is not None:  # the plan `catanc run` starts from on that machine: its costs raised
        spec, _ = apply_machine(spec, read_machine(machine))
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
        out = stdout_console()
        for table in comparison_tables(results):
            out.print(table)
    for path in written:
        (stderr_console() if as_json else stdout_console()).print(f"plot: {path}", markup=False)


@reporting
def bench(
    spec_path: SpecArg,
    cores: CoresOpt,
    policy: Annotated[
        list[str] | None,
        typer.Option(
            help="catan, catan-nosteal, baseline, fifo-static, static-fullrun or static-20s (repeat for several; "
            "default: catan, baseline and fifo-static)."
        ),
    ] = None,
    duration: Annotated[float, typer.Option(min=0.5, help="Measured seconds per policy.")] = 20.0,
    seed: WorkloadSeedOpt = 0,
    as_json: TablesJsonOpt = False,
    plot: PlotDirOpt = None,
    log: Annotated[
        Path | None,
        typer.Option(
            "--log",
            metavar="DIR",
            help="Also keep each enforced policy's run log in DIR (created if missing) as <policy>.jsonl, "
            "for catanc report, and every policy's worker records as <policy>.runs.jsonl.",
        ),
    ] = None,
    quiet: QuietOpt = False,
    loop: LoopOpt = "auto",
) -> None:
    """Run the app's synthetic workers on this machine under catanc's plan and the baselines; compare them."""
    from catanc.cli.progress import progress
    from catanc.errors import UsageError
    from catanc.extras import require
    from catanc.realbench.bench import DEFAULT_POLICIES, BenchSetup, bench_loop, bench_policies

    if plot is not None:
        require("matplotlib", "catanc bench --plot")
    loop_choice = loop_option(loop)
    for option, folder in (("--plot", plot), ("--log", log)):  # before minutes of runs, not after them
        if folder is not None and folder.exists() and not folder.is_dir():
            raise UsageError(f"{option} {folder}: not a folder")
    spec, _ = load_problem(spec_path)
    setup = BenchSetup(spec_path, spec, cores, duration, seed, log, loop=bench_loop(loop_choice))
    chosen = policy or list(DEFAULT_POLICIES)
    err = stderr_console()
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
