"""The ``catanc`` command line: parse options, call the core, map errors to exit codes.

One module per group of commands (:mod:`catanc.cli.init_command`, :mod:`catanc.cli.spec`,
:mod:`catanc.cli.planning`, :mod:`catanc.cli.runtime`, :mod:`catanc.cli.clients`, :mod:`catanc.cli.profile`,
:mod:`catanc.cli.compare`), each importing what it needs when it runs, so
that ``validate`` loads no solver; :mod:`catanc.cli.common` holds what they
share.  :data:`COMMANDS` lists them in the order ``--help`` shows them.

A command's module is imported, and typer turns its function into a click
command, only when the command is looked up: to run it, or for ``--help``,
which lists them all.  So ``catanc validate`` loads no other command's module
and pays typer's reading of no other command's parameters.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Mapping
from types import ModuleType
from typing import Any

import typer
import typer.main
from typer.core import TyperGroup

COMMANDS: dict[str, tuple[str, str]] = {
    # name: (module in catanc.cli, its function), in the order --help lists them
    "init": ("init_command", "init"),
    "validate": ("spec", "validate"),
    "chains": ("spec", "chains"),
    "allocate": ("planning", "allocate"),
    "explain": ("planning", "explain"),
    "compile": ("planning", "compile_"),
    "run": ("runtime", "run_"),
    "doctor": ("runtime", "doctor"),
    "calibrate": ("runtime", "calibrate"),
    "set-cores": ("runtime", "set_cores_"),
    "report": ("runtime", "report"),
    "client": ("clients", "client"),
    "profile": ("profile", "profile"),
    "simulate": ("compare", "simulate"),
    "bench": ("compare", "bench"),
    "schema": ("spec", "schema"),
    "version": ("main", "version"),
}


def version() -> None:
    """Print catanc's version."""
    from catanc import __version__

    sys.stdout.write(f"catanc {__version__}\n")


def commands_module(name: str) -> ModuleType:
    """The module of commands ``name`` (a :data:`COMMANDS` module), imported now.

    Each import is spelt out, not made from the name, so that the import
    graph (``tests/test_layers.py``, ``import_cycles.py``) sees every edge.
    """
    if name == "init_command":
        from catanc.cli import init_command

        return init_command
    if name == "spec":
        from catanc.cli import spec

        return spec
    if name == "planning":
        from catanc.cli import planning

        return planning
    if name == "runtime":
        from catanc.cli import runtime

        return runtime
    if name == "clients":
        from catanc.cli import clients

        return clients
    if name == "profile":
        from catanc.cli import profile

        return profile
    if name == "compare":
        from catanc.cli import compare

        return compare
    if name == "main":
        return sys.modules[__name__]
    raise ValueError(f"no module of commands {name!r}")


def command_function(name: str) -> Callable[..., Any]:
    """The function of command ``name``, importing its module only."""
    module, function = COMMANDS[name]
    found: Callable[..., Any] = getattr(commands_module(module), function)
    return found


class LazyCommands(Mapping[str, Any]):
    """The group's commands by name, each built (imported, read by typer) when first looked up.

    Names and their order come from :data:`COMMANDS` without importing
    anything, so a misspelt command is still answered with suggestions.
    """

    def __init__(self) -> None:
        self._built: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        if name not in COMMANDS:
            raise KeyError(name)
        if name not in self._built:
            one = typer.Typer(add_completion=False)
            one.command(name=name)(command_function(name))
            self._built[name] = typer.main.get_command(one)
        return self._built[name]

    def __iter__(self) -> Iterator[str]:
        return iter(COMMANDS)

    def __len__(self) -> int:
        return len(COMMANDS)


class CatancGroup(TyperGroup):
    """``catanc``'s group of commands: :class:`LazyCommands` instead of every command built up front."""

    def __init__(self, **settings: Any) -> None:
        super().__init__(**settings)
        self.commands = LazyCommands()  # type: ignore[assignment]  # read-only: nothing adds commands later

    def list_commands(self, ctx: Any) -> list[str]:  # noqa: ARG002 - click's signature
        return list(self.commands)


def catanc() -> None:
    """Compile semantic specs of robotics and XR task graphs into CPU schedules."""


app = typer.Typer(
    name="catanc",
    cls=CatancGroup,
    callback=catanc,  # a group with no commands registered up front needs a callback; it has nothing to do
    help=catanc.__doc__,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def main() -> None:
    """Console-script entry point."""
    app()
