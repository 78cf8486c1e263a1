"""The node client and the synthetic worker, against the enforcer's side of the protocol.

:class:`FakeEnforcer` plays the enforcer in the test thread with the enforcer's own socket and
endpoints (:mod:`catanc.runtime.protocol.endpoints`): it welcomes nodes (each with its ring), sends
triggers and routes by hand, and reads what the nodes report from their rings.  Clients run in
threads, workers in processes.  Every wait has a generous timeout; nothing here measures speed.
"""

from __future__ import annotations

import ast
import contextlib
import itertools
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

import catanc.client as client_module
from catanc.client import ClientError, Node, Trigger
from catanc.model.load import load_spec
from catanc.model.workload import ComputeSampler
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol import ring
from catanc.runtime.protocol.messages import (
    MAX_NAME,
    SOCKET_ENV,
    Bye,
    Done,
    Hello,
    Reject,
    Route,
    Stop,
    trigger_datagram,
)
from catanc.runtime.worker.burn import burn_parallel
from catanc.runtime.worker.command import worker_command, worker_groups, workload_worker_command
from catanc.runtime.worker.draws import check_profile, format_modes, parse_modes
from catanc.runtime.worker.options import parse_args
from catanc.runtime.worker.records import RunRecord, read_records, write_records
from tests.support.fake_enforcer import TIMEOUT_S, FakeEnforcer
from tests.support.pythons import find_python

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


def burn_ms(compute_ms: float) -> float:
    """Use ``compute_ms`` of this thread's CPU time; return what was used, in ms."""
    start = time.thread_time()
    while time.thread_time() - start < compute_ms / 1000.0:
        pass
    return (time.thread_time() - start) * 1000.0


# -- the client against a scripted enforcer ----------------------------------------------------


def test_register_welcome_and_stop_ends_the_loop(enforcer: FakeEnforcer) -> None:
    def client() -> tuple[bool, int | None, int, list[Trigger], bool]:
        with Node("LM", socket_path=enforcer.path) as node:
            registered = node.registered
            triggers = list(node)
            return registered, node.tid, threading.get_native_id(), triggers, node.stopped

    background = Background(client)
    hello = enforcer.welcome({"LM"})["LM"]
    assert (hello.node, hello.pid) == ("LM", os.getpid())
    assert enforcer.address("LM").startswith(b"\0")  # an autobound abstract address
    enforcer.send("LM", Stop())
    registered, tid, native_id, triggers, stopped = background.join()
    assert registered
    assert hello.tid == tid == native_id
    assert triggers == []
    assert stopped
    assert enforcer.receive(0) is None  # stopped by the enforcer: no bye


def test_a_run_is_reported_in_the_ring_with_its_seq_times_and_cpu(enforcer: FakeEnforcer) -> None:
    def client() -> dict[int, tuple[float, int, int]]:
        burned: dict[int, tuple[float, int, int]] = {}
        with Node("LM", socket_path=enforcer.path) as node:
            for trigger in node:
                assert node.trigger == trigger
                began = time.monotonic_ns()
                used = burn_ms(30.0)
                node.done()
                burned[trigger.seq] = (used, began, time.monotonic_ns())
                assert node.trigger is None
        return burned

    background = Background(client)
    enforcer.welcome({"LM"})
    entries = []
    for seq in (7, 8):
        enforcer.trigger("LM", seq, threads=2)
        entries += enforcer.runs("LM")
    enforcer.send("LM", Stop())
    burned = background.join()
    assert [entry.seq for entry in entries] == [7, 8]
    for entry in entries:
        used, began, ended = burned[entry.seq]
        assert entry.start_ns <= began <= ended
        assert began <= entry.end_ns <= ended
        assert entry.compute_ms is not None
        assert used <= entry.compute_ms <= 1.5 * used  # the thread's CPU time since the trigger arrived
        assert entry.threads == 2
    assert enforcer.receive(0) is None  # no datagram per run: the ring is the report


def test_done_takes_the_nodes_own_measurement_and_wait_completes_a_pending_run(enforcer: FakeEnforcer) -> None:
    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            for trigger in node:
                if trigger.seq == 1:
                    node.done(compute_ms=2.5)
                elif trigger.seq == 2:
                    node.done(compute_ms=float("nan"))  # not a time: reported as unknown
                # seq 3: no done(); the next step of the loop reports it

    background = Background(client)
    enforcer.welcome({"LM"})
    for seq in (1, 2, 3):
        enforcer.trigger("LM", seq)
    one, two, three = enforcer.runs("LM", 3)
    assert (one.seq, one.compute_ms) == (1, 2.5)
    assert (two.seq, two.compute_ms) == (2, None)
    assert three.seq == 3
    assert three.compute_ms is not None
    enforcer.send("LM", Stop())
    background.join()


