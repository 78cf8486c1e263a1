"""The ``catanc`` command line: parse options, call the core, map errors to exit codes.

One module per group of commands (:mod:`catanc.cli.init_command`, :mod:`catanc.cli.spec`,
:mod:`catanc.cli.planning`, :mod:`catanc.cli.runtime`, :mod:`catanc.cli.clients`, :mod:`catanc.cli.profile`,
:mod:`catanc.cli.compare`), each importing what it needs when it runs, so
that ``validate`` loads no solver; :mod:`catanc.cli.common` holds what they
share.  Here they are registered, in the order ``--help`` lists them.
"""

from __future__ import annotations

import sys

import typer

from catanc.cli import clients, compare, planning, profile, runtime, spec
from catanc.cli.common import reporting
from catanc.cli.init_command import init

app = typer.Typer(
    name="catanc",
    help="Compile semantic specs of robotics and XR task graphs into CPU schedules.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def version() -> None:
    """Print catanc's version."""
    from catanc import __version__

    sys.stdout.write(f"catanc {__version__}\n")


app.command(name="init")(reporting(init))
app.command()(spec.validate)
app.command()(spec.chains)
app.command()(planning.allocate)
app.command()(planning.explain)
app.command(name="compile")(planning.compile_)
app.command(name="run")(runtime.run_)
app.command()(runtime.doctor)
app.command()(runtime.calibrate)
app.command(name="set-cores")(runtime.set_cores_)
app.command()(runtime.report)
app.command()(clients.client)
app.command()(profile.profile)
app.command()(compare.simulate)
app.command()(compare.bench)
app.command()(spec.schema)
app.command()(version)


def main() -> None:
    """Console-script entry point."""
    app()
