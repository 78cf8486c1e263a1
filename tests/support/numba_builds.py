"""The suite's two numba builds, made once and side by side before the tests that need them.

numba compiles the enforcer's loop (about a minute of one CPU from an empty cache) and the simulator's kernel
(about 45 s) into caches on disk, at their first use.  Left to the tests, a fresh checkout builds them one after
the other in a serial run, and under ``pytest -n`` every worker that meets one builds it again.  Here one
process builds both at once, one per CPU, while any other worker waits on a lock; after that both load from
their caches in a second or two.
"""

from __future__ import annotations

import fcntl
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

from catanc.runtime.compiled.ready import BackgroundBuild, LoopState, state

ROOT = Path(__file__).resolve().parents[2]
LOCK = Path(tempfile.gettempdir()) / "catanc-tests-numba-builds.lock"
SIMULATED = ROOT / "specs" / "vr_illixr.yaml"  # every policy of the kernel, one core, a simulated second


def build_both() -> None:
    """Build what is not built yet; returns once both are (a build that fails is left to the tests that use it,
    which then build it themselves and fail with its error)."""
    if importlib.util.find_spec("numba") is None:
        return
    with LOCK.open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, or when this process dies
        loop = BackgroundBuild() if state() is LoopState.UNBUILT else None
        simulate = [sys.executable, "-m", "catanc", "simulate", str(SIMULATED), "-k", "1", "--duration", "1"]
        simulator = subprocess.Popen(
            simulate, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        try:
            simulator.wait()
            if loop is not None and loop.process is not None:
                loop.process.wait()
        finally:  # an interrupted session leaves no build behind
            if simulator.poll() is None:
                simulator.kill()
                simulator.wait()
            if loop is not None:
                loop.stop()