def two_nodes(enforcer: FakeEnforcer, work_ms: float = 1.0) -> tuple[Background, Background, dict[str, Hello]]:
    """Nodes A then B of one subchain, each in a thread; each returns the triggers it ran."""

    def serve(name: str) -> Callable[[], list[Trigger]]:
        def loop() -> list[Trigger]:
            ran = []
            with Node(name, socket_path=enforcer.path) as node:
                for trigger in node:
                    burn_ms(work_ms)
                    ran.append(trigger)
                    node.done()
            return ran

        return loop

    a, b = Background(serve("A")), Background(serve("B"))
    hellos = enforcer.welcome({"A", "B"})
    enforcer.send("A", Route("A", False, "B", 2, enforcer.address("B"), None))
    enforcer.send("B", Route("B", False, None, 1, None, enforcer.address("A")))
    return a, b, hellos


def test_a_finished_run_wakes_the_next_node_with_its_seq(enforcer: FakeEnforcer) -> None:
    a, b, _ = two_nodes(enforcer)
    for seq in (4, 5):
        enforcer.trigger("A", seq)
    runs_a, runs_b = enforcer.runs("A", 2), enforcer.runs("B", 2)
    assert [entry.seq for entry in runs_b] == [4, 5]
    for before, after in zip(runs_a, runs_b, strict=True):
        assert after.start_ns >= before.end_ns  # B started when A was done
        assert after.threads == 2  # on the threads the route said B's runs get
    enforcer.send("A", Stop())
    enforcer.send("B", Stop())
    assert [trigger.seq for trigger in a.join()] == [4, 5]
    assert b.join() == [Trigger("B", 4, 2), Trigger("B", 5, 2)]
    assert enforcer.receive(0) is None  # no hop went through the enforcer


def test_routes_that_came_during_a_run_are_taken_before_its_hop(enforcer: FakeEnforcer) -> None:
    # Two routes reach A after its trigger (behind it in A's queue, so while it runs): the hop at its end
    # follows the last of them (B on 3 threads), not the route before the run (2) nor the first new one (5).
    a, b, _ = two_nodes(enforcer, work_ms=100.0)
    enforcer.trigger("A", 1)
    for threads in (5, 3):
        enforcer.send("A", Route("A", False, "B", threads, enforcer.address("B"), None))
    assert [(entry.seq, entry.threads) for entry in enforcer.runs("B")] == [(1, 3)]
    for node in ("A", "B"):
        enforcer.send(node, Stop())
    a.join()
    assert b.join() == [Trigger("B", 1, 3)]


def test_a_trigger_from_anyone_else_is_ignored(enforcer: FakeEnforcer) -> None:
    a, b, _ = two_nodes(enforcer)
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as stranger:
        stranger.bind("")
        stranger.sendto(trigger_datagram("B", 99), enforcer.address("B"))
        stranger.sendto(trigger_datagram("A", 98), enforcer.address("A"))
    enforcer.trigger("A", 1)
    assert [entry.seq for entry in enforcer.runs("B")] == [1]
    for node in ("A", "B"):
        enforcer.send(node, Stop())
    assert [trigger.seq for trigger in a.join()] == [1]
    assert [trigger.seq for trigger in b.join()] == [1]


