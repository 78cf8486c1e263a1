"""``catanc client``: where the node clients are, for a build or a copy next to a node."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from catanc.cli.common import reporting


@reporting
def client(
    cflags: Annotated[
        bool, typer.Option("--cflags", help="Print the C++ compiler flags for #include <catanc/client.hpp>.")
    ] = False,
    python: Annotated[
        bool, typer.Option("--python", help="Print the path of the Python client (one file, Python 3.8+).")
    ] = False,
    ros: Annotated[
        bool,
        typer.Option("--ros", help="Print the path of catanc.ros (rclpy nodes; one file beside the Python client)."),
    ] = False,
) -> None:
    """Where the node clients are: the C++ header's include flags, the standalone Python client's file, or the
    rclpy integration's (copy it as catanc_ros.py next to the client copied as catanc_client.py)."""
    import catanc.client
    from catanc.errors import UsageError

    if cflags + python + ros != 1:
        raise UsageError(
            "give one of --cflags (the C++ client), --python (the Python client) or --ros (its rclpy integration)"
        )
    package = Path(catanc.client.__file__).resolve().parent
    if cflags:
        include = package / "include"
        if not (include / "catanc" / "client.hpp").is_file():
            raise UsageError(f"the C++ client is missing from this installation (no {include}/catanc/client.hpp)")
        sys.stdout.write(f"-I{include}\n")
    elif ros:
        sys.stdout.write(f"{package / 'ros.py'}\n")  # not imported: printing its path needs no rclpy
    else:
        sys.stdout.write(f"{package / 'client.py'}\n")
