"""``catanc init``: write a commented starter spec (kept apart from main.py: it needs no planner)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from catanc.cli.common import reporting
from catanc.spec.starter import DEFAULT_APP


@reporting
def init(
    app_name: Annotated[str, typer.Option("--app", metavar="NAME", help="The app's name.")] = DEFAULT_APP,
    out: Annotated[
        Path | None, typer.Option("--out", metavar="FILE", help="The spec file to write (default: NAME.yaml).")
    ] = None,
) -> None:
    """Write a commented starter spec (three nodes, a chain, a rate cap, a baseline) to edit into yours."""
    from catanc.artifacts.output import create_file
    from catanc.spec.starter import starter_spec

    path = out if out is not None else Path(f"{app_name}.yaml")
    create_file(path, starter_spec(app_name, str(path)))
    sys.stdout.write(f"{path}: written (app {app_name}); next: catanc validate {path}\n")