def test_descriptors_sent_to_a_registered_node_are_not_kept(enforcer: FakeEnforcer, tmp_path: Path) -> None:
    """A peer that sends open files to a node cannot make it leak descriptors: none stays open in the node."""
    a, b, _ = two_nodes(enforcer)
    planted = tmp_path / "planted"
    planted.write_text("")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as stranger, planted.open() as sent:
        stranger.bind("")
        # 6 queued at most, with the enforcer's route 7: A's trigger to B must still fit if B took none of them
        # yet (net.unix.max_dgram_qlen is 10; with 9 A's trigger was dropped once in a run of the file).
        for _ in range(2):
            for message in (trigger_datagram("B", 97), b"catanc/2 route B 0 - 1 - -", b"junk"):
                stranger.sendmsg(
                    [message],
                    [(socket.SOL_SOCKET, socket.SCM_RIGHTS, struct.pack("i", sent.fileno()))],
                    0,
                    enforcer.address("B"),
                )
    enforcer.trigger("A", 1)
    assert [entry.seq for entry in enforcer.runs("B")] == [1]  # B took every datagram sent before A's trigger
    kept = []
    for fd in Path("/proc/self/fd").iterdir():
        with contextlib.suppress(OSError):  # the listing's own descriptor is gone by now
            if fd.readlink() == planted:
                kept.append(fd.name)
    assert not kept, f"descriptors of the planted file left open in the nodes' process: {kept}"
    for node in ("A", "B"):
        enforcer.send(node, Stop())
    assert [trigger.seq for trigger in b.join()] == [1]
    a.join()


def test_a_route_that_asks_for_it_gets_a_done_per_run(enforcer: FakeEnforcer) -> None:
    def client() -> None:
        with Node("LM", socket_path=enforcer.path) as node:
            for _trigger in node:
                node.done()

    background = Background(client)
    hello = enforcer.welcome({"LM"})["LM"]
    enforcer.send("LM", Route("LM", notify=True))
    enforcer.trigger("LM", 9)
    done, received = enforcer.expect(Done)
    assert done == Done("LM", hello.tid, 9)
    assert received.sender == enforcer.address("LM")
    assert [entry.seq for entry in enforcer.runs("LM")] == [9]
    enforcer.send("LM", Stop())
    background.join()


def test_a_run_nothing_triggered_is_reported_with_seq_0(enforcer: FakeEnforcer) -> None:
    """A subscription callback: the thread registers, then reports each run it makes, waiting for nothing."""
    ready = threading.Event()
    release = threading.Event()

    def client() -> None:
        node = Node("LP", socket_path=enforcer.path)
        node.register()
        try:
            with node.run():
                burn_ms(2.0)
            start = node.begin()
            assert start <= time.monotonic_ns()
            node.done(compute_ms=1.25)
            ready.set()
            assert release.wait(TIMEOUT_S)
        finally:
            node.close()

    background = Background(client)
    enforcer.welcome({"LP"})
    first, second = enforcer.runs("LP", 2)
    assert (first.seq, second.seq) == (0, 0)
    assert first.compute_ms is not None
    assert first.compute_ms >= 2.0
    assert second.compute_ms == 1.25
    assert ready.wait(TIMEOUT_S)
    release.set()
    background.join()
    assert enforcer.expect(Bye)[0].node == "LP"


def test_wait_times_out_with_none(enforcer: FakeEnforcer) -> None:
    def client() -> tuple[Trigger | None, bool]:
        with Node("LM", socket_path=enforcer.path) as node:
            return node.wait(timeout_s=0.01), node.stopped

    background = Background(client)
    enforcer.welcome({"LM"})
    assert background.join() == (None, False)
    bye, _ = enforcer.expect(Bye)  # left on its own: says bye
    assert bye.node == "LM"


def test_interrupt_ends_the_loop_from_another_thread_and_says_bye(enforcer: FakeEnforcer) -> None:
    node = Node("LM", socket_path=enforcer.path)

    def client() -> list[Trigger]:
        with node:
            return list(node)

    background = Background(client)
    hello = enforcer.welcome({"LM"})["LM"]
    node.interrupt()
    assert background.join() == []
    assert node.stopped
    bye, _ = enforcer.expect(Bye)
    assert bye == Bye("LM", hello.tid)
    node.interrupt()  # after close: harmless


