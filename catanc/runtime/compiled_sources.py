"""The sources the compiled walk is compiled from: numba's cache of it and the object file's stamp depend on them.

Standard library only: ``catanc run`` checks the stamp (:mod:`catanc.runtime.compiled_ready`) before
it may import numpy.
"""

from __future__ import annotations

from pathlib import Path

_RUNTIME = Path(__file__).parent
_PACKAGE = _RUNTIME.parent

SOURCES = (
    *(_RUNTIME / name for name in ("compiled_walk.py", "walk_arrays.py", "compiled_build.py")),
    *(_PACKAGE / "control" / name for name in ("compiled_policy.py", "slot_table.py")),  # the slot rule
    *(_RUNTIME / name for name in ("measure.py", "ring.py", "runs.py")),  # constants compiled in
    _PACKAGE / "core" / "priorities.py",
)
"""The walk's own module first; then what its compiled code calls or takes constants from."""
