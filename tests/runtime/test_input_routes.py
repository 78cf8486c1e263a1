"""Routes to a node that runs on its input: its predecessor is told its name, never its address.

A node whose hello said ``input`` (a ROS subscription callback) is woken by its message; a trigger
from its predecessor would start a run on the previous message's data.  Checked on the enforcer's
own :class:`~catanc.runtime.enforcer.nodes.NodeThreads` with real sockets, and across the wire: what the
route says is what a client reads.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator

import pytest

from catanc.control.schedule import RuntimeSchedule, SubchainRun
from catanc.runtime.enforcer.nodes import NodeThreads
from catanc.runtime.linux.levels import Levels
from catanc.runtime.linux.sched import Restorer
from catanc.runtime.protocol.endpoints import Endpoint, Registry
from catanc.runtime.protocol.messages import Route, decode

CHAIN = SubchainRun("front", ("cam", "det", "ctl"), (0,), False, 20.0, 10.0, None, 1)


@pytest.fixture
def sockets() -> Iterator[list[socket.socket]]:
    made: list[socket.socket] = []
    yield made
    for sock in made:
        sock.close()


def _endpoint(node: str, tid: int, sockets: list[socket.socket], *, on_input: bool = False) -> Endpoint:
    """A registered thread of ``node`` whose enforcer-side socket reaches a node socket the test reads."""
    node_sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    node_sock.bind("")
    enforcer_side = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_NONBLOCK)
    enforcer_side.bind("")
    enforcer_side.connect(node_sock.getsockname())
    sockets += [node_sock, enforcer_side]
    return Endpoint(node, os.getpid(), tid, node_sock.getsockname(), enforcer_side, on_input=on_input)


def _ignore(*_args: object, **_fields: object) -> None:
    pass


def _routes(det_on_input: bool, sockets: list[socket.socket]) -> dict[str, Route]:
    registry = Registry(set(CHAIN.nodes))
    threads = NodeThreads(
        registry,
        Levels(rt=False),
        Restorer(),
        RuntimeSchedule(1, {"front": CHAIN}, ()),
        rt=False,
        cpus_of=frozenset,
        note=_ignore,
        log=_ignore,
    )
    endpoints = {
        "cam": _endpoint("cam", 101, sockets),
        "det": _endpoint("det", 102, sockets, on_input=det_on_input),
        "ctl": _endpoint("ctl", 103, sockets, on_input=True),
    }
    for endpoint in endpoints.values():
        registry.add(endpoint)
    threads.routes()
    received = {}
    for index, node in enumerate(("cam", "det", "ctl")):
        node_sock = sockets[2 * index]
        node_sock.settimeout(5.0)
        message = decode(node_sock.recv(512))  # what the client reads
        assert isinstance(message, Route)
        received[node] = message
    return received


def test_a_triggered_next_node_gets_its_address_an_input_node_only_its_name(sockets: list[socket.socket]) -> None:
    routes = _routes(det_on_input=False, sockets=sockets)
    assert routes["cam"].next_node == "det"
    assert routes["cam"].next_address == sockets[2].getsockname()  # det's socket: cam triggers it
    assert routes["det"].next_node == "ctl"
    assert routes["det"].next_address is None  # ctl runs on its input: det sends it nothing


def test_an_input_node_is_never_sent_a_trigger_by_its_predecessor(sockets: list[socket.socket]) -> None:
    routes = _routes(det_on_input=True, sockets=sockets)
    assert (routes["cam"].next_node, routes["cam"].next_address) == ("det", None)
    assert routes["det"].prev_address == sockets[0].getsockname()  # who it would accept one from, still said
