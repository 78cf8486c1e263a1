"""The trigger protocol, the node client and the synthetic worker.

A real :class:`EnforcerSocket` in a temporary folder plays the enforcer in
the test thread; clients run in threads, workers in processes.  Every wait
has a generous timeout; nothing here measures speed.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.client import ClientError, Node
from catanc.core.load import load_spec
from catanc.core.workload import ComputeSampler
from catanc.runtime.protocol import (
    MAX_DATAGRAM,
    MAX_NAME,
    MESSAGE_TYPES,
    SOCKET_ENV,
    Address,
    Bye,
    Done,
    EnforcerSocket,
    Hello,
    Message,
    ProtocolError,
    Reject,
    SetCores,
    SocketPathError,
    Stop,
    Trigger,
    Welcome,
    decode,
    trigger_datagram,
)
from catanc.runtime.worker import (
    RunRecord,
    burn_parallel,
    check_profile,
    format_modes,
    parse_args,
    parse_modes,
    read_records,
    worker_command,
    worker_groups,
    workload_worker_command,
    write_records,
)

TIMEOUT_S = 30.0
"""The bound on every wait: generous, since nothing here is timed."""

M = TypeVar("M", bound=Message)


# -- helpers -----------------------------------------------------------------------------------


class Background:
    """Run ``target`` in a daemon thread; :meth:`join` returns its result or raises its exception."""

    def __init__(self, target: Callable[[], Any]) -> None:
        self.target = target
        self.result: Any = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.result = self.target()
        except BaseException as exc:
            self.error = exc

    def join(self) -> Any:
        self.thread.join(TIMEOUT_S)
        assert not self.thread.is_alive(), "the client thread did not finish"
        if self.error is not None:
            raise self.error
        return self.result


def expect(enforcer: EnforcerSocket, kind: type[M]) -> tuple[M, Address]:
    received = enforcer.receive(TIMEOUT_S)
    assert received is not None, f"no {kind.__name__} within {TIMEOUT_S} s"
    message, sender = received
    assert isinstance(message, kind), f"expected a {kind.__name__}, got {message!r}"
    return message, sender


def welcome(enforcer: EnforcerSocket, names: set[str]) -> dict[str, tuple[Hello, Address]]:
    """Receive a hello from each node in ``names`` and welcome it."""
    seen: dict[str, tuple[Hello, Address]] = {}
    while set(seen) != names:
        hello, sender = expect(enforcer, Hello)
        assert hello.node in names
        seen[hello.node] = (hello, sender)
        assert enforcer.send(Welcome(hello.node), sender)
    return seen


def burn_ms(compute_ms: float) -> float:
    """Use ``compute_ms`` of this thread's CPU time; return what was used, in ms."""
    start = time.thread_time()
    while time.thread_time() - start < compute_ms / 1000.0:
        pass
    return (time.thread_time() - start) * 1000.0


@pytest.fixture
def enforcer(tmp_path: Path) -> Iterator[EnforcerSocket]:
    with EnforcerSocket(tmp_path / "catanc.sock") as sock:
        yield sock


# -- the client against a scripted enforcer ----------------------------------------------------


def test_register_welcome_and_stop_ends_the_loop(enforcer: EnforcerSocket) -> None:
    def client() -> tuple[bool, int | None, int, list[Trigger], bool]:
        with Node("LM", socket_path=enforcer.path) as node:
            registered = node.registered
            triggers = list(node)
            return registered, node.tid, threading.get_native_id(), triggers, node.stopped

    background = Background(client)
    hello, sender = expect(enforcer, Hello)
    assert (hello.node, hello.pid) == ("LM", os.getpid())
    assert isinstance(sender, bytes)  # an autobound abstract address
    assert sender.startswith(b"\0")
    assert enforcer.send(Welcome("LM"), sender)
    assert enforcer.send(Stop(), sender)
    registered, tid, native_id, triggers, stopped = background.join()
    assert registered
    assert hello.tid == tid == native_id
    assert triggers == []
    assert stopped
    assert enforcer.receive(0) is None  # stopped by the enforcer: no bye


def test_trigger_work_done_round_trip(enforcer: EnforcerSocket) -> None:
    def client() -> dict[int, float]:
        burned: dict[int, float] = {}
        with Node("LM", socket_path=enforcer.path) as node:
            for trigger in node:
                assert node.trigger == trigger
                burned[trigger.seq] = burn_ms(30.0)
                node.done()
                assert node.trigger is None
        return burned

    background = Background(client)
    hello, sender = welcome(enforcer, {"LM"})["LM"]
    reported: dict[int, float | None] = {}
    for seq in (7, 8):
        assert enforcer.send(Trigger("LM", seq), sender)
        done, _ = expect(enforcer, Done)
        assert (done.node, done.tid, done.seq) == ("LM", hello.tid, seq)
        reported[seq] = done.compute_ms
    assert enforcer.send(Stop(), sender)
    burned = background.join()
    assert set(burned) == {7, 8}
    for seq, used in burned.items():
        compute = reported[seq]
        assert compute is not None
        assert used <= compute <= 1.5 * used  # the client's thread CPU time since the trigger arrived


