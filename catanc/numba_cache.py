"""Removing numba's on-disk cache of a module when it is older than the module's source.

numba (0.68 at least) names a cached function's files by its name and
line number, and reads a cache index by unpickling it *before* checking that
it belongs to the current source.  After an edit, an upgrade or a branch
switch, a function may land on the line of an older one whose index pickled a
type that no longer exists, and the first call raises ``AttributeError: Can't
get attribute ...`` instead of recompiling (numba issue #10434 is the same
failure for a truncated file).  An index older than its source would be
rejected anyway, so removing it first changes nothing but the crash.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

CACHE_SUFFIXES = (".nbi", ".nbc")  # numba's index and data files


def drop_stale_cache(source: Path, depends_on: tuple[Path, ...] = ()) -> list[Path]:
    """Remove the numba cache files of ``source`` in its ``__pycache__`` that are older than it; the removed.

    ``depends_on``: the modules whose compiled functions or constants ``source``'s functions use.  numba
    checks only the stamp of a function's own file, so code compiled against an older one of these
    would be loaded as current: a cache file older than any of them goes too.

    Never raises: a file another process removed first, or a read-only install, leaves it as it is.
    """
    removed: list[Path] = []
    try:
        stamp = max(path.stat().st_mtime for path in (source, *depends_on))
        candidates = sorted((source.parent / "__pycache__").glob(f"{source.stem}.*"))
    except OSError:
        return removed
    for path in candidates:
        if path.suffix not in CACHE_SUFFIXES:
            continue
        with contextlib.suppress(OSError):
            if path.stat().st_mtime < stamp:
                path.unlink()
                removed.append(path)
    return removed
