"""Other Python interpreters on this machine, for running the standalone client under them."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path


def find_python(version: tuple[int, int]) -> Path | None:
    """A ``pythonX.Y`` interpreter: on the PATH, else one pyenv installed; None if there is none."""
    name = f"python{version[0]}.{version[1]}"
    candidates = [shutil.which(name)]
    roots = [os.environ.get("PYENV_ROOT"), str(Path.home() / ".pyenv"), "/root/.pyenv", "/opt/pyenv"]
    for root in filter(None, roots):
        candidates += sorted(str(path) for path in Path(root).glob(f"versions/{version[0]}.{version[1]}.*/bin/{name}"))
    for candidate in filter(None, candidates):
        try:
            found = subprocess.run(
                [candidate, "-I", "-S", "-c", "import sys; print(sys.version_info[:2])"],
                capture_output=True,
                text=True,
                timeout=30,
                check=False,
            )
        except OSError:
            continue
        if found.returncode == 0 and found.stdout.strip() == str(version):
            return Path(candidate)
    return None
