"""The protocol ``catanc/2`` (datagrams and rings) and the enforcer's end of it (its socket, endpoints, registry).

Datagrams against hand-written bytes and hypothesis round trips; rings against a writer and
reader that share only the documented layout; the socket and endpoints for real, in a
temporary folder (no privileges needed).
"""

from __future__ import annotations

import array
import fcntl
import mmap
import os
import socket
import struct
import threading
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.runtime.protocol import ring
from catanc.runtime.protocol.endpoints import (
    Credentials,
    Endpoint,
    EnforcerSocket,
    RateLimit,
    Registry,
    SocketPathError,
    check_private_folder,
    may_register,
    open_endpoint,
)
from catanc.runtime.protocol.messages import (
    MAX_DATAGRAM,
    Bye,
    Done,
    Hello,
    Message,
    ProtocolError,
    Reject,
    Route,
    SetCores,
    Stop,
    Trigger,
    Welcome,
    decode,
    format_address,
    parse_address,
    trigger_datagram,
)

names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,127}", fullmatch=True)
positive = st.integers(1, 2**63 - 1)
counts = st.integers(0, 2**63 - 1)
addresses = st.none() | st.binary(min_size=1, max_size=108)

messages: st.SearchStrategy[Message] = st.one_of(
    st.builds(Hello, names, positive, positive),
    st.builds(Bye, names, positive),
    st.builds(Done, names, positive, counts),
    st.builds(SetCores, positive),
    st.builds(Welcome, names, positive),
    st.builds(Trigger, names, counts, positive),
    st.builds(Reject, names, st.text(max_size=3000)),
    st.just(Stop()),
    st.builds(
        lambda node, notify, nxt, threads, prev: Route(
            node, notify, None if nxt is None else nxt[0], threads, None if nxt is None else nxt[1], prev
        ),
        names,
        st.booleans(),
        st.none() | st.tuples(names, st.binary(min_size=1, max_size=108)),
        positive,
        addresses,
    ),
)


# --------------------------------------------------------------------------- datagrams


@given(messages)
def test_decode_inverts_encode(message: Message) -> None:
    data = message.encode()
    assert len(data) <= MAX_DATAGRAM
    assert data.startswith(b"catanc/2 ")
    assert decode(data) == message


@given(names, counts, positive)
def test_a_trigger_datagram_is_the_trigger_message_encoded(node: str, seq: int, threads: int) -> None:
    assert trigger_datagram(node, seq, threads) == Trigger(node, seq, threads).encode()


def test_the_wire_format_is_words_after_the_protocol_and_version() -> None:
    """What a client in another language reads and writes, byte for byte."""
    assert Hello("LM", 4242, 4245).encode() == b"catanc/2 hello LM 4242 4245"
    assert Bye("LM", 4245).encode() == b"catanc/2 bye LM 4245"
    assert Done("LM", 4245, 17).encode() == b"catanc/2 done LM 4245 17"
    assert SetCores(3).encode() == b"catanc/2 set_cores 3"
    assert Welcome("LM", 64).encode() == b"catanc/2 welcome LM 64"
    assert Trigger("LM", 17, 2).encode() == b"catanc/2 trigger LM 17 2"
    assert Stop().encode() == b"catanc/2 stop"
    assert Reject("XX", "no node 'XX' in this app").encode() == b"catanc/2 reject XX no node 'XX' in this app"
    route = Route("LM", False, "LP", 1, b"\x0000a1f", None)
    assert route.encode() == b"catanc/2 route LM 0 LP 1 003030613166 -"
    assert Route("LP").encode() == b"catanc/2 route LP 0 - 1 - -"
    assert decode(b"catanc/2 route LP 1 - 1 - 0030303031") == Route("LP", True, None, 1, None, b"\x000001")
    # A node that runs on its input says so; its predecessor's route names it without an address.
    assert Hello("LP", 4242, 4246, on_input=True).encode() == b"catanc/2 hello LP 4242 4246 input"
    assert decode(b"catanc/2 hello LP 4242 4246 input") == Hello("LP", 4242, 4246, True)
    assert decode(b"catanc/2 route LM 0 LP 1 - -") == Route("LM", False, "LP", 1, None, None)


