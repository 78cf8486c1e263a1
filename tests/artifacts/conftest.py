"""What the artifact tests share: the example specs, compiled once."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import pytest

from catanc.artifacts.compile import Target, compile_spec

SPECS = sorted((Path(__file__).parents[2] / "specs").glob("*.yaml"))


@pytest.fixture(scope="session")
def example_targets() -> Mapping[tuple[str, int], Target]:
    """Every example spec at 1 and 2 cores, compiled in memory, by ``(stem, cores)``.

    Compiled once for the modules that read them (each compile plans its spec: seconds of CPU for the
    eight); the tests only read them."""
    return MappingProxyType({(path.stem, cores): compile_spec(path, cores) for path in SPECS for cores in (1, 2)})
