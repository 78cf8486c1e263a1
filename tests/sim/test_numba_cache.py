"""Stale numba cache files are removed before numba can trip over them (catanc.numba_cache)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import catanc.sim
from catanc.numba_cache import drop_stale_cache

HOUR_S = 3600.0


def touch(path: Path, mtime: float) -> Path:
    path.write_bytes(b"not a pickle")
    os.utime(path, (mtime, mtime))
    return path


def test_only_the_cache_files_older_than_the_source_go(tmp_path: Path) -> None:
    source = tmp_path / "kernel.py"
    source.write_text("x = 1\n")
    now = source.stat().st_mtime
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    stale = [touch(cache / "kernel.at-210.py311.nbi", now - HOUR_S), touch(cache / "kernel.at-9.py311.1.nbc", now - 1)]
    fresh = [touch(cache / "kernel.at-216.py311.nbi", now + 1), touch(cache / "kernel.at-216.py311.1.nbc", now + 60)]
    others = [
        touch(cache / "kernel.cpython-311.pyc", now - HOUR_S),  # Python's own cache
        touch(cache / "fast.run-3.py311.nbi", now - HOUR_S),  # another module's
    ]
    assert sorted(drop_stale_cache(source)) == sorted(stale)
    assert [path.exists() for path in stale] == [False, False]
    assert all(path.exists() for path in fresh + others)


def test_cache_files_older_than_a_module_the_source_depends_on_go_too(tmp_path: Path) -> None:
    # numba would load code compiled against the older dependency: only the source's own stamp is checked.
    source = tmp_path / "kernel.py"
    source.write_text("from policy import DECIDE\n")
    now = source.stat().st_mtime
    dependency = tmp_path / "policy.py"
    dependency.write_text("DECIDE = 1\n")
    os.utime(dependency, (now + HOUR_S, now + HOUR_S))
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    compiled_before = touch(cache / "kernel.switch-80.py311.nbi", now + 1)
    compiled_after = touch(cache / "kernel.switch-80.py311.1.nbc", now + 2 * HOUR_S)
    assert drop_stale_cache(source) == []
    assert drop_stale_cache(source, depends_on=(dependency,)) == [compiled_before]
    assert compiled_after.exists()


def test_a_missing_source_or_cache_folder_is_no_error(tmp_path: Path) -> None:
    assert drop_stale_cache(tmp_path / "gone.py") == []
    (tmp_path / "alone.py").write_text("")
    assert drop_stale_cache(tmp_path / "alone.py") == []


def test_importing_the_kernel_drops_its_stale_cache_files() -> None:
    package = Path(catanc.sim.__file__).parent
    (package / "__pycache__").mkdir(exist_ok=True)
    # A function's index from an older kernel, as numba names them; what it holds never matters.
    probe = touch(package / "__pycache__" / "kernel.zz_stale_probe-1.py311.nbi", 0.0)
    try:
        subprocess.run([sys.executable, "-c", "import catanc.sim.kernel"], check=True, timeout=120)
        assert not probe.exists()
    finally:
        probe.unlink(missing_ok=True)


BUILD_A_SIM = """
import catanc.sim.kernel as k
from catanc.model.load import load_spec
from catanc.sim.simulate import Setup, simulate

simulate(Setup(load_spec("specs/nav2d.yaml"), 1, 0.1, 0), "baseline")
print(len(k.new_sim.stats.cache_misses), hasattr(k.SimProxy, "_StructRefProxy__numba_ctor"))
"""


def test_a_second_process_builds_its_simulation_from_the_cache_without_compiling() -> None:
    """numba's own ``SimProxy(...)`` constructor is never cached: it compiled for 7 s in every process."""
    root = Path(catanc.sim.__file__).parents[2]
    outputs = [
        subprocess.run(
            [sys.executable, "-c", BUILD_A_SIM], cwd=root, check=True, timeout=600, capture_output=True, text=True
        ).stdout.split()
        for _ in range(2)
    ]
    assert outputs[1] == ["0", "False"]  # the first may have compiled and filled the cache