def test_done_takes_the_nodes_own_measurement_and_wait_completes_a_pending_run(enforcer: EnforcerSocket) -> None:
    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            for trigger in node:
                if trigger.seq == 1:
                    node.done(compute_ms=2.5)
                # seq 2: no done(); the next step of the loop reports it

    background = Background(client)
    _, sender = welcome(enforcer, {"LM"})["LM"]
    assert enforcer.send(Trigger("LM", 1), sender)
    assert expect(enforcer, Done)[0].compute_ms == 2.5
    assert enforcer.send(Trigger("LM", 2), sender)
    done, _ = expect(enforcer, Done)
    assert done.seq == 2
    assert done.compute_ms is not None
    assert enforcer.send(Stop(), sender)
    background.join()


def test_wait_times_out_with_none(enforcer: EnforcerSocket) -> None:
    def client() -> tuple[Trigger | None, bool]:
        with Node("LM", socket_path=enforcer.path) as node:
            return node.wait(timeout_s=0.01), node.stopped

    background = Background(client)
    welcome(enforcer, {"LM"})
    assert background.join() == (None, False)
    bye, _ = expect(enforcer, Bye)  # left on its own: says bye
    assert bye.node == "LM"


def test_interrupt_ends_the_loop_from_another_thread_and_says_bye(enforcer: EnforcerSocket) -> None:
    node = Node("LM", socket_path=enforcer.path)

    def client() -> list[Trigger]:
        with node:
            return list(node)

    background = Background(client)
    hello, _ = welcome(enforcer, {"LM"})["LM"]
    node.interrupt()
    assert background.join() == []
    assert node.stopped
    bye, _ = expect(enforcer, Bye)
    assert bye == Bye("LM", hello.tid)
    node.interrupt()  # after close: harmless


def test_interrupt_before_registering_skips_the_loop(enforcer: EnforcerSocket) -> None:
    node = Node("LM", socket_path=enforcer.path)
    node.interrupt()
    with node:
        assert not node.registered
        assert node.stopped
        assert list(node) == []
    hello, _ = expect(enforcer, Hello)
    assert expect(enforcer, Bye)[0] == Bye("LM", hello.tid)


def test_wait_and_done_belong_to_the_registered_thread(enforcer: EnforcerSocket) -> None:
    node = Node("LM", socket_path=enforcer.path)
    with pytest.raises(ClientError, match="register before wait"):
        node.wait(0)
    registered = threading.Event()
    release = threading.Event()

    def client() -> None:
        with node:
            with pytest.raises(ClientError, match="done\\(\\) without a trigger"):
                node.done()
            registered.set()
            assert release.wait(TIMEOUT_S)
            assert list(node) == []

    background = Background(client)
    _, sender = welcome(enforcer, {"LM"})["LM"]
    assert registered.wait(TIMEOUT_S)
    with pytest.raises(ClientError, match="call wait\\(\\) from that thread"):
        node.wait(0)
    release.set()
    assert enforcer.send(Stop(), sender)
    background.join()
    with pytest.raises(ClientError, match="already registered"):
        node.register()


def test_reject_is_a_client_error_with_the_reason(enforcer: EnforcerSocket) -> None:
    def client() -> None:
        with Node("XX", socket_path=enforcer.path):
            pytest.fail("registered although rejected")

    background = Background(client)
    hello, sender = expect(enforcer, Hello)
    assert enforcer.send(Reject(hello.node, "unknown node 'XX' (did you mean 'LM'?)"), sender)
    with pytest.raises(ClientError, match="rejected node 'XX': unknown node 'XX' \\(did you mean 'LM'\\?\\)"):
        background.join()
    assert enforcer.receive(0) is None  # rejected: no bye


def test_no_enforcer_at_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "missing.sock"
    with pytest.raises(ClientError, match=r"no catanc enforcer at .*missing\.sock .*: is `catanc run` running\?"):
        Node("LM", socket_path=missing).register()


def test_a_stale_socket_file_is_no_enforcer(tmp_path: Path) -> None:
    path = tmp_path / "stale.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as dead:
        dead.bind(str(path))
    with pytest.raises(ClientError, match=r"Connection refused.*is `catanc run` running"):
        Node("LM", socket_path=path).register()


def test_an_enforcer_that_never_answers(enforcer: EnforcerSocket) -> None:
    with pytest.raises(ClientError, match=r"no answer in 0\.05 s\): is `catanc run` running\?"):
        Node("LM", socket_path=enforcer.path, timeout_s=0.05).register()
    hello, _ = expect(enforcer, Hello)
    assert hello.node == "LM"


