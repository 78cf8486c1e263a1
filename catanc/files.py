"""Small files written whole and atomically: a temporary file beside the target, synced, renamed over it.

``catanc simulate --plot`` and ``catanc bench --plot`` write their PNGs so, ``catanc bench --log``
its enforcer logs: an interrupted write leaves the old file or none, never half of one.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

from catanc.errors import OutputError


def write_files(folder: Path, files: Mapping[str, bytes], kind: str = "plot", mode: int = 0o666) -> list[Path]:
    """Write each file into ``folder`` (created if missing) atomically, with ``mode`` less the umask; ``kind``
    names them in errors."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{folder}: not a folder") from None
    except OSError as exc:
        raise OutputError(f"{folder}: cannot create the {kind} folder: {exc.strerror or exc}") from None
    written = []
    for name, data in files.items():
        path = folder / name
        try:
            _replace(path, data, mode)
        except OSError as exc:
            raise OutputError(f"{path}: cannot write the {kind}: {exc.strerror or exc}") from None
        written.append(path)
    return written


def _replace(path: Path, data: bytes, mode: int) -> None:
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        umask = os.umask(0o022)
        os.umask(umask)
        Path(temporary).chmod(mode & ~umask)  # mkstemp made it private
        Path(temporary).replace(path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