def test_addresses_are_the_hex_of_the_socket_name() -> None:
    assert format_address(b"\x0000001") == "003030303031"
    assert format_address("/run/catanc/a.sock") == "2f72756e2f636174616e632f612e736f636b"
    assert format_address(None) == "-"
    assert parse_address("003030303031") == b"\x0000001"
    assert parse_address("-") is None
    with pytest.raises(ProtocolError, match="hex digits"):
        parse_address("0g")


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b'{"v":1,"type":"hello","node":"LM","pid":1,"tid":2}', "not protocol catanc/2"),
        (b"catanc/1 hello LM 1 2", "not protocol catanc/2"),
        (b"hello LM 1 2", "not a catanc datagram"),
        (b"catanc/2", "no message type"),
        (b"catanc/2 dance", "unknown message type"),
        (b"catanc/2 hello LM 1", r"hello: expected 3 fields \(node pid tid\)"),
        (b"catanc/2 hello LM 1 2 3", "hello: expected 3 fields"),
        (b"catanc/2 hello LM -1 2", "hello.pid: expected a decimal integer"),
        (b"catanc/2 hello LM 0 2", "hello.pid: expected a positive integer"),
        (b"catanc/2 hello L-M 1 2", "a node name is an identifier"),
        (b"catanc/2 hello 9LM 1 2", "a node name is an identifier"),
        (b"catanc/2 hello \xc3\xa9 1 2", "not ASCII"),
        (b"catanc/2 trigger LM 99999999999999999999 1", "trigger.seq: expected a decimal integer"),
        (b"catanc/2 trigger LM 1 0", "trigger.threads: expected a positive integer"),
        (b"catanc/2 set_cores 0", "set_cores.cores: expected a positive integer"),
        (b"catanc/2 route LM 2 - 1 - -", "route.notify: expected 0 or 1"),
        (b"catanc/2 route LM 0 - 1 0030 -", "a next address needs its next node"),
        (b"catanc/2 hello LM 1 2 output", "hello: expected 3 fields"),
        (b"catanc/2 route LM 0 - 1 0x -", "hex digits"),
        (b"catanc/2 reject", "reject: missing its node"),
        (b" " * (MAX_DATAGRAM + 1), f"at most {MAX_DATAGRAM} are accepted"),
    ],
)
def test_decode_explains_what_is_wrong(data: bytes, error: str) -> None:
    with pytest.raises(ProtocolError, match=error):
        decode(data)


@given(st.binary(max_size=MAX_DATAGRAM + 8))
def test_decode_raises_only_protocol_errors_on_any_bytes(data: bytes) -> None:
    try:
        message = decode(data)
    except ProtocolError as exc:
        assert str(exc)
    else:
        assert decode(message.encode()) == message


KINDS = [b"hello", b"bye", b"done", b"set_cores", b"welcome", b"route", b"trigger", b"reject", b"stop"]


@given(
    st.sampled_from(KINDS),
    st.lists(
        st.sampled_from([b"LM", b"-", b"0", b"1", b"17", b"00303031", b"", b"x y", b"\xff", b"9" * 25]), max_size=7
    ),
)
def test_decode_raises_only_protocol_errors_on_near_messages(kind: bytes, words: list[bytes]) -> None:
    data = b" ".join([b"catanc/2", kind, *words])
    try:
        message = decode(data)
    except ProtocolError:
        return
    assert decode(message.encode()) == message


@pytest.mark.parametrize("reason", ["x" * 5000, "é" * 2000, "two\nlines\tand tabs"])
def test_reject_reasons_are_one_line_and_shortened_to_fit(reason: str) -> None:
    reject = Reject("LM", reason)
    assert len(reject.encode()) <= MAX_DATAGRAM
    assert "\n" not in reject.reason
    assert decode(reject.encode()) == reject


# --------------------------------------------------------------------------- rings


def test_a_ring_round_trips_its_entries_in_order() -> None:
    fd = ring.create(slots=4)
    try:
        writer, reader = ring.RingWriter(fd), ring.RingReader(fd, 4)
        assert reader.new() == []
        writer.append(1, 100, 200, 50, 1)
        writer.append(2, 300, 400, ring.UNKNOWN, 2)
        first, second = reader.new()
        assert first == ring.Entry(1, 100, 200, 50, 1)
        assert (first.compute_ms, second.compute_ms) == (50 / 1e6, None)
        assert reader.new() == []
        for seq in range(3, 10):  # 7 entries into 4 slots: the 3 oldest are lost
            writer.append(seq, seq, seq + 1)
        assert [entry.seq for entry in reader.new()] == [6, 7, 8, 9]
        assert reader.overrun == 3
        writer.close()
        reader.close()
    finally:
        os.close(fd)