def test_interrupt_wakes_a_wait_blocked_in_the_receive_at_once(
    enforcer: FakeEnforcer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # A registered node waits in the socket's receive, not in a poll that sees the interrupt pipe:
    # interrupt() wakes it with a datagram to its own address, not the next look for the enforcer
    # (PROBE_S, longer than the join's timeout here).
    monkeypatch.setattr(Node, "PROBE_S", 4 * TIMEOUT_S)
    node = Node("LM", socket_path=enforcer.path)

    def client() -> list[Trigger]:
        with node:
            return list(node)

    background = Background(client)
    enforcer.welcome({"LM"})
    enforcer.trigger("LM", 1)
    assert [entry.seq for entry in enforcer.runs("LM")] == [1]
    time.sleep(0.2)  # back in wait(), blocked
    node.interrupt()
    assert background.join() == [Trigger("LM", 1, 1)]
    assert "dropped a datagram" not in caplog.text  # its own wake-up is not a stranger's datagram


def test_a_default_socket_timeout_does_not_end_a_wait(enforcer: FakeEnforcer) -> None:
    # An app that set socket.setdefaulttimeout() still gets blocking waits: the receive does not time out.
    before = socket.getdefaulttimeout()
    socket.setdefaulttimeout(0.05)
    try:
        background = Background(lambda: _first_trigger_and_lost(enforcer.path))
        enforcer.welcome({"LM"})
        time.sleep(0.3)
        enforcer.trigger("LM", 1)
        assert background.join() == (Trigger("LM", 1, 1), None)
    finally:
        socket.setdefaulttimeout(before)


def _first_trigger_and_lost(path: Path) -> tuple[Trigger | None, str | None]:
    with Node("LM", socket_path=path) as node:
        return node.wait(), node.lost


def test_interrupt_before_registering_skips_the_loop(enforcer: FakeEnforcer) -> None:
    node = Node("LM", socket_path=enforcer.path)
    node.interrupt()
    with node:
        assert not node.registered
        assert node.stopped
        assert list(node) == []
    hello, _ = enforcer.expect(Hello)
    assert hello.node == "LM"
    bye, _ = enforcer.expect(Bye)  # the enforcer may have welcomed it meanwhile: a hello is always followed by a bye
    assert bye == Bye("LM", hello.tid)


def test_wait_and_done_belong_to_the_registered_thread(enforcer: FakeEnforcer) -> None:
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
    enforcer.welcome({"LM"})
    assert registered.wait(TIMEOUT_S)
    with pytest.raises(ClientError, match="call wait\\(\\) from that thread"):
        node.wait(0)
    release.set()
    enforcer.send("LM", Stop())
    background.join()
    with pytest.raises(ClientError, match="already registered"):
        node.register()


def test_reject_is_a_client_error_with_the_reason(enforcer: FakeEnforcer) -> None:
    def client() -> None:
        with Node("XX", socket_path=enforcer.path):
            pytest.fail("registered although rejected")

    background = Background(client)
    hello, received = enforcer.expect(Hello)
    assert enforcer.sock.reply(Reject(hello.node, "no node 'XX' in this app").encode(), received.sender)
    with pytest.raises(ClientError, match="rejected node 'XX': no node 'XX' in this app"):
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


def test_an_enforcer_that_never_answers(enforcer: FakeEnforcer) -> None:
    with pytest.raises(ClientError, match=r"no answer in 0\.05 s\): is `catanc run` running\?"):
        Node("LM", socket_path=enforcer.path, timeout_s=0.05).register()
    hello, _ = enforcer.expect(Hello)
    assert hello.node == "LM"


def test_the_socket_comes_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SOCKET_ENV, str(tmp_path / "env.sock"))
    assert Node("LM").socket_path == str(tmp_path / "env.sock")
    monkeypatch.delenv(SOCKET_ENV)
    with pytest.raises(ClientError, match="CATANC_SOCKET is not set"):
        Node("LM")


@pytest.mark.parametrize("name", ["", "a\nb", "a b", "9lives", "x" * (MAX_NAME + 1)])
def test_bad_node_names(tmp_path: Path, name: str) -> None:
    with pytest.raises(ClientError, match="bad node name"):
        Node(name, socket_path=tmp_path / "catanc.sock")


