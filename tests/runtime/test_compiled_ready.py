"""Whether the compiled loop is built here (catanc.runtime.compiled_ready), and ``catanc run --loop auto``.

The stamp's checks are tested on folders made here (an upgrade, an edit, a removed or rewritten cache
file each make it "not built").  ``--loop auto`` is tested on the real kernel as a robot meets it: a
machine where the loop is not built runs the Python loop and builds it in a child that leaves with
the enforcer (its end, or its SIGKILL), and the next run takes the compiled loop.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from catanc.runtime import compiled_ready
from catanc.runtime.compiled_ready import STAMP_NAME, LoopState, cpu_identity, state, write_stamp
from catanc.runtime.watchdog import WATCHDOG_PRIORITY
from tests.support.enforcer_runs import ENFORCER_MAIN, EnforcerRun, compile_table, kill_groups, of_kind
from tests.support.linux import alive, poll

REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: the enforcer's watchdog runs at it

X86 = "processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: fpu sse2 avx2\n\nprocessor\t: 1\nmodel name\t: Other\n"

SPEC = """\
catan: 1
app: ready
nodes:
  cam: {compute_ms: 2}
  det: {compute_ms: 3}
edges: [[cam, det]]
subchains: {front: [cam, det]}
objective:
  - {chain: [cam, det], weight: 1.0}
"""


@pytest.fixture
def stamps(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty stamp folder of this test's: nothing said built."""
    folder = tmp_path / "stamps"
    monkeypatch.setenv(compiled_ready.CACHE_ENV, str(folder))
    return folder


def numba_files(folder: Path) -> Path:
    """A folder holding what numba's cache of the loop looks like (an index and its data)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "compiled_walk.wait-712.py311.nbi").write_bytes(b"index")
    (folder / "compiled_walk.wait-712.py311.1.nbc").write_bytes(b"code")
    (folder / "kernel.run-476.py311.nbi").write_bytes(b"another module's")
    return folder


# --------------------------------------------------------------------------- the stamp


def test_the_cpu_is_the_first_processors_model_and_flags() -> None:
    assert cpu_identity(X86) == cpu_identity(X86.replace("Other", "Else"))  # later processors do not count
    assert cpu_identity(X86) != cpu_identity(X86.replace("avx2", "avx512f"))
    assert cpu_identity(X86) != cpu_identity(X86.replace("Some CPU", "Some CPU v2"))
    arm = "processor\t: 0\nFeatures\t: fp asimd\nCPU implementer\t: 0x41\nCPU part\t: 0xd0c\n"
    assert cpu_identity(arm) != cpu_identity(arm.replace("0xd0c", "0xd40"))
    assert cpu_identity("") == cpu_identity("\n")


@pytest.mark.usefixtures("stamps")
def test_nothing_is_built_until_a_stamp_says_so(tmp_path: Path) -> None:
    assert state() is LoopState.UNBUILT
    assert write_stamp(tmp_path / "empty-cache") is None  # no cache files: nothing to vouch for
    assert state() is LoopState.UNBUILT
    assert write_stamp(numba_files(tmp_path / "cache")) is not None
    assert state() is LoopState.READY


def test_the_stamp_names_the_loops_cache_files_only(stamps: Path, tmp_path: Path) -> None:
    write_stamp(numba_files(tmp_path / "cache"))
    stamp = json.loads((stamps / STAMP_NAME).read_text())
    assert sorted(stamp["files"]) == ["compiled_walk.wait-712.py311.1.nbc", "compiled_walk.wait-712.py311.nbi"]
    assert stamp["key"]["source"][1] == compiled_ready.SOURCE.stat().st_size


@pytest.mark.parametrize("change", ["rewritten", "removed", "touched"])
@pytest.mark.usefixtures("stamps")
def test_a_cache_file_changed_since_the_stamp_is_not_built(tmp_path: Path, change: str) -> None:
    cache = numba_files(tmp_path / "cache")
    write_stamp(cache)
    index = cache / "compiled_walk.wait-712.py311.nbi"
    if change == "rewritten":
        index.write_bytes(b"a longer index")
    elif change == "removed":
        index.unlink()
    else:
        stat = index.stat()
        os.utime(index, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    assert state() is LoopState.UNBUILT


@pytest.mark.usefixtures("stamps")
def test_another_numba_or_no_numba_is_not_built(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_stamp(numba_files(tmp_path / "cache"))
    assert state() is LoopState.READY
    monkeypatch.setattr(compiled_ready, "numba_version", lambda: "0.1.0")
    assert state() is LoopState.UNBUILT
    monkeypatch.setattr(compiled_ready, "numba_version", lambda: None)
    assert state() is LoopState.NO_NUMBA


@pytest.mark.parametrize("text", ["", "{", "[1, 2]", '{"key": 1}', '{"key": {}, "files": {}, "folder": "/"}'])
def test_a_broken_stamp_is_not_built(stamps: Path, text: str) -> None:
    stamps.mkdir()
    (stamps / STAMP_NAME).write_text(text)
    assert state() is LoopState.UNBUILT


def test_an_edit_of_the_loops_source_is_not_built(
    stamps: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = tmp_path / "compiled_walk.py"
    shutil.copy2(compiled_ready.SOURCE, source)
    monkeypatch.setattr(compiled_ready, "SOURCE", source)
    write_stamp(numba_files(tmp_path / "cache"))
    assert state() is LoopState.READY
    source.write_text(source.read_text() + "# an edit\n")
    assert state() is LoopState.UNBUILT
    assert (stamps / STAMP_NAME).exists()


OUT_OF_REACH = """
import importlib, sys
from catanc.runtime.compiled_ready import scipy_out_of_reach
if sys.argv[1] == "scipy":
    import scipy  # numba's own import does this (a version check)