def test_a_ring_has_the_documented_layout() -> None:
    """A reader written from the docstring alone (struct offsets), not from RingReader."""
    fd = ring.create(slots=8)
    try:
        writer = ring.RingWriter(fd)
        writer.append(17, 1_000, 3_000, 1_500, 2)
        raw = os.pread(fd, 64 + 8 * 48, 0)
        magic, version, slots, entry_size, written = struct.unpack_from("=IIIIQ", raw, 0)
        assert raw[:4] == b"CATR"
        assert (magic, version, slots, entry_size, written) == (0x52544143, 1, 8, 48, 1)
        assert struct.unpack_from("=QQQQIIQ", raw, 64) == (17, 1_000, 3_000, 1_500, 2, 0, 0)
        assert len(raw) == ring.ring_size(8)
        writer.close()
    finally:
        os.close(fd)


def test_a_ring_cannot_grow_or_shrink() -> None:
    """A node holding the ring's descriptor cannot make the enforcer's mapping fault (SIGBUS) by shrinking it."""
    fd = ring.create()
    try:
        seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
        wanted = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL
        assert seals & wanted == wanted
        with pytest.raises(PermissionError):
            os.ftruncate(fd, 0)
        with pytest.raises(PermissionError):
            os.ftruncate(fd, 1 << 20)
    finally:
        os.close(fd)


def test_a_rewound_counter_is_taken_from_where_it_is() -> None:
    fd = ring.create(slots=4)
    try:
        writer, reader = ring.RingWriter(fd), ring.RingReader(fd, 4)
        writer.append(1, 1, 2)
        assert len(reader.new()) == 1
        with mmap.mmap(fd, ring.ring_size(4)) as raw:
            struct.pack_into("=Q", raw, 16, 0)  # a hostile node rewinds `written`
        assert reader.new() == []
        writer.written = 0
        writer.append(5, 1, 2)
        assert [entry.seq for entry in reader.new()] == [5]
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- the enforcer's socket