def test_a_vanished_enforcer_ends_the_loop_and_says_why(
    enforcer: FakeEnforcer, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(Node, "PROBE_S", 0.02)
    registered = threading.Event()

    def client() -> tuple[list[Trigger], str | None]:
        with Node("LM", socket_path=enforcer.path) as node:
            registered.set()
            return list(node), node.lost

    background = Background(client)
    enforcer.welcome({"LM"})
    assert registered.wait(TIMEOUT_S)
    enforcer.close()  # no stop: a crash, as the node sees it
    triggers, lost = background.join()
    assert triggers == []
    assert lost is not None
    assert "went away without stopping node 'LM'" in lost
    assert capsys.readouterr().err == f"catanc: {lost}\n"  # one warning


# -- without an enforcer: the node's own timer -------------------------------------------------


def test_without_a_socket_a_fallback_period_runs_the_loop_on_a_timer(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv(SOCKET_ENV, raising=False)
    starts = []
    with Node("LM", fallback_period_ms=20.0) as node:
        for trigger in node:
            starts.append(time.monotonic())
            assert trigger == Trigger("LM", len(starts), 1)
            burn_ms(2.0)
            node.done()
            if len(starts) == 11:
                node.interrupt()
    assert node.fallback_period_ms == 20.0
    assert not node.registered
    # Ten periods between the first trigger and the last: 200 ms, not more (the timer keeps its phase).
    assert starts[-1] - starts[0] == pytest.approx(0.2, abs=0.03)
    assert capsys.readouterr().err == (
        "catanc: CATANC_SOCKET is not set: node 'LM' runs on its own timer every 20 ms (no enforcer)\n"
    )


def test_the_fallback_timer_skips_the_ticks_a_long_run_overran(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(SOCKET_ENV, raising=False)
    # At a 100 ms period a busy machine's late wake-ups (tens of ms) stay apart from both wrong answers:
    # a tick at once (0 ms) and a timer restarted at the late run's end (100 ms).  (At 10 ms, a 5 ms
    # bound of 4 ms failed under load.)
    with Node("LM", fallback_period_ms=100.0) as node:
        first = node.wait()
        time.sleep(0.55)  # five ticks and a half
        second = node.wait()
        began = time.monotonic()
        third = node.wait()
        waited = time.monotonic() - began
    assert (first, second, third) == (Trigger("LM", 1), Trigger("LM", 2), Trigger("LM", 3))
    assert waited == pytest.approx(0.05, abs=0.04)  # the next tick on the timer's phase, not 100 ms later


def test_the_fallback_timer_waits_with_a_timeout_and_stops_on_interrupt(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(SOCKET_ENV, raising=False)
    node = Node("LM", fallback_period_ms=1000.0)
    with node:
        assert node.wait() == Trigger("LM", 1)
        assert node.wait(timeout_s=0.01) is None  # the next tick is a second away
        Background(node.interrupt).join()
        assert node.wait() is None
        assert node.stopped


@pytest.mark.parametrize("period", [0.0, -5.0, float("nan"), float("inf"), True, "20"])
def test_a_fallback_period_is_a_positive_number_of_ms(period: Any) -> None:
    with pytest.raises(ClientError, match="fallback_period_ms is a number of ms > 0"):
        Node("LM", fallback_period_ms=period)


def test_a_socket_wins_over_the_fallback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SOCKET_ENV, str(tmp_path / "missing.sock"))
    node = Node("LM", fallback_period_ms=20.0)
    assert node.fallback_period_ms is None
    with pytest.raises(ClientError, match="no catanc enforcer at"):
        node.register()


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


@pytest.mark.parametrize(
    "ros",
    [
        ["--ros-args", "--params-file", "/x/params.yaml"],
        ["--ros-args", "-p", "rate:=3", "--", "--node", "B"],
        ["--ros-args", "--ros-args", "-r", "__node:=b", "--"],
    ],
)
def test_worker_options_skip_ros_sections_as_rcl_does(ros: list[str]) -> None:
    """A launcher appends ``--ros-args --params-file ...`` to a ROS process's command: a worker standing for one
    ignores each ROS section and reads what follows its ``--``."""
    options = parse_args(["--node", "A", "--compute-ms", "2", *ros])
    after = ros[ros.index("--") + 1 :] if "--" in ros else []
    assert set(options.nodes) == {"A", *after[1:2]}


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


def run_once(enforcer: FakeEnforcer, node: str, seq: int) -> float:
    enforcer.trigger(node, seq)
    entries = enforcer.runs(node)
    assert [entry.seq for entry in entries] == [seq], entries  # one run per trigger (what came, if not)
    (entry,) = entries
    assert entry.compute_ms is not None
    return entry.compute_ms


def test_worker_runs_its_nodes_in_threads_and_exits_on_stop(enforcer: FakeEnforcer, spawn: Spawn) -> None:
    process = spawn(worker_command({"A": 20.0, "B": [(1.0, 5.0)]}, socket_path=enforcer.path))
    hellos = enforcer.welcome({"A", "B"})
    assert hellos["A"].pid == hellos["B"].pid == process.pid
    assert hellos["A"].tid != hellos["B"].tid
    for seq in (1, 2):
        assert 20.0 <= run_once(enforcer, "A", seq) <= 30.0
        assert 5.0 <= run_once(enforcer, "B", seq) <= 7.5
    for node in hellos:
        enforcer.send(node, Stop())
    assert finish(process) == (0, "")
    assert enforcer.receive(0) is None  # stopped: no bye


@pytest.mark.parametrize("shared", [False, True])
def test_worker_runs_an_executors_nodes_one_after_the_other(
    enforcer: FakeEnforcer, spawn: Spawn, tmp_path: Path, shared: bool
) -> None:
    # A and B (40 ms each) triggered together, three times. Apart, their threads run at once (the
    # interpreter lock interleaves them): every pair of runs overlaps. In one executor, never.
    record = tmp_path / "runs"
    executors = [("A", "B")] if shared else []
    process = spawn([*worker_command({"A": 40.0, "B": 40.0}, socket_path=enforcer.path, executors=executors),
                     "--record", str(record)])  # fmt: skip
    enforcer.welcome({"A", "B"})
    for seq in (1, 2, 3):
        enforcer.trigger("A", seq)
        enforcer.trigger("B", seq)
        assert [entry.seq for entry in enforcer.runs("A")] == [seq]
        assert [entry.seq for entry in enforcer.runs("B")] == [seq]
    for node in ("A", "B"):
        enforcer.send(node, Stop())
    assert finish(process) == (0, "")
    runs = read_records(record)
    a = [run for run in runs if run.node == "A"]
    b = [run for run in runs if run.node == "B"]
    assert len(a) == len(b) == 3
    overlapping = sum(1 for x in a for y in b if x.start_ns < y.end_ns and y.start_ns < x.end_ns)
    assert overlapping == (0 if shared else 3)


def test_worker_draws_modes_from_its_seed(enforcer: FakeEnforcer, spawn: Spawn) -> None:
    def modes_drawn() -> list[bool]:
        process = spawn(worker_command({"M": [(0.5, 2.0), (0.5, 40.0)]}, seed=1, socket_path=enforcer.path))
        enforcer.welcome({"M"})
        drawn = []
        for seq in range(16):
            compute = run_once(enforcer, "M", seq)
            assert 2.0 <= compute <= 3.0 or 40.0 <= compute <= 60.0
            drawn.append(compute > 20.0)
        enforcer.send("M", Stop())
        assert finish(process) == (0, "")
        enforcer.endpoints.pop("M").close()
        return drawn

    first = modes_drawn()
    assert any(first)
    assert not all(first)
    assert modes_drawn() == first


def test_worker_scales_compute_after_the_given_time(enforcer: FakeEnforcer, spawn: Spawn) -> None:
    process = spawn(worker_command({"A": 10.0}, scale_after=(2.0, 3.0), socket_path=enforcer.path))
    enforcer.welcome({"A"})
    computes = [run_once(enforcer, "A", 0)]
    deadline = time.monotonic() + TIMEOUT_S
    while computes[-1] < 20.0 and time.monotonic() < deadline:
        computes.append(run_once(enforcer, "A", len(computes)))
    computes += [run_once(enforcer, "A", len(computes) + i) for i in range(3)]
    enforcer.send("A", Stop())
    assert finish(process) == (0, "")
    before, after = computes[0], computes[-4:]
    assert 10.0 <= before <= 15.0
    assert all(30.0 <= compute <= 45.0 for compute in after)
    assert all(2.0 <= compute / before <= 4.5 for compute in after)  # ~3x
    switch = next(i for i, compute in enumerate(computes) if compute >= 20.0)
    assert all(compute < 15.0 for compute in computes[:switch])
    assert all(compute >= 30.0 for compute in computes[switch:])  # and it stays slow


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_worker_exits_cleanly_on_signals(enforcer: FakeEnforcer, spawn: Spawn, signum: signal.Signals) -> None:
    process = spawn(worker_command({"A": 1.0, "B": 1.0}, socket_path=enforcer.path))
    hellos = enforcer.welcome({"A", "B"})
    run_once(enforcer, "A", 1)
    process.send_signal(signum)
    assert finish(process) == (0, "")
    byes = {enforcer.expect(Bye)[0], enforcer.expect(Bye)[0]}
    assert byes == {Bye("A", hellos["A"].tid), Bye("B", hellos["B"].tid)}


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
    records = [RunRecord("LM", 10, 20, 9, 100, 112), RunRecord("a node", 30, 45, 15)]
    write_records(tmp_path / "runs", records)
    assert read_records(tmp_path / "runs") == records
    assert [p.name for p in tmp_path.iterdir()] == ["runs"]  # no temporary file left
    (tmp_path / "old").write_text('{"node":"LM","start_ns":10,"end_ns":20,"cpu_ns":9}\n')  # before the thread clocks
    assert read_records(tmp_path / "old") == [RunRecord("LM", 10, 20, 9, 0, 0)]
    (tmp_path / "bad").write_text('{"node": "LM", "start_ns": 1}\n')
    with pytest.raises(ValueError, match="bad:1: not a run record"):
        read_records(tmp_path / "bad")


def test_worker_draws_from_the_specs_workload_and_records_every_run(
    enforcer: FakeEnforcer, spawn: Spawn, tmp_path: Path
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
    enforcer.welcome({"M", "G"})
    measured = [run_once(enforcer, "M", seq) for seq in range(12)]
    grown = [run_once(enforcer, "G", seq) for seq in range(3)]
    for node in ("M", "G"):
        enforcer.send(node, Stop())
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
    for node in ("M", "G"):  # the thread's clock: the run's CPU lies between its start and its done, in order
        mine = sorted(r for r in runs if r.node == node)
        for run in mine:
            assert run.thread_cpu_start_ns > 0
            assert run.thread_cpu_start_ns + run.cpu_ns <= run.thread_cpu_done_ns
        for earlier, later in itertools.pairwise(mine):
            assert earlier.thread_cpu_done_ns <= later.thread_cpu_start_ns
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


# -- the standalone file: any Python from 3.8, nothing else installed --------------------------

CLIENT_FILE = Path(client_module.__file__)
PYTHON_38 = find_python((3, 8))
NO_PYTHON_38 = "no Python 3.8 interpreter on this machine (PATH, pyenv)"


def test_the_clients_constants_are_the_protocols_and_the_rings() -> None:
    assert client_module.PROTOCOL == protocol.PROTOCOL
    assert client_module.SOCKET_ENV == protocol.SOCKET_ENV
    assert client_module.MAX_DATAGRAM == protocol.MAX_DATAGRAM
    assert client_module._RING_MAGIC == ring.MAGIC
    assert client_module._RING_VERSION == ring.LAYOUT_VERSION
    assert client_module._HEADER_SIZE == ring.HEADER_SIZE
    assert client_module._ENTRY_SIZE == ring.ENTRY_SIZE == client_module._ENTRY.size
    assert client_module._HEADER.format == ring.HEADER.format
    assert client_module._ENTRY.format.startswith(ring.ENTRY.format)  # then the reserved word, zero
    assert client_module._UNKNOWN == ring.UNKNOWN
    assert client_module._trigger_prefix("LM") + b"7 2" == trigger_datagram("LM", 7, 2)


def test_the_client_parses_as_python_3_8() -> None:
    ast.parse(CLIENT_FILE.read_text(), filename=str(CLIENT_FILE), feature_version=(3, 8))


def standalone_imports(python: str, tmp_path: Path) -> set[str]:
    """The modules that importing a copy of the client loads, isolated (-I: no environment, no user
    site; -S: no site-packages) from a folder that holds nothing else."""
    shutil.copy(CLIENT_FILE, tmp_path / "catanc_client.py")
    code = (
        "import sys; sys.path.insert(0, '.'); before = set(sys.modules)\n"
        "import catanc_client\n"
        "print(' '.join(sorted(set(sys.modules) - before)))"
    )
    done = subprocess.run(
        [python, "-I", "-S", "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT_S, check=False
    )
    assert done.returncode == 0, done.stderr
    return set(done.stdout.split())


@pytest.mark.parametrize(
    "python",
    [
        pytest.param(sys.executable, id="this-python"),
        pytest.param(str(PYTHON_38), id="python3.8", marks=pytest.mark.skipif(PYTHON_38 is None, reason=NO_PYTHON_38)),
    ],
)
def test_a_copy_of_the_client_imports_the_standard_library_only(python: str, tmp_path: Path) -> None:
    loaded = standalone_imports(python, tmp_path)
    assert "catanc_client" in loaded
    stdlib = set(sys.stdlib_module_names)
    foreign = sorted(name for name in loaded if name.split(".")[0] not in stdlib | {"catanc_client"})
    assert not foreign, f"the client imports {foreign}"
