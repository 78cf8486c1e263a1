"""The Hypothesis profiles of tests/conftest.py: ``ci`` where ``CI`` is set (derandomized, no example
database), ``explore`` elsewhere; what pytest itself loads is checked by running it, as .ci/run does."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import hypothesis_profile

REPO = Path(__file__).resolve().parents[1]

# Run by a pytest of its own with the suite's conftest as a plugin, as a property test in CI would be.
PROFILE_PROBE = """\
from hypothesis import given, settings, strategies as st

@settings(max_examples=5)
@given(st.integers())
def test_probe(value):
    print("profile", settings.get_current_profile_name(), settings().database)
"""


def drawn(profile: str) -> list[int]:
    """The integers a 20-example property test is given under ``profile``."""
    seen: list[int] = []

    @settings(settings.get_profile(profile), max_examples=20, database=None)
    @given(st.integers())
    def record(value: int) -> None:
        seen.append(value)

    record()
    return seen


def test_ci_set_to_anything_picks_the_ci_profile() -> None:
    assert hypothesis_profile({"CI": "true"}) == "ci"
    assert hypothesis_profile({"CI": ""}) == "ci"  # set is enough, as Hypothesis' own rule has it
    assert hypothesis_profile({}) == "explore"
    assert hypothesis_profile({"HOME": "/root"}) == "explore"


def test_this_run_has_the_profile_its_environment_asks_for(request: pytest.FixtureRequest) -> None:
    name = request.config.getoption("hypothesis_profile") or hypothesis_profile(os.environ)
    active = settings()  # the loaded profile's values
    assert settings.get_current_profile_name() == name
    assert active.derandomize == (name == "ci")
    assert (active.database is None) == (name == "ci")
    assert active.deadline is None  # never a timed test, in either


def test_ci_draws_the_same_examples_each_run() -> None:
    first = drawn("ci")
    assert len(first) >= 10
    assert drawn("ci") == first


def test_explore_draws_new_examples_each_run() -> None:
    # 20 integers from Hypothesis' random seed: the same twice would be a derandomized run.
    assert drawn("explore") != drawn("explore")


def test_pytest_with_ci_set_loads_the_ci_profile_and_writes_no_database(tmp_path: Path) -> None:
    (tmp_path / "test_probe.py").write_text(PROFILE_PROBE)
    env = {**os.environ, "CI": "true", "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-s", "-p", "tests.conftest", "-p", "no:cacheprovider", "test_probe.py"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "profile ci None" in done.stdout
    assert not (tmp_path / ".hypothesis" / "examples").exists()  # Hypothesis' default place, under the cwd