def test_the_socket_comes_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SOCKET_ENV, str(tmp_path / "env.sock"))
    assert Node("LM").socket_path == tmp_path / "env.sock"
    monkeypatch.delenv(SOCKET_ENV)
    with pytest.raises(ClientError, match="CATANC_SOCKET is not set"):
        Node("LM")


@pytest.mark.parametrize("name", ["", "a\nb", "x" * (MAX_NAME + 1)])
def test_bad_node_names(tmp_path: Path, name: str) -> None:
    with pytest.raises(ClientError, match="bad node name"):
        Node(name, socket_path=tmp_path / "catanc.sock")


def test_a_vanished_enforcer_ends_the_wait_with_an_error(
    enforcer: EnforcerSocket, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(Node, "PROBE_S", 0.02)
    registered = threading.Event()

    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            registered.set()
            list(node)

    background = Background(client)
    welcome(enforcer, {"LM"})
    assert registered.wait(TIMEOUT_S)
    enforcer.close()  # no stop: a crash, as the node sees it
    with pytest.raises(ClientError, match="went away without stopping node 'LM'"):
        background.join()


# -- the protocol ------------------------------------------------------------------------------

_printable = st.characters(exclude_categories=("C", "Z")) | st.just(" ")
names = st.text(_printable, min_size=1, max_size=MAX_NAME).filter(str.isprintable)
positive = st.integers(1, 2**63 - 1)
counts = st.integers(0, 2**63 - 1)
compute = st.none() | st.floats(0, allow_nan=False, allow_infinity=False) | st.integers(0, 10**9)

messages: st.SearchStrategy[Message] = st.one_of(
    st.builds(Hello, names, positive, positive),
    st.builds(Done, names, positive, counts, compute),
    st.builds(Bye, names, positive),
    st.builds(Welcome, names),
    st.builds(Trigger, names, counts, positive),
    st.builds(Reject, names, st.text(max_size=3000)),
    st.just(Stop()),
    st.builds(SetCores, positive),
)


@given(messages)
def test_decode_inverts_encode(message: Message) -> None:
    data = message.encode()
    assert len(data) <= MAX_DATAGRAM
    assert json.loads(data)["v"] == 1
    assert decode(data) == message


@given(names | st.sampled_from(['"seq":0,', 'a","seq":0,"b']), counts, positive)
def test_a_trigger_datagram_is_the_trigger_message_encoded(node: str, seq: int, threads: int) -> None:
    data = trigger_datagram(node, seq, threads)
    assert data == Trigger(node, seq, threads).encode()
    assert decode(data) == Trigger(node, seq, threads)


def _raises_only_protocol_errors(data: bytes) -> None:
    try:
        message = decode(data)
    except ProtocolError as exc:
        assert str(exc)
    else:
        assert decode(message.encode()) == message


@given(st.binary(max_size=MAX_DATAGRAM + 8))
def test_decode_raises_only_protocol_errors_on_any_bytes(data: bytes) -> None:
    _raises_only_protocol_errors(data)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6,
)
field_names = st.sampled_from(["node", "pid", "tid", "seq", "compute_ms", "reason", "cores", "extra"])
field_values = json_values | names | st.integers(-3, 3) | st.floats(-1, 1e3)


@given(
    st.sampled_from([1, 1, 1, 2, 1.0, True, "1", None]),
    st.sampled_from([*MESSAGE_TYPES, "dance", 3, None]),
    st.dictionaries(field_names, field_values, max_size=6),
)
def test_decode_raises_only_protocol_errors_on_near_messages(version: Any, kind: Any, body: dict[str, Any]) -> None:
    document = dict(body)
    if version is not None:
        document["v"] = version
    if kind is not None:
        document["type"] = kind
    _raises_only_protocol_errors(json.dumps(document).encode())


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b"\xff{}", r"not UTF-8 \(byte 0\)"),
        (b"{", "not JSON"),
        (b"[1]", "a message is a JSON object, got list"),
        (b'{"type":"stop"}', 'no protocol version: a message carries "v": 1'),
        (b'{"v":2,"type":"stop"}', "protocol version 2; this catanc speaks version 1"),
        (b'{"v":true,"type":"stop"}', "protocol version True"),
        (b'{"v":1}', "no message type"),
        (b'{"v":1,"type":"dance"}', r"unknown message type 'dance' \(expected one of: hello, done, bye,"),
        (b'{"v":1,"type":"hello","node":"LM","pid":1}', r"hello: missing field\(s\): tid"),
        (b'{"v":1,"type":"stop","why":0}', r"stop: unknown field\(s\): 'why' \(expected: none\)"),
        (b'{"v":1,"type":"hello","node":"LM","pid":"1","tid":2}', "hello.pid: expected a positive integer, got '1'"),
        (b'{"v":1,"type":"hello","node":"","pid":1,"tid":2}', "hello.node: a node name is 1 to 128 printable"),
        (b'{"v":1,"type":"trigger","node":"LM","seq":-1}', "trigger.seq: expected a non-negative integer"),
        (b'{"v":1,"type":"done","node":"LM","tid":1,"seq":1,"compute_ms":-1}', "done.compute_ms: expected a finite"),
        (b'{"v":1,"type":"done","node":"LM","tid":1,"seq":1,"compute_ms":NaN}', "done.compute_ms"),
        (b'{"v":1,"type":"done","node":"LM","tid":1,"seq":1,"compute_ms":true}', "done.compute_ms"),
        (b'{"v":1,"type":"set_cores","cores":0}', "set_cores.cores: expected a positive integer, got 0"),
        (b" " * (MAX_DATAGRAM + 1), "at most 1024 are accepted"),
    ],
)
def test_decode_explains_what_is_wrong(data: bytes, error: str) -> None:
    with pytest.raises(ProtocolError, match=error):
        decode(data)


