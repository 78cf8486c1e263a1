"""The C++ client (catanc/include/catanc/client.hpp), built by the system's compiler as a user would.

The example node (examples/cpp/node.cpp) is compiled once with ``catanc client --cflags`` and
warnings as errors, then driven by :class:`FakeEnforcer`: the enforcer's own socket, endpoints
and rings, scripted by the test, so each part of protocol ``catanc/2`` is checked on the wire.
Its runs under ``catanc run`` on the real kernel are in test_clients_on_the_kernel.py.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol import ring
from catanc.runtime.protocol.messages import Bye, Done, Hello, Reject, Route, Stop, trigger_datagram
from tests.support.client_nodes import Run, finish, parse_runs, without_enforcer
from tests.support.fake_enforcer import TIMEOUT_S, FakeEnforcer

HEADER = Path(__file__).resolve().parents[1] / "catanc" / "include" / "catanc" / "client.hpp"

Start = Callable[..., "subprocess.Popen[str]"]


@pytest.fixture(scope="module")
def example(cpp_example: Path) -> Path:
    return cpp_example


@pytest.fixture
def start(example: Path, enforcer: FakeEnforcer) -> Iterator[Start]:
    """Start the example with ``CATANC_SOCKET`` naming the fake enforcer."""
    started: list[subprocess.Popen[str]] = []

    def run(*nodes: str) -> subprocess.Popen[str]:
        env = {**without_enforcer(), "CATANC_SOCKET": str(enforcer.path)}
        proc = subprocess.Popen(
            [str(example), *nodes], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        started.append(proc)
        return proc

    yield run
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=TIMEOUT_S)


def test_the_headers_constants_are_the_protocols_and_the_rings() -> None:
    text = HEADER.read_text()

    def constant(name: str) -> str:
        found = re.search(rf"inline constexpr [\w:* ]+ {name} = ([^;]+);", text)
        assert found, f"no {name} in {HEADER.name}"
        return found.group(1)

    assert constant("kProtocol") == f'"{protocol.PROTOCOL.decode()}"'
    assert constant("kSocketEnv") == f'"{protocol.SOCKET_ENV}"'
    assert int(constant("kMaxDatagram")) == protocol.MAX_DATAGRAM
    assert int(constant("kMaxName")) == protocol.MAX_NAME
    assert int(constant("kRingMagic"), 16) == ring.MAGIC
    assert int(constant("kRingVersion")) == ring.LAYOUT_VERSION
    assert int(constant("kRingHeaderSize")) == ring.HEADER_SIZE
    assert int(constant("kRingEntrySize")) == ring.ENTRY_SIZE
    assert int(constant("kRingWrittenOffset")) == ring.WRITTEN_OFFSET
    assert constant("kUnknownCompute") == "~std::uint64_t{0}"  # 2**64 - 1, ring.UNKNOWN


def test_the_cli_points_at_the_header_and_the_python_client() -> None:
    def catanc(*args: str) -> str:
        done = subprocess.run(
            [sys.executable, "-m", "catanc", "client", *args], capture_output=True, text=True, timeout=60, check=True
        )
        return done.stdout.strip()

    assert catanc("--cflags") == f"-I{HEADER.parent.parent}"
    assert Path(catanc("--python")).read_bytes() == (HEADER.parents[2] / "client.py").read_bytes()
    refused = subprocess.run(
        [sys.executable, "-m", "catanc", "client"], capture_output=True, text=True, timeout=60, check=False
    )
    assert refused.returncode == 2
    assert "give one of --cflags" in refused.stderr


def test_a_node_registers_its_thread_runs_when_triggered_and_ends_on_stop(enforcer: FakeEnforcer, start: Start) -> None:
    proc = start("LM:20")
    hello = enforcer.welcome({"LM"})["LM"]
    assert hello.pid == proc.pid
    assert hello.tid != proc.pid  # the node's own thread, not the main one
    assert enforcer.address("LM").startswith(b"\0")  # autobound
    entries = []
    for seq in (7, 8):
        enforcer.trigger("LM", seq, threads=2)
        entries += enforcer.runs("LM")
    enforcer.send("LM", Stop())
    status, runs, err = finish(proc)
    assert (status, err) == (0, "")
    assert [entry.seq for entry in entries] == [7, 8]
    assert [(run.node, run.seq) for run in runs] == [("LM", 7), ("LM", 8)]
    for entry, run in zip(entries, runs, strict=True):
        assert entry.start_ns <= run.start_ns <= entry.end_ns <= run.end_ns  # the example notes its end after done()
        assert entry.compute_ms is not None
        assert 20.0 <= entry.compute_ms <= 30.0  # its thread's CPU time since the trigger
        assert entry.threads == 2
    assert enforcer.receive(0) is None  # no datagram per run, and no bye after a stop


def test_a_finished_run_wakes_the_next_node_and_no_one_else_triggers_it(enforcer: FakeEnforcer, start: Start) -> None:
    proc = start("A:2", "B:1")
    hellos = enforcer.welcome({"A", "B"})
    enforcer.send("A", Route("A", False, "B", 3, enforcer.address("B"), None))
    enforcer.send("B", Route("B", False, None, 1, None, enforcer.address("A")))
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as stranger:
        stranger.bind("")
        stranger.sendto(trigger_datagram("B", 99), enforcer.address("B"))
        stranger.sendto(trigger_datagram("A", 98), enforcer.address("A"))
        time.sleep(0.2)  # read (and dropped) before the real triggers
    for seq in (4, 5):
        enforcer.trigger("A", seq)
    runs_a, runs_b = enforcer.runs("A", 2), enforcer.runs("B", 2)
    assert [entry.seq for entry in runs_b] == [4, 5]
    for before, after in zip(runs_a, runs_b, strict=True):
        assert after.start_ns >= before.end_ns  # B started once A was done
        assert after.threads == 3  # the route's threads for B
    # A stop for A alone: the example then interrupts B, whose socket may be closed before a stop for B
    # could be sent (a second stop failed that way under load).  Interrupted, not stopped, B says bye.
    enforcer.send("A", Stop())
    status, runs, err = finish(proc)
    assert (status, err) == (0, "")
    assert sorted((run.node, run.seq) for run in runs) == [("A", 4), ("A", 5), ("B", 4), ("B", 5)]
    assert enforcer.expect(Bye)[0] == Bye("B", hellos["B"].tid)
    assert enforcer.receive(0) is None  # no hop went through the enforcer, and no bye from the stopped A


def test_a_route_that_asks_for_it_gets_a_done_per_run(enforcer: FakeEnforcer, start: Start) -> None:
    proc = start("LM:1")
    hello = enforcer.welcome({"LM"})["LM"]
    enforcer.send("LM", Route("LM", notify=True))
    time.sleep(0.1)
    enforcer.trigger("LM", 9)
    done, received = enforcer.expect(Done)
    assert done == Done("LM", hello.tid, 9)
    assert received.sender == enforcer.address("LM")
    enforcer.send("LM", Stop())
    assert finish(proc)[0] == 0


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_interrupt_from_a_signal_handler_ends_every_loop_and_says_bye(
    enforcer: FakeEnforcer, start: Start, signum: int
) -> None:
    proc = start("A:1", "B:1")
    hellos = enforcer.welcome({"A", "B"})
    enforcer.trigger("A", 1)
    enforcer.runs("A")
    proc.send_signal(signum)
    status, runs, err = finish(proc)
    assert (status, err) == (0, "")
    assert runs == [Run("A", 1, runs[0].start_ns, runs[0].end_ns)]
    byes = {enforcer.expect(Bye)[0], enforcer.expect(Bye)[0]}
    assert byes == {Bye("A", hellos["A"].tid), Bye("B", hellos["B"].tid)}


def test_a_rejected_node_gets_an_exception_with_the_enforcers_reason(enforcer: FakeEnforcer, start: Start) -> None:
    proc = start("XX:1")
    hello, received = enforcer.expect(Hello)
    assert enforcer.sock.reply(Reject(hello.node, "no node 'XX' in this app").encode(), received.sender)
    status, runs, err = finish(proc)
    assert (status, runs) == (1, [])
    assert f"the catanc enforcer at {enforcer.path} rejected node 'XX': no node 'XX' in this app" in err
    assert enforcer.receive(0) is None  # rejected: no bye


def test_an_enforcer_that_goes_away_ends_the_loop_cleanly(enforcer: FakeEnforcer, start: Start) -> None:
    proc = start("LM:1")
    enforcer.welcome({"LM"})
    enforcer.trigger("LM", 1)
    enforcer.runs("LM")
    enforcer.close()  # no stop: a crash, as the node sees it
    gone = time.monotonic()
    status, runs, err = finish(proc)
    took = time.monotonic() - gone
    assert [run.seq for run in runs] == [1]
    assert status == 1
    assert f"catanc: lost the catanc enforcer at {enforcer.path}: it went away without stopping node 'LM'" in err
    assert took < 3.0  # noticed at the next probe, a second after the last datagram


def test_no_enforcer_socket_and_no_fallback_is_an_error(example: Path, tmp_path: Path) -> None:
    done = subprocess.run(
        [str(example), "LM:1"], env=without_enforcer(), capture_output=True, text=True, timeout=TIMEOUT_S, check=False
    )
    assert done.returncode == 1
    assert "no catanc enforcer socket: CATANC_SOCKET is not set" in done.stderr
    missing = tmp_path / "missing.sock"
    done = subprocess.run(
        [str(example), "LM:1"],
        env={**without_enforcer(), "CATANC_SOCKET": str(missing)},
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    assert done.returncode == 1
    assert f"no catanc enforcer at {missing} (No such file or directory): is `catanc run` running?" in done.stderr


def test_bad_node_names_are_refused(example: Path) -> None:
    done = subprocess.run(
        [str(example), "9lives:1"], env=without_enforcer(), capture_output=True, text=True, timeout=TIMEOUT_S,
        check=False,
    )  # fmt: skip
    assert done.returncode == 1
    assert "bad node name '9lives'" in done.stderr
    assert parse_runs(done.stdout) == []


@pytest.mark.slow
def test_a_built_wheel_ships_the_header_where_the_cli_says(tmp_path: Path) -> None:
    """A non-editable install: the wheel holds the header, and its ``catanc client --cflags`` finds it."""
    repo, source = HEADER.parents[3], tmp_path / "source"  # a copy: the build writes its own folders
    for folder in ("catanc", "templates"):
        shutil.copytree(repo / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__"))
    for file in ("pyproject.toml", "README.md"):
        shutil.copy(repo / file, source / file)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", str(source), "-w", str(tmp_path / "wheel")],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    if built.returncode != 0 and "No matching distribution" in built.stderr:
        pytest.skip("pip cannot reach an index for the build's setuptools")
    assert built.returncode == 0, built.stderr
    (wheel,) = (tmp_path / "wheel").glob("catanc-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        assert "catanc/include/catanc/client.hpp" in archive.namelist()
        archive.extractall(tmp_path / "site")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site")}
    flags = subprocess.run(
        [sys.executable, "-m", "catanc", "client", "--cflags"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout.split()
    assert flags == [f"-I{tmp_path / 'site' / 'catanc' / 'include'}"]
    assert (tmp_path / "site" / "catanc" / "include" / "catanc" / "client.hpp").read_bytes() == HEADER.read_bytes()
