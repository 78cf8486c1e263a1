"""The Python client's executor hooks and run origins: ``fd()``, ``alive()``, ``on_input`` and ``done(origin_ns=...)``.

Against :class:`~tests.support.fake_enforcer.FakeEnforcer`, which reads the ring as the enforcer
does: an origin is checked against the clocks read by the test itself, not against the client.
"""

from __future__ import annotations

import select
import socket
import threading
import time

import pytest

from catanc.client import ClientError, Node
from catanc.runtime.protocol.messages import Route, Stop
from tests.support.fake_enforcer import TIMEOUT_S, FakeEnforcer
from tests.test_client import Background


def _realtime_minus_monotonic_ns() -> int:
    return time.time_ns() - time.monotonic_ns()


def test_an_origin_is_written_into_the_ring_on_the_monotonic_clock(enforcer: FakeEnforcer) -> None:
    sensed = time.time_ns() - 7_000_000  # 7 ms ago, on the clock of a ROS header.stamp
    offsets = []

    def client() -> None:
        with Node("LP", socket_path=enforcer.path, on_input=True) as node:
            offsets.append(_realtime_minus_monotonic_ns())
            node.begin()
            node.done(origin_ns=sensed)  # given to done()
            with node.run(origin_ns=sensed + 1_000_000):  # given to begin()
                pass
            with node.run():  # none
                pass
            offsets.append(_realtime_minus_monotonic_ns())

    background = Background(client)
    enforcer.welcome({"LP"})
    first, second, third = enforcer.runs("LP", 3)
    background.join()
    low, high = min(offsets), max(offsets)  # the two clocks drift apart by far less than 1 ms meanwhile
    assert sensed - high - 1_000_000 <= first.origin_ns <= sensed - low + 1_000_000
    assert first.end_ns - first.origin_ns >= 6_000_000  # 7 ms before its end, within the clocks' drift
    assert second.origin_ns - first.origin_ns == pytest.approx(1_000_000, abs=1_000_000)
    assert third.origin_ns == 0  # no origin: the enforcer takes none (or a head's start)


def test_a_hello_says_the_node_runs_on_its_input(enforcer: FakeEnforcer) -> None:
    def client() -> None:
        with Node("LP", socket_path=enforcer.path, on_input=True):
            pass

    background = Background(client)
    assert enforcer.welcome({"LP"})["LP"].on_input
    background.join()


def test_an_input_node_without_an_enforcer_just_runs_without_a_warning(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("CATANC_SOCKET", raising=False)
    node = Node("LP", on_input=True)
    node.register()
    with node.run(origin_ns=time.time_ns()):
        pass
    node.begin()
    node.done()
    assert node.fd() is None
    assert not node.alive()
    node.close()
    assert capfd.readouterr().err == ""  # not the "runs on its own timer" warning: it runs on its input
    with pytest.raises(ClientError, match="runs on its input has no fallback timer"):
        Node("LP", on_input=True, fallback_period_ms=10.0)


def test_fd_is_readable_when_a_trigger_waits_and_wait_0_takes_it(enforcer: FakeEnforcer) -> None:
    taken: list[int] = []

    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            fd = node.fd()
            assert fd is not None
            while len(taken) < 2:
                assert select.select([fd], [], [], TIMEOUT_S)[0], "fd never became readable"
                trigger = node.wait(0)  # takes what arrived, never blocks
                if trigger is not None:
                    taken.append(trigger.seq)
                    node.done()
            assert select.select([fd], [], [], TIMEOUT_S)[0]
            assert node.wait(0) is None  # a stop: nothing to run, the node is stopped
            assert node.stopped

    background = Background(client)
    enforcer.welcome({"LM"})
    for seq in (3, 4):
        enforcer.trigger("LM", seq)
        enforcer.runs("LM")
    enforcer.send("LM", Stop())
    background.join()
    assert taken == [3, 4]


def test_fd_is_none_on_the_fallback_timer(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CATANC_SOCKET", raising=False)
    with Node("LM", fallback_period_ms=5.0) as node:
        assert node.fd() is None
        assert not node.alive()


def test_alive_until_the_enforcer_goes_away(enforcer: FakeEnforcer) -> None:
    checked = threading.Event()
    gone = threading.Event()
    answers: list[object] = []

    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            answers.append(node.alive())
            checked.set()
            assert gone.wait(TIMEOUT_S)
            answers.append(node.alive())
            answers.append(node.lost)

    background = Background(client)
    enforcer.welcome({"LM"})
    assert checked.wait(TIMEOUT_S)
    enforcer.sock.close()  # a killed enforcer: its socket takes no datagrams (here: gone)
    gone.set()
    background.join()
    assert answers[:2] == [True, False]
    assert isinstance(answers[2], str)
    assert "went away" in answers[2]


def test_no_trigger_goes_to_a_next_node_that_runs_on_its_input(enforcer: FakeEnforcer) -> None:
    """The route names B without an address (B said ``input``): A's runs send B nothing."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as next_node:
        next_node.bind("")

        def head() -> None:
            with Node("A", socket_path=enforcer.path) as node:
                for _ in node:
                    node.done()

        background = Background(head)
        enforcer.welcome({"A"})
        enforcer.send("A", Route("A", False, "B", 1, None, None))
        enforcer.trigger("A", 1)
        enforcer.runs("A")
        # The same again with B's address: this datagram proves the receive below would see one.
        enforcer.send("A", Route("A", False, "B", 1, next_node.getsockname(), None))
        enforcer.trigger("A", 2)
        enforcer.runs("A")
        enforcer.send("A", Stop())
        background.join()
        next_node.settimeout(TIMEOUT_S)
        assert next_node.recv(512) == b"catanc/2 trigger B 2 1"  # the first datagram B got is run 2's
