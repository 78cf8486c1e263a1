"""The enforcer's side of the protocol, driven by a test: :class:`FakeEnforcer`."""

from __future__ import annotations

import select
import time
from pathlib import Path
from typing import TypeVar

from catanc.runtime.protocol import ring
from catanc.runtime.protocol.endpoints import Endpoint, EnforcerSocket, Received, open_endpoint
from catanc.runtime.protocol.messages import Hello, Message, decode, trigger_datagram

TIMEOUT_S = 30.0
"""The bound on every wait: generous, since nothing here is timed."""

M = TypeVar("M", bound=Message)


class FakeEnforcer:
    """The enforcer's side, driven by the test: its socket, and an endpoint (socket and ring) per welcomed node."""

    def __init__(self, path: Path) -> None:
        self.sock = EnforcerSocket(path)
        self.path = path
        self.endpoints: dict[str, Endpoint] = {}

    def receive(self, timeout_s: float) -> tuple[Message, Received] | None:
        if not select.select([self.sock], (), (), timeout_s)[0]:
            return None
        for received in self.sock.receive(limit=1):
            return decode(received.data), received
        return None

    def expect(self, kind: type[M]) -> tuple[M, Received]:
        got = self.receive(TIMEOUT_S)
        assert got is not None, f"no {kind.__name__} within {TIMEOUT_S} s"
        message, received = got
        assert isinstance(message, kind), f"expected a {kind.__name__}, got {message!r}"
        return message, received

    def welcome(self, names: set[str]) -> dict[str, Hello]:
        """Take a hello from each node in ``names`` and welcome it (its endpoint and ring)."""
        seen: dict[str, Hello] = {}
        while set(seen) != names:
            hello, received = self.expect(Hello)
            assert hello.node in names
            assert received.sender is not None
            seen[hello.node] = hello
            self.endpoints[hello.node] = open_endpoint(hello.node, hello.pid, hello.tid, received.sender)
        return seen

    def send(self, node: str, message: Message) -> None:
        assert self.endpoints[node].send(message.encode())

    def trigger(self, node: str, seq: int, threads: int = 1) -> None:
        assert self.endpoints[node].send(trigger_datagram(node, seq, threads))

    def address(self, node: str) -> bytes:
        address = self.endpoints[node].address
        assert isinstance(address, bytes)
        return address

    def runs(self, node: str, count: int = 1) -> list[ring.Entry]:
        """The next ``count`` runs ``node`` reports in its ring."""
        reader = self.endpoints[node].reader
        assert reader is not None
        found: list[ring.Entry] = []
        deadline = time.monotonic() + TIMEOUT_S
        while len(found) < count:
            assert time.monotonic() < deadline, f"{node} reported {len(found)} of {count} runs"
            found += reader.new()
            time.sleep(0.001)
        return found

    def close(self) -> None:
        for endpoint in self.endpoints.values():
            endpoint.close()
        self.sock.close()
