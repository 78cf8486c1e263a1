"""Whether the compiled loop is built here (catanc.runtime.compiled.ready), and ``catanc run --loop auto``.

The stamp's checks are tested on folders made here (an upgrade, an edit, another CPU, a removed or
rewritten object file each make it "not built").  ``--loop auto`` is tested on the real kernel as a robot meets it: a
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

from catanc.errors import LoopError
from catanc.runtime.compiled import ready as compiled_ready
from catanc.runtime.compiled.ready import OBJECT_NAME, STAMP_NAME, LoopState, cpu_identity, find, load, state
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
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


LAYOUT = (("float64", 2), ("int64", 1))


def built(folder: Path, code: bytes = b"machine code") -> Path:
    """What a build writes (an object file, and the stamp naming it), here with bytes of the test's own."""
    stamp = compiled_ready.write_built(code, "entry", LAYOUT)
    assert stamp == folder / STAMP_NAME
    return folder / OBJECT_NAME


# --------------------------------------------------------------------------- the stamp


def test_the_cpu_is_the_first_processors_model_and_flags() -> None:
    assert cpu_identity(X86) == cpu_identity(X86.replace("Other", "Else"))  # later processors do not count
    assert cpu_identity(X86) != cpu_identity(X86.replace("avx2", "avx512f"))
    assert cpu_identity(X86) != cpu_identity(X86.replace("Some CPU", "Some CPU v2"))
    arm = "processor\t: 0\nFeatures\t: fp asimd\nCPU implementer\t: 0x41\nCPU part\t: 0xd0c\n"
    assert cpu_identity(arm) != cpu_identity(arm.replace("0xd0c", "0xd40"))
    assert cpu_identity("") == cpu_identity("\n")


def test_nothing_is_built_until_a_stamp_says_so(stamps: Path) -> None:
    assert state() is LoopState.UNBUILT
    assert find() is None
    built(stamps)
    assert state() is LoopState.READY
    assert find() == (b"machine code", "entry", LAYOUT)


@pytest.mark.parametrize("change", ["rewritten", "same size", "removed"])
def test_an_object_file_changed_since_the_stamp_is_not_built(stamps: Path, change: str) -> None:
    code = built(stamps)
    if change == "rewritten":
        code.write_bytes(b"other machine code")
    elif change == "same size":
        code.write_bytes(b"machine kode")
    else:
        code.unlink()
    assert state() is LoopState.UNBUILT


@pytest.mark.parametrize("package", ["numba", "llvmlite"])
def test_another_numba_or_llvmlite_or_no_numba_is_not_built(
    stamps: Path, monkeypatch: pytest.MonkeyPatch, package: str
) -> None:
    built(stamps)
    assert state() is LoopState.READY
    installed = compiled_ready.version_of
    monkeypatch.setattr(compiled_ready, "version_of", lambda name: "0.1.0" if name == package else installed(name))
    assert state() is LoopState.UNBUILT
    if package == "numba":
        monkeypatch.setattr(compiled_ready, "version_of", lambda name: None if name == package else installed(name))
        assert state() is LoopState.NO_NUMBA


