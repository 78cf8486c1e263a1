"""What the test folders share: the real-kernel fixtures, and the markers.

Markers (registered in pyproject.toml; pytest runs with ``--strict-markers``):

- ``realtime``: needs root and the real kernel (SCHED_FIFO, affinities,
  switching to ``nobody``).  Every test that uses the :func:`real_kernel` or
  :func:`nobody` fixture gets it here, so ``pytest -m "not realtime"`` runs
  anywhere.  Such a test also skips, with the reason, where the machine
  lacks the part.
- ``serial``: runs with the CPUs to itself, never beside another test (``pytest -n``): the
  ``realtime`` and ``ros`` tests, and those that hold the measured timing of real processes to
  numbers (:data:`TIMED_MODULES`).  The README runs the suite in two passes: ``-m "not serial"``
  on every CPU (pytest-xdist), then ``-m serial`` one test at a time.
- ``slow``: out of the fast tier, ``pytest -m "not slow and not realtime and not ros"``:
  takes more than ~10 s on the 2-core development VM, or belongs to a module whose
  tests each start processes (the CLI, node processes, ``catanc run``) or run numba-compiled
  code whose first build costs a minute (the compiled loop, the simulator's kernel).  Given
  here by rule (:data:`SLOW_MODULES`, :data:`COMPILED_FIXTURES`), and by hand on single tests.

Hypothesis profiles: ``ci`` (derandomized, no example database) wherever ``CI`` is set, as
``.ci/run`` has it; ``explore`` elsewhere (new examples each run, failures kept in the
gitignored ``.hypothesis/``).  ``--hypothesis-profile`` picks one by name.  Neither has a
deadline or the too-slow health check: a loaded machine must not fail a test (speed lives in
the benchmarks).

Helpers that are not fixtures live in :mod:`tests.support`.  ``untraded`` plans without Stage II's
executor trade.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from hypothesis import HealthCheck, settings

from tests.support.fake_enforcer import FakeEnforcer
from tests.support.linux import missing_tools, nobody_ids, require_fifo

if TYPE_CHECKING:
    from catanc.runtime.compiled.entry import WalkEntry

REALTIME_FIXTURES = frozenset({"real_kernel", "nobody"})
COMPILED_FIXTURES = frozenset({"compiled_loop_built", "compiled_loop"})
"""The compiled loop: built from scratch (a fresh clone) it takes about a minute of CPU."""

TESTS = Path(__file__).parent
SLOW_MODULES = frozenset(
    {
        # the compiled simulator in every test: its numba build takes ~47 s of CPU from an empty cache
        "sim/test_fifo_static.py",
        "sim/test_kernel.py",
        "sim/test_numba_cache.py",
        "sim/test_plots.py",
        "sim/test_simulate.py",
        "sim/test_stealing.py",
        "explain/test_executor_caps.py",
        "explain/test_executors.py",
        "planning/test_executor_trade.py",
        # the compiled walk against the Python one: its numba build, as the simulator's
        "runtime/test_compiled_walk.py",
        # re-plans against fresh cvxpy solves, seconds each
        "planning/test_replan.py",
        # processes in most tests: the CLI, node processes, catanc run, compilers
        "artifacts/test_launch_py.py",
        "cli/test_progress.py",
        "explain/test_explain_piped.py",
        "realbench/test_bench.py",
        "runtime/test_compiled_ready.py",
        "runtime/test_doctor.py",
        "runtime/test_enforcer.py",
        "runtime/test_enforcer_processes.py",
        "runtime/test_hostile_clients.py",
        "runtime/test_observe.py",
        "runtime/test_ring_counter.py",
        "runtime/test_runtime_costs.py",
        "runtime/test_sched.py",
        "runtime/test_watchdog.py",
        "test_client_cpp.py",
        "test_clients_on_the_kernel.py",
    }
)
"""Modules (under tests/) out of the fast tier as a whole."""
TIMED_MODULES = frozenset(
    {
        # real processes' periods and compute times measured and held to numbers, without the real kernel
        "runtime/test_observe.py",
        "test_clients_on_the_kernel.py",
    }
)
"""Modules (under tests/) whose tests are ``serial`` though not ``realtime``: another test beside them skews
what they measure."""

# On Hypothesis' own default, not on the profile loaded now (its built-in ci one where CI is set).
settings.register_profile(
    "explore",
    settings.get_profile("default"),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.register_profile("ci", settings.get_profile("explore"), derandomize=True, database=None)


def hypothesis_profile(environ: Mapping[str, str]) -> str:
    """The profile a run takes unless ``--hypothesis-profile`` names one: ``ci`` where ``CI`` is set at all
    (Hypothesis' own rule for its built-in profile of that name), else ``explore``."""
    return "ci" if "CI" in environ else "explore"


settings.load_profile(hypothesis_profile(os.environ))


@pytest.fixture(scope="module")
def real_kernel(request: pytest.FixtureRequest, compiled_loop_built: None) -> None:
    """Skips unless CPUs 0 and 1 are allowed and SCHED_FIFO is permitted here.

    A test module asks for more with module constants: ``REALTIME_PRIORITY``
    (the highest SCHED_FIFO priority its tests use, default 1) and
    ``REALTIME_TOOLS`` (programs they run, e.g. ``chrt``).
    """
    if missing := missing_tools(*getattr(request.module, "REALTIME_TOOLS", ())):
        pytest.skip(f"needs {', '.join(missing)}")
    require_fifo(getattr(request.module, "REALTIME_PRIORITY", 1))


@pytest.fixture(scope="session")
def compiled_loop_built() -> None:
    """The compiled loop built on this machine (its object file and stamp), once, before any test starts an
    enforcer: ``catanc run``'s default loop is then the compiled one, as on a machine that has run catanc before.
    Compiled from scratch (a fresh checkout) it takes about a minute, with numba's cache of the walk a few
    seconds.  Without numba it does nothing: the enforcers run the Python loop."""
    if importlib.util.find_spec("numba") is None:
        return
    from catanc.runtime.compiled.ready import LoopState, build, state

    if state() is LoopState.READY:
        return
    _, stamp = build()
    assert stamp is not None, "the compiled loop was built but not stamped: no writable stamp folder"


@pytest.fixture(scope="session")
def compiled_loop(compiled_loop_built: None) -> WalkEntry:
    """The compiled loop's entry linked into this process, for a test of it: skips without numba."""
    pytest.importorskip("numba", reason="the compiled loop needs numba")
    from catanc.runtime.compiled.ready import load

    return load()


@pytest.fixture(scope="session")
def cpp_example(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The C++ example node, compiled once for every module that runs it (g++ takes seconds of CPU).

    Skips where there is no C++ compiler."""
    from tests.support.client_nodes import build_cpp_example  # only the client tests load the client helpers

    return build_cpp_example(tmp_path_factory.mktemp("cpp"))


@pytest.fixture(scope="module")
def nobody(real_kernel: None) -> tuple[int, int]:
    """``nobody``'s uid and gid; skips unless the tests may switch to it (root, setpriv, prlimit)."""
    return nobody_ids()


@pytest.fixture
def shared_folder() -> Iterator[Path]:
    """A folder under /tmp that ``nobody`` may use (pytest's own are the test user's alone)."""
    folder = Path(tempfile.mkdtemp(prefix="catanc-nobody-", dir="/tmp"))
    folder.chmod(0o777)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        if REALTIME_FIXTURES & fixtures:
            item.add_marker(pytest.mark.realtime)
        module = module_of(item)
        if COMPILED_FIXTURES & fixtures or module in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
        # tests/ros/conftest.py marks its tests ros too, maybe after this hook: its folder decides here
        if REALTIME_FIXTURES & fixtures or module.startswith("ros/") or module in TIMED_MODULES:
            item.add_marker(pytest.mark.serial)


def pytest_collection_finish(session: pytest.Session) -> None:
    """numba's two builds first, side by side, where a selected test may need them (the fast tier needs
    neither): :mod:`tests.support.numba_builds`."""
    if session.config.option.collectonly or not any(item.get_closest_marker("slow") for item in session.items):
        return
    from tests.support.numba_builds import build_both  # imports catanc's compiled-loop module

    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line("building numba's caches where they are not built (a minute on a fresh checkout)")
    build_both()


def module_of(item: pytest.Item) -> str:
    """The item's file relative to tests/, as :data:`SLOW_MODULES` names it ("" outside it)."""
    return item.path.relative_to(TESTS).as_posix() if item.path.is_relative_to(TESTS) else ""


@pytest.fixture
def enforcer(tmp_path: Path) -> Iterator[FakeEnforcer]:
    """A fake enforcer on a socket in the test's folder, for the client tests (closed after the test)."""
    fake = FakeEnforcer(tmp_path / "catanc.sock")
    try:
        yield fake
    finally:
        fake.close()


@pytest.fixture
def untraded(monkeypatch: pytest.MonkeyPatch) -> None:
    """Plans made without Stage II's executor trade (every member at its least ``k``, as before the trade):
    for tests of the executor model on plans that lose many triggers, and for the simulator to judge the
    trade against."""
    from catanc.planning.stage2.turns import LayoutTurns  # only the tests that ask load the planner

    monkeypatch.setattr(LayoutTurns, "best_spacing", lambda *_args, **_kwargs: None)