def test_wire_format_is_compact_json_with_version_and_type() -> None:
    assert Done("LM", 12, 3, 1.5).encode() == b'{"v":1,"type":"done","node":"LM","tid":12,"seq":3,"compute_ms":1.5}'
    assert Stop().encode() == b'{"v":1,"type":"stop"}'
    assert decode(b'{"type":"done","v":1,"seq":3,"node":"LM","tid":12,"compute_ms":null}') == Done("LM", 12, 3, None)
    assert Done("LM", 1, 1, 2).compute_ms == 2.0
    assert isinstance(ProtocolError("x"), ValueError)


@pytest.mark.parametrize("reason", ["x" * 5000, "é" * 2000, "\n" * 1000])
def test_long_reject_reasons_are_shortened_to_fit(reason: str) -> None:
    reject = Reject("LM", reason)
    assert len(reject.encode()) <= MAX_DATAGRAM
    assert reject.reason.endswith("...")
    assert reason.startswith(reject.reason[:-3])
    assert decode(reject.encode()) == reject


def test_messages_check_their_fields_when_built() -> None:
    with pytest.raises(ProtocolError, match=r"hello.tid"):
        Hello("LM", 1, 0)
    with pytest.raises(ProtocolError, match=r"reject.reason: not encodable"):
        Reject("LM", "\ud800")


# -- the enforcer's socket ---------------------------------------------------------------------


