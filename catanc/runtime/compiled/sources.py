"""The sources the compiled walk is compiled from: numba's cache of it and the object file's stamp depend on them.

Standard library only: ``catanc run`` checks the stamp (:mod:`catanc.runtime.compiled.ready`) before
it may import numpy.
"""

from __future__ import annotations

from pathlib import Path

_COMPILED = Path(__file__).parent
_PACKAGE = _COMPILED.parent.parent

SOURCES = (
    *(_COMPILED / name for name in ("walk.py", "arrays.py", "build.py")),
    *(_PACKAGE / "control" / name for name in ("compiled_policy.py", "slot_table.py")),  # the slot rule
    _PACKAGE / "control" / "measure.py",  # constants compiled in
    _PACKAGE / "runtime" / "protocol" / "ring.py",
    _PACKAGE / "runtime" / "enforcer" / "runs.py",
    _PACKAGE / "model" / "priorities.py",
)
"""The walk's own module first; then what its compiled code calls or takes constants from."""
