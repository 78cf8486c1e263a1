"""Whether this machine has the compiled loop built, building it off the enforcer's path, and loading it.

numba compiles the loop (:mod:`catanc.runtime.compiled.walk`, behind the C entry of
:mod:`catanc.runtime.compiled.build`) into an object file once per machine and catanc version:
about a minute of one CPU.  ``catanc run`` then links that file in without numba
(:class:`~catanc.runtime.compiled.entry.WalkEntry`: ~0.03 s of CPU).  Its default (``--loop
auto``) takes the compiled loop only where the file is built, so a run never spends the minute
before its socket is up (nodes give up after 5 s); elsewhere it runs the Python loop and builds
the file in a child process at SCHED_OTHER, nice 19, for the next run.

Beside the object file a *stamp* says what it was built for: numba's and llvmlite's versions,
Python's, the CPU (the code uses its features), a digest of the modules compiled, and the file's
size, digest, entry symbol and the walk's layout.  A stamp that no longer matches (an upgrade, an
edit, another CPU, a changed or missing file) is "not built", and so is a stamp or object file
that someone other than this user or root could have written (:func:`read_own`).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import hashlib
import importlib.metadata
import json
import os
import platform
import signal
import stat
import subprocess
import sys
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from catanc.errors import LoopError, OutputError
from catanc.files import write_files
from catanc.runtime.compiled import sources as compiled_sources

if TYPE_CHECKING:  # the entry imports numpy, which the enforcer must not before its planner's fork
    from catanc.runtime.compiled.entry import Layout, WalkEntry

CACHE_ENV = "CATANC_CACHE_DIR"
"""A folder for the stamp instead of the default places (tests; read-only installs)."""

STAMP_NAME = "compiled_walk.ready.json"
OBJECT_NAME = "compiled_walk.o"
SOURCES = compiled_sources.SOURCES  # what the object file is compiled from
PR_SET_PDEATHSIG = 1
CPU_FIELDS = ("model name", "flags", "Features", "CPU implementer", "CPU part")  # x86-64 and aarch64


LoopChoice = Literal["auto", "compiled", "python"]
"""``catanc run --loop``: see :meth:`catanc.runtime.enforcer.run.Enforcer._compiled_loop`."""


class LoopState(Enum):
    READY = "ready"  # built: loads in ~0.03 s
    UNBUILT = "unbuilt"  # numba is here, the loop's object file is not (or is stale)
    NO_NUMBA = "no numba"  # the Python loop only


def stamp_folders() -> list[Path]:
    """Where the object file and its stamp may be, in order: ``$CATANC_CACHE_DIR`` alone if set; else beside the
    source (an install this user may write), then the user's cache folder."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen:
        return [Path(chosen)]
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "catanc"
    return [SOURCES[0].parent / "__pycache__", user]


def version_of(package: str) -> str | None:
    """An installed package's version (read from its metadata: it is not imported), None if it is not installed."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def cpu_identity(cpuinfo: str) -> str:
    """A digest of the first CPU's model and flags in ``/proc/cpuinfo``'s text (numba compiles for the host CPU)."""
    first: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip() and first:
            break  # the first processor's block ends
        name, _, value = line.partition(":")
        if name.strip() in CPU_FIELDS:
            first.setdefault(name.strip(), value.strip())
    return hashlib.sha256(json.dumps(first, sort_keys=True).encode()).hexdigest()[:16]


def machine_key(numba: str) -> dict[str, Any]:
    """What the object file depends on, here and now (``numba``: its version)."""
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        cpuinfo = ""
    sources = hashlib.sha256()
    for source in SOURCES:
        sources.update(source.read_bytes())
    return {
        "numba": numba,
        "llvmlite": version_of("llvmlite"),
        "python": sys.version,
        "machine": platform.machine(),
        "cpu": cpu_identity(cpuinfo),
        "sources": sources.hexdigest(),
    }


def read_own(path: Path) -> bytes | None:
    """``path``'s bytes if it is a file (not a link) of this user's or root's that no one else may write; else None.

    The object file is machine code ``catanc run`` executes, often as root and at SCHED_FIFO: one that another
    user could have written (or swapped in, in a folder others may write) is never read."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_uid not in {0, os.geteuid()} or info.st_mode & 0o022:
            return None
        with os.fdopen(fd, "rb", closefd=False) as stream:
            return stream.read()
    except OSError:
        return None
    finally:
        os.close(fd)


