"""Whether this machine has the compiled loop built, and building it off the enforcer's path.

numba compiles the loop (:mod:`catanc.runtime.compiled_walk`) once per machine and catanc version:
about a minute of one CPU, then ~0.6 s to load from its on-disk cache.  ``catanc run``'s default
(``--loop auto``) takes the compiled loop only where that cache is known to be there, so a run never
spends the minute before its socket is up (nodes give up after 5 s); elsewhere it runs the Python
loop and builds the cache in a child process at SCHED_OTHER, nice 19, for the next run.

numba cannot say whether a function is in its cache without loading it, so a *stamp* file says so:
written after a process loaded (or compiled) the loop, it names what numba keys its cache on (its
version, Python's, the CPU, the source file's size and time) and the cache files numba wrote, with
their sizes and times.  A stamp that no longer matches (an upgrade, an edit, a deleted
``__pycache__``, another CPU) is "not built".
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
import subprocess
import sys
from collections.abc import Iterator
from enum import Enum
from pathlib import Path
from typing import Any, Literal

from catanc.errors import OutputError
from catanc.files import write_files

CACHE_ENV = "CATANC_CACHE_DIR"
"""A folder for the stamp instead of the default places (tests; read-only installs)."""

STAMP_NAME = "compiled_walk.ready.json"
SOURCE = Path(__file__).with_name("compiled_walk.py")  # the module numba compiles and keys its cache on
NUMBA_FILES = (".nbi", ".nbc")
PR_SET_PDEATHSIG = 1
CPU_FIELDS = ("model name", "flags", "Features", "CPU implementer", "CPU part")  # x86-64 and aarch64


LoopChoice = Literal["auto", "compiled", "python"]
"""``catanc run --loop``: see :meth:`catanc.runtime.enforcer.Enforcer._compiled_loop`."""


class LoopState(Enum):
    READY = "ready"  # built: loads in ~0.6 s
    UNBUILT = "unbuilt"  # numba is here, its cache of the loop is not (or is stale)
    NO_NUMBA = "no numba"  # the Python loop only


def stamp_folders() -> list[Path]:
    """Where a stamp may be, in order: ``$CATANC_CACHE_DIR`` alone if set; else beside the source (where numba
    caches when it may write there), then the user's cache folder (where numba caches otherwise)."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen:
        return [Path(chosen)]
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "catanc"
    return [SOURCE.parent / "__pycache__", user]


def numba_version() -> str | None:
    """The installed numba's version (read from its metadata: numba is not imported), None without numba."""
    try:
        return importlib.metadata.version("numba")
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
    """What numba's cache of the loop depends on, here and now (``numba``: its version)."""
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        cpuinfo = ""
    source = SOURCE.stat()
    return {
        "numba": numba,
        "python": sys.version,
        "machine": platform.machine(),
        "cpu": cpu_identity(cpuinfo),
        "source": [source.st_mtime_ns, source.st_size],
    }


def _file_stats(folder: Path) -> dict[str, list[int]]:
    """numba's cache files of the loop's module in ``folder``: name -> [mtime_ns, size]."""
    stats: dict[str, list[int]] = {}
    for path in sorted(folder.glob(f"{SOURCE.stem}.*")):
        if path.suffix in NUMBA_FILES:
            with contextlib.suppress(OSError):
                stat = path.stat()
                stats[path.name] = [stat.st_mtime_ns, stat.st_size]
    return stats


def stamp_matches(stamp: dict[str, Any], key: dict[str, Any]) -> bool:
    """Whether ``stamp`` (a parsed stamp file) was written for ``key`` and its cache files are still as written."""
    if stamp.get("key") != key:
        return False
    files = stamp.get("files")
    folder = stamp.get("folder")
    if not isinstance(files, dict) or not files or not isinstance(folder, str):
        return False
    now = _file_stats(Path(folder))
    return all(now.get(name) == stat for name, stat in files.items())


def state() -> LoopState:
    """Whether the compiled loop is built on this machine (a few stat calls: numba is not imported)."""
    numba = numba_version()
    if numba is None:
        return LoopState.NO_NUMBA
    key = machine_key(numba)
    for folder in stamp_folders():
        try:
            stamp = json.loads((folder / STAMP_NAME).read_text())
        except (OSError, ValueError):
            continue
        if isinstance(stamp, dict) and stamp_matches(stamp, key):
            return LoopState.READY
    return LoopState.UNBUILT


def write_stamp(cache_folder: Path) -> Path | None:
    """Record that this process has the loop from numba's cache in ``cache_folder``: the stamp written (atomically,
    in the first stamp folder that takes it), or None where none does (the next run builds again)."""
    numba = numba_version()
    files = _file_stats(cache_folder)
    if numba is None or not files:
        return None
    stamp = {"key": machine_key(numba), "folder": str(cache_folder), "files": files}
    text = json.dumps(stamp, indent=1, sort_keys=True) + "\n"
    for folder in stamp_folders():
        with contextlib.suppress(OutputError):
            return write_files(folder, {STAMP_NAME: text.encode()}, kind="compiled loop's stamp")[0]
    return None


@contextlib.contextmanager
def scipy_out_of_reach() -> Iterator[None]:
    """Within it, importing scipy's linear algebra fails at once (unless this process has it already).

    numba imports scipy when it is imported (a version check) and ``scipy.linalg`` when it first loads its
    numpy support (a BLAS check for ``np.dot``): ~0.2 s of CPU together, a quarter of loading the compiled
    loop, which multiplies no matrices.  Both treat an ImportError as "not installed"."""
    blocked = next((name for name in ("scipy", "scipy.linalg") if name not in sys.modules), None)
    if blocked is None:
        yield
        return
    sys.modules[blocked] = None  # type: ignore[assignment]  # None here: an import raises ImportError
    try:
        yield
    finally:
        if blocked in sys.modules and sys.modules[blocked] is None:
            del sys.modules[blocked]


def build() -> Path | None:
    """Load the compiled loop into this process (compiling it where numba's cache lacks it) and stamp it; the stamp.

    Imports numba: call it at SCHED_OTHER, never from a real-time thread."""
    from catanc.runtime.compiled_loop import numba_cache_folder, warm_up  # noqa: PLC0415 - numba's import

    warm_up()
    folder = numba_cache_folder()
    return write_stamp(folder) if folder is not None else None


class BackgroundBuild:
    """A child process building the compiled loop for the next run; ended with its parent, whatever happens."""

    def __init__(self) -> None:
        argv = [sys.executable, "-m", "catanc.runtime.compiled_ready", str(os.getpid())]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        self.process: subprocess.Popen[bytes] | None = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env
        )

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process is not None else None

    def stop(self) -> None:
        """End the build if it is still running (numba writes each cache file whole: nothing half-written stays)."""
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
        return 0 if build() is not None else 1
    return 1  # nowhere to write a stamp


if __name__ == "__main__":
    sys.exit(_build_in_background(int(sys.argv[1])))
