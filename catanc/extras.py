"""Optional dependencies: the extra that installs each, and a clear error when one is missing.

``pip install catanc`` plans and compiles; the simulator's compiled loop
needs numba (a dependency; ``catanc[sim]`` names it too) and the plots need matplotlib
(``catanc[plot]``).  A command that needs one calls :func:`require` before
it starts work, so a missing extra is one line naming the fix, exit code 2.
"""

from __future__ import annotations

import importlib

from catanc.errors import MissingExtraError

EXTRA_OF = {"numba": "sim", "matplotlib": "plot"}
"""Module -> the extra of pyproject.toml that installs it."""


def require(module: str, needed_by: str) -> None:
    """Import ``module``; raise :class:`MissingExtraError` naming its extra if it is not installed."""
    try:
        importlib.import_module(module)
    except ImportError:
        extra = EXTRA_OF[module]
        raise MissingExtraError(
            f"{needed_by} needs {module}, which is not installed: pip install 'catanc[{extra}]'"
        ) from None
