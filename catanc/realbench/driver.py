"""The baselines' side of the trigger protocol: registrations, triggers on timers and inputs, stop.

Plays the enforcer's part of :mod:`catanc.runtime.protocol.messages` (:class:`DriverSocket`: the
enforcer's socket and an endpoint per node, as ``catanc run`` makes them), so the workers of
every policy run the same client code, but only triggers: the rules of
:mod:`catanc.control.timers`, no slices, no re-planning.  Each node is routed to report
every run with a ``done`` (``NOTIFY 1``), which its input-triggered successors wait for.  Each
registering thread is handed to ``place`` (pin it, set its priority) before it is welcomed.
One thread does everything, the caller's.
"""

from __future__ import annotations

import select
import time
from collections.abc import Callable, Collection
from pathlib import Path

from catanc.control.timers import TIMER, Clock, TriggerRules, Triggers
from catanc.errors import CatancError, ExitCode
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol.endpoints import Endpoint, EnforcerSocket, decode_or_none, open_endpoint
from catanc.runtime.protocol.messages import Address
from catanc.spec.language import Spec

POLL_S = 0.05
"""The longest wait for a message while nodes register (then ``alive`` is asked again)."""


class BenchError(CatancError):
    """A benchmark run could not be completed (a worker failed, or never registered); the message says which."""

    exit_code = ExitCode.INTERNAL


def now_ms() -> float:
    return time.monotonic_ns() / 1e6


class DriverSocket:
    """The driver's transport: the enforcer's socket, and one endpoint (socket and ring) per welcomed node."""

    def __init__(self, path: str | Path) -> None:
        self.sock = EnforcerSocket(path)
        self.path = self.sock.path
        self._endpoints: dict[Address, Endpoint] = {}
        self._waiting: list[tuple[protocol.Message, Address]] = []

    def receive(self, timeout_s: float | None) -> tuple[protocol.Message, Address] | None:
        """The next message and its sender, waiting at most ``timeout_s`` (garbage is dropped)."""
        if not self._waiting:
            if not select.select([self.sock], (), (), timeout_s)[0]:
                return None
            for received in self.sock.receive():
                message, _ = decode_or_none(received.data)
                if message is not None and received.sender is not None:
                    self._waiting.append((message, received.sender))
        return self._waiting.pop(0) if self._waiting else None

    def welcome(self, hello: protocol.Hello, address: Address) -> bool:
        """Register ``hello``'s thread: its endpoint, welcome and ring, and a route asking for a done per run."""
        try:
            endpoint = open_endpoint(hello.node, hello.pid, hello.tid, address)
        except OSError:
            return False
        self._endpoints[address] = endpoint
        return endpoint.send(protocol.Route(hello.node, notify=True).encode())

    def send(self, message: protocol.Message, address: Address) -> bool:
        return self.send_bytes(message.encode(), address)

    def send_bytes(self, datagram: bytes, address: Address) -> bool:
        """Through the node's endpoint if it has one (a reject goes from the enforcer's socket)."""
        endpoint = self._endpoints.get(address)
        if endpoint is None:
            return self.sock.reply(datagram, address)
        return endpoint.send(datagram)

    def close(self) -> None:
        for endpoint in self._endpoints.values():
            endpoint.close()
        self._endpoints.clear()
        self.sock.close()

    def __enter__(self) -> DriverSocket:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Driver:
    """Registers the app's node threads and triggers them as the baseline says."""

    def __init__(
        self,
        sock: DriverSocket,
        spec: Spec,
        rules: TriggerRules,
        *,
        place: Callable[[protocol.Hello], None],
        clock: Callable[[], float] = now_ms,
    ) -> None:
        self.sock = sock
        self.spec = spec
        self.rules = rules
        self.place = place
        self.clock = clock
        self.endpoints: dict[str, Address] = {}
        self.triggers = Triggers(rules)
        self.running: dict[str, int] = {}  # node -> the seq of the run it was triggered for
        self.seq = 0
        self.sent = 0

    def register(self, nodes: Collection[str], timeout_s: float, alive: Callable[[], None]) -> None:
        """Welcome registrations until every node in ``nodes`` has one; ``alive()`` raises if a worker died."""
        deadline = time.monotonic() + timeout_s
        while not set(nodes) <= set(self.endpoints):
            alive()
            if time.monotonic() > deadline:
                missing = ", ".join(sorted(set(nodes) - set(self.endpoints)))
                raise BenchError(f"node(s) {missing} did not register within {timeout_s:g} s")
            got = self.sock.receive(POLL_S)
            if got is not None:
                self._handle(*got)

    def run(self, start_ms: float, end_ms: float) -> None:
        """Trigger from ``start_ms`` (timers and sensor clocks start there) until ``end_ms``."""
        clock = Clock(self.rules, start_ms)
        while True:
            now = self.clock()
            if now >= end_ms:
                return
            for _, kind, node in clock.due(now):
                self._start(self.triggers.fire(node) if kind == TIMER else self.triggers.output(node))
            wait_ms = min(clock.next_ms(), end_ms) - self.clock()
            got = self.sock.receive(max(wait_ms, 0.0) / 1000.0)
            if got is not None:
                self._handle(*got)

    def stop(self, grace_s: float = protocol.STOP_GRACE_S) -> None:
        """Tell every registered node the run is over (their loops end), then wait at most ``grace_s``
        for the runs still going: a node in the middle of one still reports it, and fails if the
        socket is gone.  Nothing new is triggered."""
        for address in self.endpoints.values():
            self.sock.send(protocol.Stop(), address)
        deadline = self.clock() + grace_s * 1000.0
        while self.running and (remaining_ms := deadline - self.clock()) > 0:
            got = self.sock.receive(remaining_ms / 1000.0)
            if got is not None and isinstance(got[0], protocol.Done | protocol.Bye):
                self.running.pop(got[0].node, None)

    def _handle(self, message: protocol.Message, address: Address) -> None:
        if isinstance(message, protocol.Hello):
            self._register(message, address)
        elif isinstance(message, protocol.Done):
            if self.running.get(message.node) == message.seq:
                del self.running[message.node]
                self._start(self.triggers.done(message.node))
        elif isinstance(message, protocol.Bye) and message.node in self.endpoints:
            del self.endpoints[message.node]
            self.running.pop(message.node, None)
            self.triggers.abandon(message.node)

    def _register(self, hello: protocol.Hello, address: Address) -> None:
        node = self.spec.nodes.get(hello.node)
        if node is None or not node.scheduled:
            why = "no node" if node is None else "no scheduled node"
            self.sock.send(protocol.Reject(hello.node, f"{why} {hello.node!r} in app {self.spec.app}"), address)
            return
        if hello.node in self.endpoints:
            self.sock.send(protocol.Reject(hello.node, f"node {hello.node!r} is registered already"), address)
            return
        self.place(hello)
        if self.sock.welcome(hello, address):
            self.endpoints[hello.node] = address

    def _start(self, nodes: list[str]) -> None:
        for node in nodes:
            address = self.endpoints.get(node)
            self.seq += 1
            if address is not None and self.sock.send_bytes(protocol.trigger_datagram(node, self.seq), address):
                self.running[node] = self.seq
                self.sent += 1
            else:  # not there (any more): it will not run, and nothing waits for it
                self.endpoints.pop(node, None)
                self.triggers.abandon(node)