def test_the_socket_refuses_to_replace_a_file(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    path.write_text("keep me\n")
    with pytest.raises(SocketPathError, match="exists and is not a socket: refusing"):
        EnforcerSocket(path)
    assert path.read_text() == "keep me\n"


def test_the_socket_replaces_a_stale_socket_but_not_a_live_one(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as crashed:
        crashed.bind(str(path))
    with EnforcerSocket(path):
        with pytest.raises(SocketPathError, match="another catanc enforcer is running at"):
            EnforcerSocket(path)
        assert path.stat().st_mode & 0o777 == 0o666  # anyone's node may send; registering is checked
    assert not path.exists()


def test_the_socket_leaves_a_successors_socket_alone(tmp_path: Path) -> None:
    path = tmp_path / "catanc.sock"
    old = EnforcerSocket(path)
    path.unlink()
    with EnforcerSocket(path):
        old.close()
        assert path.exists()


def test_the_socket_says_who_sent_each_datagram(tmp_path: Path) -> None:
    with EnforcerSocket(tmp_path / "catanc.sock") as enforcer, socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as peer:
        peer.bind("")
        peer.sendto(SetCores(2).encode(), str(enforcer.path))
        peer.sendto(b"\xffgarbage", str(enforcer.path))
        got = list(enforcer.receive())
        assert [received.data for received in got] == [SetCores(2).encode(), b"\xffgarbage"]
        assert got[0].credentials == Credentials(os.getpid(), os.geteuid(), os.getegid())
        assert got[0].sender == peer.getsockname()
        assert list(enforcer.receive()) == []  # never blocks


def test_the_socket_reads_a_flood_a_bounded_batch_at_a_time(tmp_path: Path) -> None:
    with EnforcerSocket(tmp_path / "catanc.sock") as enforcer, socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as peer:
        peer.setblocking(False)
        sent = 0
        for _ in range(200):
            try:
                peer.sendto(b"x", str(enforcer.path))
                sent += 1
            except BlockingIOError:
                break
        assert len(list(enforcer.receive(limit=8))) == min(8, sent)


@pytest.mark.parametrize("mode", [0o777, 0o775])
def test_a_socket_folder_others_may_write_in_is_refused(tmp_path: Path, mode: int) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    folder.chmod(mode)
    with pytest.raises(SocketPathError, match="only its owner may create files"):
        check_private_folder(folder)
    folder.chmod(0o755)
    check_private_folder(folder)
    link = tmp_path / "link"
    link.symlink_to(folder)
    with pytest.raises(SocketPathError, match="not a folder"):
        check_private_folder(link)


# --------------------------------------------------------------------------- who may register


def test_root_and_the_enforcers_user_may_register_any_thread_of_a_process() -> None:
    tid = threading.get_native_id()
    mine = Credentials(os.getpid(), os.geteuid(), os.getegid())
    assert may_register(mine, os.getpid(), tid) is None
    assert may_register(Credentials(1, 0, 0), os.getpid(), tid, own_uid=12345) is None
    assert "is not a thread of process" in (may_register(mine, os.getpid(), 2**22 + 7) or "")
    assert may_register(None, os.getpid(), tid) == "the kernel gave no credentials for the datagram"


def test_another_user_may_register_only_threads_of_its_own_processes() -> None:
    stranger = Credentials(1, 54321, 54321)
    why = may_register(stranger, os.getpid(), threading.get_native_id(), own_uid=12345)
    assert why == f"process {os.getpid()} belongs to uid {os.geteuid()}, not to the sender's uid 54321"
    owner = Credentials(1, os.geteuid(), os.getegid())
    assert may_register(owner, os.getpid(), threading.get_native_id(), own_uid=12345) is None


def test_a_rate_limit_lets_a_burst_through_then_the_rate() -> None:
    limit = RateLimit(rate=10.0, burst=3.0)
    now = limit._at
    assert [limit.take(now) for _ in range(4)] == [True, True, True, False]
    assert limit.take(now + 0.05) is False  # half a token
    assert limit.take(now + 0.1) is True


def _hello(node: str, tid: int | None = None) -> Hello:
    return Hello(node, os.getpid(), tid or threading.get_native_id())


def test_the_registry_keeps_one_endpoint_per_node_and_thread() -> None:
    registry = Registry({"LM", "LP"})
    mine = Credentials(os.getpid(), os.geteuid(), os.getegid())
    assert registry.check(_hello("LM"), mine) == (None, True)
    assert registry.check(_hello("XX"), mine) == ("no node 'XX' in this app (its nodes: LM, LP)", True)
    first = Endpoint("LM", os.getpid(), threading.get_native_id(), b"\x00a")
    second = Endpoint("LM", os.getpid(), threading.get_native_id(), b"\x00b")
    assert registry.add(first) is None
    assert registry.add(second) is first  # the same node and thread again: replaced, not added
    assert registry.of("LM") == [second]
    assert registry.from_address(b"\x00b", "LM") is second
    assert registry.remove(second)
    assert not registry.remove(second)
    assert registry.of("LM") == []


def test_the_registry_limits_threads_per_node_and_registrations_per_peer() -> None:
    registry = Registry({"LM"})
    mine = Credentials(os.getpid(), os.geteuid(), os.getegid())
    tids = [int(task.name) for task in Path(f"/proc/{os.getpid()}/task").iterdir()]
    for i in range(16):
        registry.add(Endpoint("LM", os.getpid(), 10_000_000 + i, None))
    assert registry.check(_hello("LM", tids[0]), mine) == ("node 'LM' has 16 threads registered already", True)
    flood = Registry({"LP"})
    answers = [flood.check(_hello("LP"), mine) for _ in range(30)]
    assert answers[0] == (None, True)
    assert answers[-1] == ("too many registrations: slow down", False)  # over its rate: no answer at all


def test_an_endpoint_welcomes_its_node_with_a_ring_through_a_socket_of_its_own(tmp_path: Path) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as node:
        node.bind("")
        endpoint = open_endpoint("LM", os.getpid(), threading.get_native_id(), node.getsockname())
        try:
            data, ancillary, _, sender = node.recvmsg(MAX_DATAGRAM, socket.CMSG_SPACE(4))
            assert decode(data) == Welcome("LM", ring.SLOTS)
            ((level, kind, payload),) = ancillary
            assert (level, kind) == (socket.SOL_SOCKET, socket.SCM_RIGHTS)
            fd = array.array("i", payload)[0]
            writer = ring.RingWriter(fd)
            os.close(fd)
            writer.append(3, 10, 20, 5, 1)
            assert endpoint.reader is not None
            assert [entry.seq for entry in endpoint.reader.new()] == [3]
            assert endpoint.send(Trigger("LM", 4).encode())
            assert node.recvfrom(MAX_DATAGRAM) == (Trigger("LM", 4).encode(), sender)  # from the endpoint's socket
            writer.close()
        finally:
            endpoint.close()


def test_a_node_that_never_reads_fills_only_its_own_endpoint() -> None:
    """Its endpoint's sends fail (that node's problem); another node's endpoint still sends."""
    with (
        socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as deaf,
        socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as other,
    ):
        deaf.bind("")
        other.bind("")
        one = open_endpoint("A", os.getpid(), threading.get_native_id(), deaf.getsockname())
        two = open_endpoint("B", os.getpid(), threading.get_native_id(), other.getsockname())
        try:
            sent = sum(one.send(Trigger("A", seq).encode()) for seq in range(2000))
            assert sent < 2000
            assert one.failed
            assert two.send(Trigger("B", 1).encode())
            assert not two.failed
        finally:
            one.close()
            two.close()