def _built(stamp: dict[str, Any], key: dict[str, Any], folder: Path) -> tuple[bytes, str, Layout] | None:
    """The object file ``stamp`` (a parsed stamp file in ``folder``) names, if it was built for ``key`` and is as
    built: its bytes, entry symbol and walk layout."""
    symbol, layout, digest = stamp.get("symbol"), stamp.get("layout"), stamp.get("sha256")
    if stamp.get("key") != key or not isinstance(symbol, str) or not isinstance(layout, list):
        return None
    code = read_own(folder / OBJECT_NAME)
    if code is None or hashlib.sha256(code).hexdigest() != digest:
        return None
    try:
        return code, symbol, tuple((str(dtype), int(ndim)) for dtype, ndim in layout)
    except (TypeError, ValueError):
        return None


def find() -> tuple[bytes, str, Layout] | None:
    """The compiled loop's object file built for this machine (its bytes, entry symbol, walk layout), or None."""
    numba = version_of("numba")
    if numba is None:
        return None
    key = machine_key(numba)
    for folder in stamp_folders():
        text = read_own(folder / STAMP_NAME)
        try:
            stamp = json.loads(text) if text is not None else None
        except ValueError:
            continue
        found = _built(stamp, key, folder) if isinstance(stamp, dict) else None
        if found is not None:
            return found
    return None


def state() -> LoopState:
    """Whether the compiled loop is built on this machine (numba is not imported)."""
    if version_of("numba") is None:
        return LoopState.NO_NUMBA
    return LoopState.READY if find() is not None else LoopState.UNBUILT


def load(found: tuple[bytes, str, Layout] | None = None) -> WalkEntry:
    """The compiled loop's entry (``found``, or what :func:`find` finds), linked into this process; :class:`LoopError`
    if it is not built or does not link."""
    from catanc.runtime.compiled.entry import WalkEntry  # noqa: PLC0415 - numpy and LLVM only where it runs

    found = found or find()
    if found is None:
        raise LoopError("the compiled loop is not built on this machine")
    return WalkEntry(*found)


def write_built(code: bytes, symbol: str, layout: Layout) -> Path | None:
    """Write the object file ``code`` and its stamp (atomically, the file first, in the first stamp folder that takes
    them): the stamp, or None where no folder does (the next run builds again)."""
    numba = version_of("numba")
    if numba is None:
        return None
    stamp = {
        "key": machine_key(numba),
        "layout": [list(field) for field in layout],
        "sha256": hashlib.sha256(code).hexdigest(),
        "symbol": symbol,
    }
    text = json.dumps(stamp, sort_keys=True) + "\n"
    files = {OBJECT_NAME: code, STAMP_NAME: text.encode()}  # the object first: a stamp never names an older file
    for folder in stamp_folders():
        with contextlib.suppress(OutputError):  # 0644 whatever the umask: read_own refuses files others may write
            return write_files(folder, files, kind="compiled loop", mode=0o644)[1]
    return None


def build() -> tuple[WalkEntry, Path | None]:
    """Compile the loop's object file, link it into this process and write it with its stamp: the entry, and the
    stamp or None (:func:`write_built`).  A file that does not link is not written (:class:`LoopError`).

    Imports numba: call it at SCHED_OTHER, never from a real-time thread."""
    from catanc.runtime.compiled.build import object_code  # noqa: PLC0415 - numba's import
    from catanc.runtime.compiled.entry import WalkEntry  # noqa: PLC0415 - as in load

    code, symbol, layout = object_code()
    entry = WalkEntry(code, symbol, layout)
    return entry, write_built(code, symbol, layout)


class BackgroundBuild:
    """A child process building the compiled loop for the next run; ended with its parent, whatever happens."""

    def __init__(self) -> None:
        argv = [sys.executable, "-m", "catanc.runtime.compiled.ready", str(os.getpid())]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        self.process: subprocess.Popen[bytes] | None = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env
        )

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process is not None else None

    def stop(self) -> None:
        """End the build if it is still running (each file is written whole, the stamp last: nothing half-written
        stays)."""
        process, self.process = self.process, None
        if process is None:
            return
        if process.poll() is None:
            process.kill()
        process.wait()


def _die_with(parent: int) -> bool:
    """SIGKILL this process when its parent exits (the kernel's parent-death signal); False if it is gone already."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    return os.getppid() == parent


def _build_in_background(parent: int) -> int:
    """The child of :class:`BackgroundBuild`: at SCHED_OTHER and nice 19, one build at a time per stamp folder."""
    if not _die_with(parent):
        return 0
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(OSError):
        os.nice(19)
    for folder in stamp_folders():  # the lock beside the first stamp folder this user may write
        try:
            folder.mkdir(parents=True, exist_ok=True)
            lock = os.open(folder / (STAMP_NAME + ".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError:
            continue
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return 0  # another build holds it: that one will stamp
        try:
            _, stamp = build()
        except LoopError:
            return 1
        return 0 if stamp is not None else 1
    return 1  # nowhere to write a stamp


if __name__ == "__main__":
    sys.exit(_build_in_background(int(sys.argv[1])))
