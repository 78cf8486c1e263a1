"""The command line, ``catanc`` (the console script is ``catanc.cli:main``)."""

from catanc.cli.main import app, main

__all__ = ["app", "main"]
