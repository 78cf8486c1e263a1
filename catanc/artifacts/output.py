"""The I/O edge of ``catanc compile``: write, dry-run or compare an output folder.

All three take the emit stage's ``{relative path: text}`` and share its
bytes.  Writing is all or nothing: the files go to a staging folder beside
the target, which then replaces the target in one ``rename`` (an atomic
exchange with ``renameat2`` where the file system has it), so an
interrupted compile leaves the old folder or the new one, never a mix.  A
folder holding anything catanc did not write is never replaced: a user's
file is never lost.  The one exception is a ``__pycache__`` folder, which
Python writes next to ``launch.py`` when ``ros2 launch`` imports it: a cache,
neither compared nor kept.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import difflib
import errno
import glob
import os
import shutil
import stat
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

from catanc.artifacts.emit import EXECUTABLE, GENERATED
from catanc.errors import NotCompiledError, OutputBlockedError, OutputError, UsageError

CACHE_FOLDERS = frozenset({"__pycache__"})
"""Folders Python writes beside launch.py: never a change for ``--check``, dropped when the folder is replaced."""


class Status(Enum):
    NEW = "new"
    CHANGED = "changed"
    MISSING = "missing"  # expected, not in the folder
    EXTRA = "extra"  # in the folder, not expected
    UNCHANGED = "unchanged"


@dataclass(frozen=True)
class Comparison:
    """How a folder differs from what would be written there."""

    folder: Path
    exists: bool
    statuses: dict[str, Status]  # per file name, sorted
    diffs: dict[str, str] = field(default_factory=dict)  # unified diffs of changed, new and missing files

    @property
    def current(self) -> bool:
        return self.exists and all(status is Status.UNCHANGED for status in self.statuses.values())

    def of(self, status: Status) -> list[str]:
        return [name for name, found in self.statuses.items() if found is status]


# --------------------------------------------------------------------------- reading


def _read_folder(folder: Path) -> dict[str, tuple[bytes, bool]] | None:
    """``{name: (bytes, executable)}`` of the folder's entries; None if there is no folder.

    Raises :class:`OutputBlockedError` when the path is not a plain folder of
    plain files (a file, a symbolic link, a sub-folder is in the way).
    """
    try:
        info = folder.lstat()
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        raise _file_in_the_way(folder) from None
    except OSError as exc:
        raise OutputError(f"{folder}: cannot read the output folder: {exc.strerror or exc}") from None
    if stat.S_ISLNK(info.st_mode):
        raise OutputBlockedError(
            f"{folder}: is a symbolic link; catanc replaces its output folder as a whole, so point --out at a folder"
        )
    if not stat.S_ISDIR(info.st_mode):
        raise OutputBlockedError(f"{folder}: a file is in the way of the output folder; move it or pick another --out")
    found: dict[str, tuple[bytes, bool]] = {}
    try:
        for entry in sorted(os.scandir(folder), key=lambda e: e.name):
            mode = entry.stat(follow_symlinks=False).st_mode
            if entry.name in CACHE_FOLDERS and stat.S_ISDIR(mode):
                continue  # a file or link of that name is still someone's, reported as extra
            if not stat.S_ISREG(mode):
                found[entry.name] = (b"", False)  # reported as extra; never read
                continue
            found[entry.name] = (Path(entry.path).read_bytes(), bool(mode & stat.S_IXUSR))
    except OSError as exc:
        raise OutputError(f"{folder}: cannot read the output folder: {exc.strerror or exc}") from None
    return found


def _file_in_the_way(folder: Path) -> OutputBlockedError:
    above = next((parent for parent in folder.parents if parent.exists() and not parent.is_dir()), None)
    what = f"{above} is a file" if above is not None else "a parent is a file"
    return OutputBlockedError(f"{folder}: a file is in the way of the output folder ({what})")


def compare(folder: Path, files: Mapping[str, str], *, with_diffs: bool = False) -> Comparison:
    """How ``folder`` differs from ``files`` (no folder: every file is new)."""
    existing = _read_folder(folder)
    statuses: dict[str, Status] = {}
    diffs: dict[str, str] = {}
    for name in sorted({*files, *(existing or {})}):
        wanted = files.get(name)
        have = (existing or {}).get(name)
        if wanted is None:
            statuses[name] = Status.EXTRA
            continue
        if have is None:
            statuses[name] = Status.NEW if existing is None else Status.MISSING
            old_text = ""
        else:
            old_text = have[0].decode("utf-8", errors="replace")
            same = have[0] == wanted.encode("utf-8") and have[1] == (name in EXECUTABLE)
            statuses[name] = Status.UNCHANGED if same else Status.CHANGED
        if with_diffs and statuses[name] is not Status.UNCHANGED:
            diffs[name] = _diff(folder / name, old_text, wanted, have is not None)
    return Comparison(folder, existing is not None, statuses, diffs)


def _diff(path: Path, old: str, new: str, existed: bool) -> str:
    lines = difflib.unified_diff(
        old.splitlines(keepends=True),
        new.splitlines(keepends=True),
        fromfile=f"{path} (on disk)" if existed else "/dev/null",
        tofile=f"{path} (generated)",
    )
    text = "".join(line if line.endswith("\n") else line + "\n\\ No newline at end of file\n" for line in lines)
    if not text and existed:  # same text: only the executable bit differs
        text = f"{path}: should be executable\n"
    return text


# --------------------------------------------------------------------------- writing


def write(folder: Path, files: Mapping[str, str]) -> Comparison:
    """Make ``folder`` hold exactly ``files``, atomically; returns what changed (nothing written if nothing did)."""
    before = compare(folder, files)
    foreign = [name for name in before.of(Status.EXTRA) if name not in GENERATED]
    if foreign:
        raise OutputBlockedError(
            f"{folder}: holds files catanc did not write ({', '.join(foreign)}); the output folder is replaced as "
            "a whole, so move them away or pick another --out"
        )
    if before.current:
        return before
    parent = folder.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise _file_in_the_way(folder) from None
    except OSError as exc:
        raise OutputError(f"{parent}: cannot create the output folder's parent: {exc.strerror or exc}") from None
    _remove_leftovers(folder)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.{os.getpid()}.", suffix=".partial", dir=parent))
    except OSError as exc:
        raise OutputError(f"{parent}: cannot write here: {exc.strerror or exc}") from None
    try:
        _fill(staging, files)
        _swap_in(staging, folder, replace=before.exists)
    except OSError as exc:
        raise OutputError(f"{folder}: cannot write the output folder: {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # after a swap it holds the old folder
    _sync(parent)
    return before


def _remove_leftovers(folder: Path) -> None:
    """Remove the staging folders of earlier writes of ``folder`` whose process is gone (a killed compile's).

    A staging folder is named ``.<folder>.<pid>.<random>.partial`` (``.old`` added while swapping),
    so one whose process still runs (a compile going on beside this one) is left alone.
    """
    prefix = f".{folder.name}."
    for entry in folder.parent.glob(f"{glob.escape(prefix)}*.partial*"):
        middle = entry.name[len(prefix) :].split(".", 1)[0]
        if not middle.isdigit() or _alive(int(middle)) or not entry.is_dir() or entry.is_symlink():
            continue
        shutil.rmtree(entry, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _fill(staging: Path, files: Mapping[str, str]) -> None:
    umask = _umask()
    for name, text in files.items():
        path = staging / name
        path.write_bytes(text.encode("utf-8"))
        path.chmod((0o777 if name in EXECUTABLE else 0o666) & ~umask)
        _sync(path)
    staging.chmod(0o777 & ~umask)  # mkdtemp made it private
    _sync(staging)


def _umask() -> int:
    current = os.umask(0o022)
    os.umask(current)
    return current


def _sync(path: Path) -> None:
    """Flush a file or folder to disk, so a crash right after a rename cannot leave empty files."""
    flags = os.O_RDONLY | (os.O_DIRECTORY if path.is_dir() else 0)
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _swap_in(staging: Path, folder: Path, *, replace: bool) -> None:
    """Put ``staging`` at ``folder``; the old folder (if any) ends up at ``staging``."""
    if not replace:
        staging.rename(folder)  # fails if a folder appeared meanwhile, rather than mixing
        staging.mkdir()  # for the caller's clean-up
        return
    if _exchange(staging, folder):
        return
    # No atomic exchange here: two renames; between them the folder is briefly absent, never mixed.
    backup = staging.with_name(staging.name + ".old")
    folder.rename(backup)
    try:
        staging.rename(folder)
    except OSError:
        backup.rename(folder)
        raise
    backup.rename(staging)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically with Linux's ``renameat2``; False where it is not available."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    libc = ctypes.CDLL(libc_name, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is None:
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def ensure_comparable(comparison: Comparison) -> None:
    """``--check`` needs a folder to compare with."""
    if not comparison.exists:
        raise NotCompiledError(
            f"{comparison.folder}: no output folder to check; run the same command without --check to create it"
        )


def create_file(path: Path, text: str) -> None:
    """Write a new file atomically: all of ``text`` or nothing, and never over an existing file.

    The text goes to a temporary file beside ``path``, flushed to disk, then
    hard-linked to ``path``: the link fails if ``path`` exists, even if it
    appeared a moment ago, so a user's file is never replaced.
    """
    if path.exists() or path.is_symlink():
        raise UsageError(f"{path}: already exists; catanc does not overwrite it (choose another name with --out)")
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"{parent}: no such folder")
    try:
        staging = _staged(parent, path.name, text, 0o666 & ~_umask())
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        os.link(staging, path)
    except FileExistsError:
        raise UsageError(f"{path}: already exists; catanc does not overwrite it") from None
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        staging.unlink(missing_ok=True)
    _sync(parent)


def replace_file(path: Path, text: str) -> None:
    """Replace ``path``'s text atomically (or create it): the old file or all of ``text``, never a mix.

    The text goes to a temporary file beside it, flushed to disk, with the old file's mode (a new
    file's from the umask), then replaces it in one rename.  A symbolic link to the file: its
    target is replaced and the link stays.  :class:`~catanc.errors.OutputError` naming ``path``
    if it cannot be written; no temporary file is left behind.
    """
    target = path.resolve()
    try:
        mode = target.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        staging = _staged(target.parent, target.name, text, mode)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        staging.replace(target)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        staging.unlink(missing_ok=True)
    _sync(target.parent)


def _staged(parent: Path, name: str, text: str, mode: int) -> Path:
    """``text`` in a new temporary file in ``parent`` (named after ``name``), flushed to disk, with ``mode``."""
    fd, staging = tempfile.mkstemp(dir=parent, prefix=f".{name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(text.encode("utf-8"))
            handle.flush()
            os.fsync(handle.fileno())
        Path(staging).chmod(mode)  # mkstemp made it private
    except BaseException:
        Path(staging).unlink(missing_ok=True)
        raise
    return Path(staging)