def test_another_cpu_is_not_built(stamps: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    built(stamps)
    monkeypatch.setattr(compiled_ready, "cpu_identity", lambda _text: "another CPU")
    assert state() is LoopState.UNBUILT


@pytest.mark.parametrize(
    "text",
    ["", "{", "[1, 2]", '{"key": 1}', '{"key": {}, "symbol": "e", "layout": [], "sha256": ""}', "STAMP-BAD-LAYOUT"],
)
def test_a_broken_stamp_is_not_built(stamps: Path, text: str) -> None:
    code = built(stamps)
    stamp = json.loads((stamps / STAMP_NAME).read_text())
    if text == "STAMP-BAD-LAYOUT":  # the right key and file, a layout that is not (dtype, dimensions) pairs
        text = json.dumps({**stamp, "layout": [["float64"]]})
    (stamps / STAMP_NAME).write_text(text)
    assert code.exists()
    assert state() is LoopState.UNBUILT


@pytest.mark.parametrize("source", range(len(compiled_ready.SOURCES)))
def test_an_edit_of_a_module_compiled_is_not_built(
    stamps: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, source: int
) -> None:
    copies = []
    for original in compiled_ready.SOURCES:
        copies.append(tmp_path / original.name)
        shutil.copy2(original, copies[-1])
    monkeypatch.setattr(compiled_ready, "SOURCES", tuple(copies))
    built(stamps)
    assert state() is LoopState.READY
    copies[source].write_text(copies[source].read_text() + "# an edit\n")
    assert state() is LoopState.UNBUILT
    assert (stamps / STAMP_NAME).exists()


@pytest.mark.parametrize("change", ["object writable by the group", "stamp writable by all", "object a link"])
def test_files_others_could_have_written_are_not_built(stamps: Path, change: str) -> None:
    """The object file is machine code the enforcer runs (as root, at SCHED_FIFO): never one another user could have
    written, nor one reached through a link."""
    code = built(stamps)
    if change == "object writable by the group":
        code.chmod(0o664)
    elif change == "stamp writable by all":
        (stamps / STAMP_NAME).chmod(0o646)
    else:
        real = stamps / "elsewhere.o"
        code.rename(real)
        code.symlink_to(real)
    assert state() is LoopState.UNBUILT


def test_files_of_another_user_are_not_built(stamps: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root to give a file away")
    code = built(stamps)
    assert state() is LoopState.READY
    os.chown(code, 65534, -1)  # nobody's now
    assert state() is LoopState.UNBUILT


def test_a_loose_umask_still_writes_files_only_their_owner_may_write(stamps: Path) -> None:
    loose = os.umask(0o002)  # a desktop's user-private-group default: new files group-writable
    try:
        code = built(stamps)
    finally:
        os.umask(loose)
    assert code.stat().st_mode & 0o777 == 0o644
    assert (stamps / STAMP_NAME).stat().st_mode & 0o777 == 0o644
    assert state() is LoopState.READY


def test_bytes_that_are_no_object_file_are_a_load_error(stamps: Path) -> None:
    """A stamp vouching for bytes that are no object file: ``load`` says so, LLVM's loader never sees them."""
    built(stamps, b"not an object file")
    with pytest.raises(LoopError, match="not an object file"):
        load()


def test_nothing_built_is_a_load_error(stamps: Path) -> None:
    with pytest.raises(LoopError, match="not built"):
        load()


def build_child(stamps: Path, parent: int) -> subprocess.CompletedProcess[str]:
    """``python -m catanc.runtime.compiled.ready PARENT``: the background build, as the enforcer starts it."""
    argv = [sys.executable, "-m", "catanc.runtime.compiled.ready", str(parent)]
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
    assert json.loads((stamps / STAMP_NAME).read_text())["sha256"]


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
def test_an_unbuilt_loop_runs_python_builds_it_and_the_next_run_is_compiled(tmp_path: Path, runs: list[Run]) -> None:
    stamps = tmp_path / "stamps"
    env = {compiled_ready.CACHE_ENV: str(stamps)}
    table = compile_table(SPEC, tmp_path / "table", 1)
    first = new_run(runs, tmp_path)
    # numba's cache is there (the fixture), but LLVM still generates the object file: ~8 s of one CPU at nice 19,
    # so the run lasts until the build has stamped its file (the stamp is written last), then gets Ctrl-C
    first.start(table, duration=120.0, env=env)
    start = first.start_event()
    assert start["loop"] == "python"
    builder = builder_pid(start)
    poll(lambda: (stamps / STAMP_NAME).is_file() or None, "the build to stamp the compiled loop", timeout=100.0)
    os.kill(first.pid, signal.SIGINT)
    assert first.wait(20) == 0, first.stderr()
    assert not alive(builder)
    assert json.loads((stamps / STAMP_NAME).read_text())["sha256"]

    second = new_run(runs, tmp_path)
    second.start(table, duration=2.0, env=env)
    assert second.start_event()["loop"] == "compiled"
    assert second.start_event()["loop_why"] == "built on this machine"
    mapped = Path(f"/proc/{second.pid}/maps").read_text()  # the object file linked by llvmlite, numba never loaded
    assert "libllvmlite" in mapped
    assert "/numba/" not in mapped
    assert second.wait(20) == 0, second.stderr()


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