def test_enforcer_socket_refuses_to_replace_a_file(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    path.write_text("keep me\n")
    with pytest.raises(SocketPathError, match="exists and is not a socket: refusing"):
        EnforcerSocket(path)
    assert path.read_text() == "keep me\n"


def test_enforcer_socket_replaces_a_stale_socket_but_not_a_live_one(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as crashed:
        crashed.bind(str(path))
    with EnforcerSocket(path) as first:
        with pytest.raises(SocketPathError, match="another catanc enforcer is running at"):
            EnforcerSocket(path)
        assert path.exists()
        assert first.receive(0) is None
    assert not path.exists()
    first.close()  # twice: harmless


def test_enforcer_socket_leaves_a_successors_socket_alone(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    old = EnforcerSocket(path)
    path.unlink()
    with EnforcerSocket(path):
        old.close()
        assert path.exists()


def test_enforcer_socket_reports_an_unusable_path(tmp_path: Path) -> None:
    with pytest.raises(SocketPathError, match=r"cannot bind the enforcer's socket at .*No such file"):
        EnforcerSocket(tmp_path / "missing" / "catanc.sock")


def test_receive_skips_garbage_and_hears_unbound_senders(enforcer: EnforcerSocket) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as control:
        control.sendto(b"\xffnot a message", str(enforcer.path))
        control.sendto(b'{"v":1,"type":"set_cores","cores":"3"}', str(enforcer.path))
        control.sendto(SetCores(3).encode(), str(enforcer.path))
    assert enforcer.receive(TIMEOUT_S) == (SetCores(3), None)
    assert enforcer.dropped == 2
    assert not enforcer.send(Stop(), None)  # an unbound sender cannot be answered


def test_send_to_a_vanished_client_returns_false(enforcer: EnforcerSocket) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as client:
        client.bind("")
        address = client.getsockname()
        assert enforcer.send(Welcome("LM"), address)
        assert decode(client.recv(MAX_DATAGRAM)) == Welcome("LM")
    assert not enforcer.send(Trigger("LM", 1), address)
    assert not enforcer.send(Trigger("LM", 1), str(enforcer.path.with_name("gone.sock")))


# -- the synthetic worker ----------------------------------------------------------------------


def test_worker_command_writes_each_profile_next_to_its_node(tmp_path: Path) -> None:
    argv = worker_command(
        {"A": 5, "B": [(0.8, 1), (0.2, 12.5)]}, seed=3, scale_after=(5, 3), socket_path=tmp_path / "s.sock"
    )
    assert argv == [
        sys.executable,
        "-m",
        "catanc.runtime.worker",
        "--node",
        "A",
        "--compute-ms",
        "5.0",
        "--node",
        "B",
        "--modes",
        "0.8:1.0,0.2:12.5",
        "--seed",
        "3",
        "--scale-after",
        "5.0:3.0",
        "--socket",
        str(tmp_path / "s.sock"),
    ]
    options = parse_args(argv[3:])
    assert options.nodes == {"A": ((1.0, 5.0),), "B": ((0.8, 1.0), (0.2, 12.5))}
    assert (options.seed, options.scale_after, options.socket_path) == (3, (5.0, 3.0), tmp_path / "s.sock")
    short = ["python3", "-m", "catanc.runtime.worker", "--node", "A", "--compute-ms", "1.0"]
    assert worker_command({"A": 1.0}, python="python3") == short


@pytest.mark.parametrize(
    ("nodes", "error"),
    [
        ({}, "at least one node"),
        ({"A": -1.0}, "compute time must be a number of ms >= 0"),
        ({"A": []}, "at least one mode"),
        ({"A": [(0.0, 1.0)]}, "weight must be a positive number"),
        ({"": 1.0}, "bad node name"),
    ],
)
def test_worker_command_refuses_bad_profiles(nodes: dict[str, Any], error: str) -> None:
    with pytest.raises(ValueError, match=error):
        worker_command(nodes)


def test_modes_round_trip_through_text() -> None:
    modes = check_profile([(0.8, 1), (0.2, 12)])
    assert parse_modes(format_modes(modes)) == modes == ((0.8, 1.0), (0.2, 12.0))
    with pytest.raises(ValueError, match=r"'0.8' is not WEIGHT:MS"):
        parse_modes("0.8,0.2:12")


def test_worker_options_share_one_profile_or_take_one_per_node() -> None:
    shared = parse_args(["--node", "A", "--node", "B", "--compute-ms", "2"])
    assert shared.nodes == {"A": ((1.0, 2.0),), "B": ((1.0, 2.0),)}
    assert (shared.seed, shared.scale_after, shared.socket_path) == (0, None, None)


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["--node", "A"], "give each node a compute time"),
        (["--node", "A", "--node", "B", "--node", "C", "--compute-ms", "1", "--compute-ms", "2"], "3 nodes but 2"),
        (["--node", "A", "--node", "A", "--compute-ms", "1"], "node(s) given twice: A"),
        (["--node", "A", "--compute-ms", "fast"], "'fast' is not a number of ms"),
        (["--node", "A", "--compute-ms", "-2"], "compute time must be a number of ms >= 0"),
        (["--node", "A", "--modes", "1:x"], "'1:x' is not WEIGHT:MS (two numbers)"),
        (["--node", "A", "--compute-ms", "1", "--scale-after", "5"], "'5' is not S:FACTOR"),
        (["--node", "A", "--compute-ms", "1", "--scale-after", "5:-1"], "the factor must be a number >= 0"),
    ],
)
def test_worker_usage_errors(argv: list[str], error: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        parse_args(argv)
    assert exited.value.code == 2
    assert error in capsys.readouterr().err


def test_worker_groups_put_an_executors_nodes_in_one_worker() -> None:
    nodes = ["scan", "GL", "GM", "GP", "NC"]
    assert worker_groups(nodes, {}) == [("scan",), ("GL",), ("GM",), ("GP",), ("NC",)]
    assert worker_groups(nodes, {"mapper": ["GM", "GL"], "nav": ["NC", "GP"]}) == [
        ("scan",),
        ("GL", "GM"),
        ("GP", "NC"),
    ]
    argv = worker_command({"GL": 3.0, "GM": 150.0}, executors=[("GL", "GM")], python="python3")
    assert argv[-2:] == ["--executor", "GL,GM"]
    assert parse_args(argv[3:]).executors == (("GL", "GM"),)
    with pytest.raises(ValueError, match="does not serve GP"):
        worker_command({"GL": 3.0}, executors=[("GL", "GP")])


@pytest.mark.parametrize(
    ("extra", "error"),
    [
        (["--executor", "A"], "give two or more different nodes"),
        (["--executor", "A,A"], "give two or more different nodes"),
        (["--executor", "A,C"], "this worker does not serve C"),
        (["--executor", "A,B", "--executor", "B,A"], "B, A already in another executor"),
    ],
)
def test_worker_executor_usage_errors(extra: list[str], error: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        parse_args(["--node", "A", "--node", "B", "--compute-ms", "1", *extra])
    assert exited.value.code == 2
    assert error in capsys.readouterr().err


Spawn = Callable[[list[str]], "subprocess.Popen[str]"]


@pytest.fixture
def spawn() -> Iterator[Spawn]:
    started: list[subprocess.Popen[str]] = []

    def start(argv: list[str]) -> subprocess.Popen[str]:
        process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(process)
        return process

    yield start
    for process in started:
        if process.poll() is None:
            process.kill()
        process.communicate(timeout=TIMEOUT_S)


def finish(process: subprocess.Popen[str]) -> tuple[int, str]:
    _, err = process.communicate(timeout=TIMEOUT_S)
    return process.returncode, err


def run_once(enforcer: EnforcerSocket, node: str, seq: int, sender: Address) -> float:
    assert enforcer.send(Trigger(node, seq), sender)
    done, _ = expect(enforcer, Done)
    assert (done.node, done.seq) == (node, seq)
    assert done.compute_ms is not None
    return done.compute_ms


def test_worker_runs_its_nodes_in_threads_and_exits_on_stop(enforcer: EnforcerSocket, spawn: Spawn) -> None:
    process = spawn(worker_command({"A": 20.0, "B": [(1.0, 5.0)]}, socket_path=enforcer.path))
    hellos = welcome(enforcer, {"A", "B"})
    assert hellos["A"][0].pid == hellos["B"][0].pid == process.pid
    assert hellos["A"][0].tid != hellos["B"][0].tid
    for seq in (1, 2):
        assert 20.0 <= run_once(enforcer, "A", seq, hellos["A"][1]) <= 30.0
        assert 5.0 <= run_once(enforcer, "B", seq, hellos["B"][1]) <= 7.5
    for _, sender in hellos.values():
        assert enforcer.send(Stop(), sender)
    assert finish(process) == (0, "")
    assert enforcer.receive(0) is None  # stopped: no bye


@pytest.mark.parametrize("shared", [False, True])
def test_worker_runs_an_executors_nodes_one_after_the_other(
    enforcer: EnforcerSocket, spawn: Spawn, tmp_path: Path, shared: bool
) -> None:
    # A and B (40 ms each) triggered together, three times. Apart, their threads run at once (the
    # interpreter lock interleaves them): every pair of runs overlaps. In one executor, never.
    record = tmp_path / "runs"
    executors = [("A", "B")] if shared else []
    process = spawn([*worker_command({"A": 40.0, "B": 40.0}, socket_path=enforcer.path, executors=executors),
                     "--record", str(record)])  # fmt: skip
    hellos = welcome(enforcer, {"A", "B"})
    for seq in (1, 2, 3):
        assert enforcer.send(Trigger("A", seq), hellos["A"][1])
        assert enforcer.send(Trigger("B", seq), hellos["B"][1])
        assert {expect(enforcer, Done)[0].node for _ in range(2)} == {"A", "B"}
    for _, sender in hellos.values():
        assert enforcer.send(Stop(), sender)
    assert finish(process) == (0, "")
    runs = read_records(record)
    a = [run for run in runs if run.node == "A"]
    b = [run for run in runs if run.node == "B"]
    assert len(a) == len(b) == 3
    overlapping = sum(1 for x in a for y in b if x.start_ns < y.end_ns and y.start_ns < x.end_ns)
    assert overlapping == (0 if shared else 3)


def test_worker_draws_modes_from_its_seed(enforcer: EnforcerSocket, spawn: Spawn) -> None:
    def modes_drawn() -> list[bool]:
        process = spawn(worker_command({"M": [(0.5, 2.0), (0.5, 40.0)]}, seed=1, socket_path=enforcer.path))
        _, sender = welcome(enforcer, {"M"})["M"]
        drawn = []
        for seq in range(16):
            compute = run_once(enforcer, "M", seq, sender)
            assert 2.0 <= compute <= 3.0 or 40.0 <= compute <= 60.0
            drawn.append(compute > 20.0)
        assert enforcer.send(Stop(), sender)
        assert finish(process) == (0, "")
        return drawn

    first = modes_drawn()
    assert any(first)
    assert not all(first)
    assert modes_drawn() == first


def test_worker_scales_compute_after_the_given_time(enforcer: EnforcerSocket, spawn: Spawn) -> None:
    process = spawn(worker_command({"A": 10.0}, scale_after=(2.0, 3.0), socket_path=enforcer.path))
    _, sender = welcome(enforcer, {"A"})["A"]
    computes = [run_once(enforcer, "A", 0, sender)]
    deadline = time.monotonic() + TIMEOUT_S
    while computes[-1] < 20.0 and time.monotonic() < deadline:
        computes.append(run_once(enforcer, "A", len(computes), sender))
    computes += [run_once(enforcer, "A", len(computes) + i, sender) for i in range(3)]
    assert enforcer.send(Stop(), sender)
    assert finish(process) == (0, "")
    before, after = computes[0], computes[-4:]
    assert 10.0 <= before <= 15.0
    assert all(30.0 <= compute <= 45.0 for compute in after)
    assert all(2.0 <= compute / before <= 4.5 for compute in after)  # ~3x
    switch = next(i for i, compute in enumerate(computes) if compute >= 20.0)
    assert all(compute < 15.0 for compute in computes[:switch])
    assert all(compute >= 30.0 for compute in computes[switch:])  # and it stays slow


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_worker_exits_cleanly_on_signals(enforcer: EnforcerSocket, spawn: Spawn, signum: signal.Signals) -> None:
    process = spawn(worker_command({"A": 1.0, "B": 1.0}, socket_path=enforcer.path))
    hellos = welcome(enforcer, {"A", "B"})
    run_once(enforcer, "A", 1, hellos["A"][1])
    process.send_signal(signum)
    assert finish(process) == (0, "")
    byes = {expect(enforcer, Bye)[0], expect(enforcer, Bye)[0]}
    assert byes == {Bye("A", hellos["A"][0].tid), Bye("B", hellos["B"][0].tid)}


def test_worker_without_an_enforcer_fails_with_a_hint(tmp_path: Path) -> None:
    argv = worker_command({"A": 1.0}, socket_path=tmp_path / "none.sock")
    finished = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    assert finished.returncode == 1
    assert "no catanc enforcer at" in finished.stderr
    assert "is `catanc run` running?" in finished.stderr


# -- the worker's workload option: the spec's model, a shared clock, run records ----------------

WORKLOAD_SPEC = """\
catan: 1
app: drawn
nodes:
  M: {compute_ms: {modes: [{share: 0.5, ms: 2}, {share: 0.5, ms: 30}]}}
  G: {compute_ms: 4, workload: {growth: {start: 1, end: 3, over_s: 100}}}
  S: {scheduled: false, rate_hz: 10}
edges: [[S, M], [M, G]]
subchains: {m: [M], g: [G]}
objective: [{chain: [S, M, G], weight: 1}]
"""


def test_workload_worker_command_round_trips(tmp_path: Path) -> None:
    argv = workload_worker_command(
        ["M", "G"],
        tmp_path / "spec.yaml",
        seed=4,
        clock_start_ns=123,
        record=tmp_path / "runs",
        socket_path=tmp_path / "s.sock",
        speedups={"G": (1.0, 1.5), "X": (1.0, 2.0)},
    )
    options = parse_args(argv[3:])
    assert options.nodes == {"M": (), "G": ()}  # the spec's model draws
    assert (options.workload, options.record) == (tmp_path / "spec.yaml", tmp_path / "runs")
    assert options.clock_start_ns == 123
    assert (options.seed, options.speedups, options.socket_path) == (4, {"G": (1.0, 1.5)}, tmp_path / "s.sock")
    with pytest.raises(ValueError, match="clock-start-ns"):
        workload_worker_command(["M"], "spec.yaml", clock_start_ns=-1)


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["--node", "A", "--workload", "s.yaml", "--compute-ms", "1"], "give no --compute-ms or --modes with it"),
        (["--node", "A", "--compute-ms", "1", "--clock-start-ns", "5"], "--clock-start-ns goes with --workload"),
        (["--node", "A", "--workload", "s.yaml", "--clock-start-ns", "soon"], "'soon' is not a CLOCK_MONOTONIC time"),
    ],
)
def test_workload_usage_errors(argv: list[str], error: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        parse_args(argv)
    assert exited.value.code == 2
    assert error in capsys.readouterr().err


def test_run_records_round_trip(tmp_path: Path) -> None:
    records = [RunRecord("LM", 10, 20, 9), RunRecord("a node", 30, 45, 15)]
    write_records(tmp_path / "runs", records)
    assert read_records(tmp_path / "runs") == records
    assert [p.name for p in tmp_path.iterdir()] == ["runs"]  # no temporary file left
    (tmp_path / "bad").write_text('{"node": "LM", "start_ns": 1}\n')
    with pytest.raises(ValueError, match="bad:1: not a run record"):
        read_records(tmp_path / "bad")


def test_worker_draws_from_the_specs_workload_and_records_every_run(
    enforcer: EnforcerSocket, spawn: Spawn, tmp_path: Path
) -> None:
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(WORKLOAD_SPEC)
    record = tmp_path / "runs.jsonl"
    # The model's time counts from 100 s ago: G's growth has reached its end, 3x its 4 ms.
    clock_start = time.monotonic_ns() - 100 * 10**9
    began = time.monotonic_ns()
    argv = workload_worker_command(
        ["M", "G"], spec_path, seed=7, clock_start_ns=clock_start, record=record, socket_path=enforcer.path
    )
    process = spawn(argv)
    hellos = welcome(enforcer, {"M", "G"})
    measured = [run_once(enforcer, "M", seq, hellos["M"][1]) for seq in range(12)]
    grown = [run_once(enforcer, "G", seq, hellos["G"][1]) for seq in range(3)]
    for _, sender in hellos.values():
        assert enforcer.send(Stop(), sender)
    assert finish(process) == (0, "")
    ended = time.monotonic_ns()
    sampler = ComputeSampler(load_spec(spec_path), 7)
    drawn = [sampler.compute_ms("M", 100.0) for _ in range(12)]  # M's draws do not depend on the time
    assert {2.0, 30.0} == set(drawn)
    for got, want in zip(measured, drawn, strict=True):
        assert want <= got <= want * 1.5 + 1.0
    assert all(12.0 <= got <= 20.0 for got in grown)
    runs = read_records(record)
    assert [r.node for r in runs].count("M") == 12
    assert [r.node for r in runs].count("G") == 3
    for r in runs:
        assert began <= r.start_ns < r.end_ns <= ended
        assert r.cpu_ns <= r.end_ns - r.start_ns + 1_000_000  # CPU time never exceeds the run by much
    m_cpu = [r.cpu_ns / 1e6 for r in sorted(runs) if r.node == "M"]
    assert m_cpu == pytest.approx(drawn, rel=0.5, abs=1.0)


def test_worker_refuses_a_node_its_workload_spec_does_not_schedule(tmp_path: Path) -> None:
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(WORKLOAD_SPEC)
    argv = workload_worker_command(["S"], spec_path, socket_path=tmp_path / "none.sock")
    finished = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    assert finished.returncode == 2
    assert "does not schedule node 'S'" in finished.stderr


# -- importing the client is light -------------------------------------------------------------


@pytest.fixture(scope="module")
def client_imports() -> set[str]:
    code = "import json, sys\nimport catanc.client\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=TIMEOUT_S, check=True)
    return set(json.loads(out.stdout))


@pytest.mark.parametrize(
    "module",
    [
        "cvxpy",
        "pulp",
        "numpy",
        "scipy",
        "highspy",
        "clarabel",
        "catanc.planning.planner",
        "catanc.planning.stage1",
        "catanc.planning.stage2",
        "catanc.planning.replan",
        "pydantic",
        "yaml",
        "networkx",
    ],
)
def test_importing_the_client_loads_no_solver(client_imports: set[str], module: str) -> None:
    loaded = sorted(name for name in client_imports if name == module or name.startswith(module + "."))
    assert not loaded, f"importing catanc.client loads {loaded}"


def test_a_trigger_without_threads_means_one_and_zero_threads_is_refused() -> None:
    assert decode(b'{"v":1,"type":"trigger","node":"LM","seq":3}') == Trigger("LM", 3, 1)
    assert decode(b'{"v":1,"type":"trigger","node":"LM","seq":3,"threads":2}') == Trigger("LM", 3, 2)
    with pytest.raises(ProtocolError, match="threads"):
        decode(b'{"v":1,"type":"trigger","node":"LM","seq":3,"threads":0}')
    with pytest.raises(ProtocolError, match="missing field"):
        decode(b'{"v":1,"type":"trigger","node":"LM"}')  # seq has no default


def test_parallel_burn_uses_the_threads_the_speedup_makes_worth_it() -> None:
    # 2 threads at speedup 1.8: each burns 20 / 1.8 ms, so the process uses about 2 x 11.1 ms of CPU.
    began = time.process_time()
    burn_parallel(20.0, 2, (1.0, 1.8))
    assert time.process_time() - began == pytest.approx(2 * 20.0 / 1.8 / 1000, rel=0.25)
    # A third thread would not help (speedup 1.8 again): still two.
    began = time.process_time()
    burn_parallel(20.0, 3, (1.0, 1.8, 1.8))
    assert time.process_time() - began == pytest.approx(2 * 20.0 / 1.8 / 1000, rel=0.25)
    began = time.process_time()
    burn_parallel(10.0, 1, (1.0, 1.8))
    assert time.process_time() - began == pytest.approx(0.010, rel=0.25)


def test_worker_speedup_option() -> None:
    argv = worker_command({"A": 5.0, "B": 1.0}, speedups={"A": (1.0, 1.8), "B": (1.0,), "C": (1.0, 2.0)})
    options = parse_args(argv[3:])
    assert options.speedups == {"A": (1.0, 1.8)}  # B gains nothing from threads; C is not served here
    with pytest.raises(ValueError, match="starts with 1"):
        worker_command({"A": 5.0}, speedups={"A": (2.0, 3.0)})
    with pytest.raises(SystemExit):
        parse_args(["--node", "A", "--compute-ms", "1", "--speedup", "Z=1,2"])
