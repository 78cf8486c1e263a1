"""catanc.sim.memory: freed memory is reused without faulting its pages in again.

Each case runs in a fresh interpreter: the setting is process-wide and once.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")

BLOCK_MIB = 64  # above glibc's largest dynamic mmap threshold (32 MiB): without the setting, every block is mmapped

CHILD = textwrap.dedent(
    f"""
    import ctypes, resource, sys
    import numpy as np
    from catanc.sim.memory import keep_freed_memory

    PR_SET_THP_DISABLE = 41  # 4 KiB pages whatever the machine's transparent huge page setting: one fault each
    ctypes.CDLL(None).prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0)
    applied = keep_freed_memory() if sys.argv[1] == "keep" else None
    faults = []
    for _ in range(3):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        block = np.ones({BLOCK_MIB} << 20, np.uint8)  # every page touched
        del block
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    print(applied, faults[-1])
    """
)

PAGES = (BLOCK_MIB << 20) // 4096


def _last_round(mode: str) -> tuple[str, int]:
    done = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True)
    applied, faults = done.stdout.split()
    return applied, int(faults)


def test_without_the_setting_a_freed_block_faults_in_again() -> None:
    """The premise: glibc hands a large freed block back, so allocating it again faults every page."""
    _, faults = _last_round("default")
    assert faults > PAGES // 2


def test_with_the_setting_a_freed_block_is_reused_without_faults() -> None:
    applied, faults = _last_round("keep")
    if applied != "True":
        pytest.skip("not glibc: mallopt is not there")
    assert faults < PAGES // 20