def attempt(name):
    try:
        return importlib.import_module(name).__name__
    except ImportError:
        return "refused"
with scipy_out_of_reach():
    print(attempt("scipy.linalg"), attempt("scipy.linalg.cython_blas"))
print(attempt("scipy.linalg"))
with scipy_out_of_reach():
    print(attempt("scipy.linalg.cython_blas"))
"""


@pytest.mark.parametrize("first", ["nothing", "scipy"])
def test_scipys_linear_algebra_is_out_of_reach_only_within_and_only_where_not_imported(first: str) -> None:
    """In a fresh interpreter (with scipy's top level imported first, as numba's import does, or not):
    refused within, importable after; once imported, left alone."""
    argv = [sys.executable, "-c", OUT_OF_REACH, first]
    done = subprocess.run(argv, capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["refused", "refused", "scipy.linalg", "scipy.linalg.cython_blas"]


def build_child(stamps: Path, parent: int) -> subprocess.CompletedProcess[str]:
    """``python -m catanc.runtime.compiled_ready PARENT``: the background build, as the enforcer starts it."""
    argv = [sys.executable, "-m", "catanc.runtime.compiled_ready", str(parent)]
    env = {**os.environ, compiled_ready.CACHE_ENV: str(stamps)}
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300, check=False)


@pytest.mark.usefixtures("compiled_loop")
def test_one_build_at_a_time_and_only_for_its_parent(tmp_path: Path) -> None:
    stamps = tmp_path / "stamps"
    stamps.mkdir()
    held = os.open(stamps / (STAMP_NAME + ".lock"), os.O_RDWR | os.O_CREAT)
    fcntl.flock(held, fcntl.LOCK_EX)
    try:
        busy = build_child(stamps, os.getpid())  # another build holds the lock: this one leaves it
        assert (busy.returncode, busy.stderr) == (0, "")
        assert not (stamps / STAMP_NAME).exists()
    finally:
        os.close(held)
    orphan = build_child(stamps, os.getpid() + 1_000_000)  # not its parent's child: nothing to build for
    assert orphan.returncode == 0
    assert not (stamps / STAMP_NAME).exists()
    done = build_child(stamps, os.getpid())
    assert (done.returncode, done.stderr) == (0, "")
    assert json.loads((stamps / STAMP_NAME).read_text())["files"]


# --------------------------------------------------------------------------- catanc run --loop auto, real kernel


class Run(EnforcerRun):
    def start(self, table: Path, *options: str, duration: float, env: dict[str, str]) -> None:
        argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--start", "spec"]
        argv += ["--socket", str(self.socket), "--log", str(self.log), "--duration", str(duration), *options]
        with (self.folder / "enforcer.out").open("wb") as out, (self.folder / "enforcer.err").open("wb") as err:
            self.enforcer = subprocess.Popen(
                argv, stdout=out, stderr=err, env={**os.environ, **env}, start_new_session=True
            )

    def start_event(self) -> dict[str, object]:
        return poll(lambda: next(iter(of_kind(self.events(), "start")), None), "the log's start")


@pytest.fixture
def runs(tmp_path: Path) -> Iterator[list[Run]]:
    made: list[Run] = []
    yield made
    kill_groups([run.enforcer for run in made if run.enforcer is not None])
    for run in made:
        shutil.rmtree(run.short, ignore_errors=True)


def new_run(runs: list[Run], tmp_path: Path) -> Run:
    folder = tmp_path / f"run{len(runs)}"
    folder.mkdir()
    run = Run(folder, Path(tempfile.mkdtemp(prefix="catanc-test-")))
    runs.append(run)
    return run


def builder_pid(start: dict[str, object]) -> int:
    why = str(start["loop_why"])
    assert "building it for the next run (pid " in why, why
    return int(why.split("(pid ")[1].split(",", maxsplit=1)[0])


@pytest.mark.usefixtures("real_kernel", "compiled_loop")
def test_an_unbuilt_loop_runs_python_builds_it_and_the_next_run_is_compiled(
    tmp_path: Path, runs: list[Run]
) -> None:
    stamps = tmp_path / "stamps"
    env = {compiled_ready.CACHE_ENV: str(stamps)}
    table = compile_table(SPEC, tmp_path / "table", 1)
    first = new_run(runs, tmp_path)
    first.start(table, duration=6.0, env=env)  # numba's cache is there (the fixture): the build only loads it
    start = first.start_event()
    assert start["loop"] == "python"
    builder = builder_pid(start)
    assert first.wait(20) == 0, first.stderr()
    assert not alive(builder)
    assert json.loads((stamps / STAMP_NAME).read_text())["files"]

    second = new_run(runs, tmp_path)
    second.start(table, duration=0.5, env=env)
    assert second.wait(20) == 0, second.stderr()
    assert second.start_event()["loop"] == "compiled"
    assert second.start_event()["loop_why"] == "built on this machine"


@pytest.mark.parametrize("end", ["duration", "sigkill"])
@pytest.mark.usefixtures("real_kernel", "compiled_loop")
def test_the_build_never_outlives_the_enforcer(tmp_path: Path, runs: list[Run], end: str) -> None:
    # An empty numba cache of its own: the build compiles from scratch (a minute), so it is running when the run ends.
    env = {compiled_ready.CACHE_ENV: str(tmp_path / "stamps"), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    run = new_run(runs, tmp_path)
    run.start(compile_table(SPEC, tmp_path / "table", 1), duration=1.5, env=env)
    builder = builder_pid(run.start_event())
    assert alive(builder)
    if end == "sigkill":
        os.kill(run.pid, signal.SIGKILL)
    run.wait(20)
    poll(lambda: not alive(builder) or None, f"the build (pid {builder}) to end with the enforcer", timeout=2.0)
    assert not (tmp_path / "stamps" / STAMP_NAME).exists()
