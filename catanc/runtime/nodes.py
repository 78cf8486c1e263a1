"""The app's node threads as the enforcer keeps them: registered, placed, routed, and put back.

- **Registering**: a hello passes :meth:`Registry.check` (known node, limits, rate, who may
  register which thread) before anything is read from ``/proc`` or changed; then the thread
  gets its endpoint (socket and ring, :func:`~catanc.runtime.endpoints.open_endpoint`), its
  original is remembered (for the restore and the watchdog), and it is *placed*: pinned to its
  subchain's CPUs at its resting SCHED_FIFO level (1 shared, 2 dedicated, 3 unscheduled).
- **Routes**: every node of a subchain is told where its runs go next (its successor's
  address and thread count) and whom to accept triggers from (its predecessor): only heads
  are triggered by the enforcer.  Routes are sent again whenever a neighbour comes or goes.
- **Adopting**: threads a raised node thread starts inherit its level and CPUs; once a second
  they are looked for and remembered, so they are put back too.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from catanc.control.schedule import RuntimeSchedule, SubchainRun, node_priority
from catanc.core.priorities import APP_FIFO_LEVELS
from catanc.runtime import protocol
from catanc.runtime.endpoints import Endpoint, EnforcerSocket, Received, Registry, open_endpoint
from catanc.runtime.levels import Levels
from catanc.runtime.ring import RingReader
from catanc.runtime.sched import SCHED_RESET_ON_FORK, Restorer, ThreadGone, read_policy, set_affinity, threads_of

Note = Callable[[str, str], None]
"""(kind, text): something to tell (throttled per kind by the caller)."""
Log = Callable[..., None]


@dataclass(frozen=True)
class Wiring:
    """What the enforcer's hot path needs of the node threads, per subchain, for one registry version."""

    version: int
    schedule: RuntimeSchedule
    readers: dict[str, tuple[tuple[int, Endpoint, RingReader], ...]]  # (node index, thread, its ring)
    tids: dict[str, tuple[tuple[int, ...], ...]]  # [first]: the threads of the nodes from node `first` on
    heads: dict[str, Endpoint | None]  # the head to trigger, if every node has a thread that can run


@dataclass(frozen=True)
class Registered:
    """A registration accepted."""

    endpoint: Endpoint
    replaced: bool


class NodeThreads:
    """Registered node threads: registration, placement, routes, adoption; :attr:`schedule` is the plan in force."""

    def __init__(
        self,
        registry: Registry,
        levels: Levels,
        restorer: Restorer,
        schedule: RuntimeSchedule,
        *,
        rt: bool,
        cpus_of: Callable[[Iterable[int]], frozenset[int]],
        note: Note,
        log: Log,
    ) -> None:
        self.registry = registry
        self.levels = levels
        self.restorer = restorer
        self.schedule = schedule
        self.rt = rt
        self.cpus_of = cpus_of
        self.note = note
        self.log = log
        self.version = 0  # bumped whenever a node thread comes or goes (what the enforcer derives is redone)
        self.preexisting: dict[int, set[int]] = {}  # pid -> its threads when a node of it first registered

    # ------------------------------------------------------------------ registering

    def hello(self, hello: protocol.Hello, received: Received, sock: EnforcerSocket) -> Registered | None:
        """Register ``hello``'s thread if its sender may (a reject otherwise, unless it is over its rate)."""
        why, answer = self.registry.check(hello, received.credentials)
        if why is not None:
            self.note("hello", f"registration of {hello.node!r} (thread {hello.tid}) refused: {why}")
            if answer:
                sock.reply(protocol.Reject(hello.node, why).encode(), received.sender)
            return None
        if received.sender is None:
            return None
        try:
            endpoint = open_endpoint(hello.node, hello.pid, hello.tid, received.sender, on_input=hello.on_input)
        except OSError:
            return None  # its socket is gone already
        try:
            if hello.pid not in self.preexisting:  # read before the thread is raised: what it starts later inherits
                self.preexisting[hello.pid] = set(threads_of(hello.pid))
            self.restorer.remember(hello.tid)
            if not self.place(endpoint):
                endpoint.close()
                return None
        except ThreadGone:
            endpoint.close()
            return None
        except BaseException:
            endpoint.close()
            raise
        previous = self.registry.add(endpoint)
        if previous is not None:
            previous.close()
        self.version += 1
        self.routes()
        self.log("register", node=hello.node, pid=hello.pid, tid=hello.tid)
        return Registered(endpoint, previous is not None)

    def attach(self, node: str, pid: int, tids: Iterable[int]) -> None:
        """Pin and prioritise the threads of a process that does not speak the protocol, as ``node``'s."""
        for tid in tids:
            endpoint = Endpoint(node, pid, tid, None)
            try:
                self.restorer.remember(tid)
            except ThreadGone:
                continue
            if self.place(endpoint):
                self.registry.add(endpoint)
                self.version += 1

    def bye(self, bye: protocol.Bye, sender: object) -> None:
        endpoint = self.registry.find(bye.node, bye.tid)
        if endpoint is not None and endpoint.address == sender:
            self.unregister(endpoint)

    def unregister(self, endpoint: Endpoint) -> None:
        if self.registry.remove(endpoint):
            if not any(other.tid == endpoint.tid for other in self.registry.endpoints()):
                self.levels.forget(endpoint.tid)
            self.version += 1
            self.routes()

    def gone(self, endpoint: Endpoint, why: str = "exited") -> None:
        """A node thread exited or stopped taking datagrams: forget it, the others go on."""
        if self.registry.find(endpoint.node, endpoint.tid) is endpoint:
            self.unregister(endpoint)
            self.note("gone", f"{endpoint.node}: thread {endpoint.tid} {why}")
            self.log("gone", node=endpoint.node, tid=endpoint.tid)

    def gone_tids(self, tids: Iterable[int]) -> None:
        for tid in set(tids):
            for endpoint in [e for e in self.registry.endpoints() if e.tid == tid]:
                self.gone(endpoint)

    # ------------------------------------------------------------------ placing

    def place(self, endpoint: Endpoint) -> bool:
        """Pin a node thread to its subchain's CPUs at its resting level (CPUs only without RT); False if gone."""
        run = self.schedule.subchain_of(endpoint.node)
        cores = run.cores if run is not None else range(self.schedule.cores)
        level = node_priority(run)
        try:
            set_affinity(endpoint.tid, self.cpus_of(cores))
        except ThreadGone:
            return False
        return self.levels.rest(endpoint.tid, max(level, self._other_roles(endpoint)))

    def _other_roles(self, endpoint: Endpoint) -> int:
        """The highest resting level the same thread has as another node (an executor serving several)."""
        levels = [
            node_priority(self.schedule.subchain_of(other.node))
            for other in self.registry.endpoints()
            if other.tid == endpoint.tid and other.node != endpoint.node
        ]
        return max(levels, default=0)

    def place_all(self) -> None:
        """Re-pin every node thread for a new allocation (the caller resets what it had raised)."""
        self.levels.reset()
        for endpoint in self.registry.endpoints():
            if not self.place(endpoint):
                self.gone(endpoint)

    # ------------------------------------------------------------------ routes

    def route_for(self, endpoint: Endpoint) -> protocol.Route:
        run = self.schedule.subchain_of(endpoint.node)
        if run is None:
            return protocol.Route(endpoint.node)
        index = run.nodes.index(endpoint.node)
        after = self.registry.speaker(run.nodes[index + 1]) if index + 1 < len(run.nodes) else None
        before = self.registry.speaker(run.nodes[index - 1]) if index > 0 else None
        return protocol.Route(
            endpoint.node,
            False,
            None if after is None else after.node,
            run.threads_of(index + 1)[0] if after is not None else 1,
            None if after is None or after.on_input else _raw(after.address),  # its message wakes it
            None if before is None else _raw(before.address),
        )

    def routes(self) -> None:
        """Send each node thread its route where it changed."""
        for endpoint in self.registry.endpoints():
            if endpoint.sock is None:
                continue
            route = self.route_for(endpoint)
            if route == endpoint.route:
                continue
            if endpoint.send(route.encode()):
                endpoint.route = route
            else:
                self.gone(endpoint, f"takes no datagrams ({endpoint.error})")

    # ------------------------------------------------------------------ what the hot path asks

    def head(self, run: SubchainRun) -> Endpoint | None:
        """``run``'s head thread to trigger, if every node of ``run`` has a thread that can run (else a run
        started now would stall at the missing one and be given up as lost)."""
        head = None
        for node in run.nodes:
            speaker = self.registry.speaker(node)
            if speaker is None:
                return None
            head = head or speaker
        return head

    def wiring(self, schedule: RuntimeSchedule) -> Wiring:
        """Per subchain, what the hot path needs of its node threads (rebuilt when a thread comes or goes)."""
        readers: dict[str, tuple[tuple[int, Endpoint, RingReader], ...]] = {}
        tids: dict[str, tuple[tuple[int, ...], ...]] = {}
        heads: dict[str, Endpoint | None] = {}
        for name, run in schedule.subchains.items():
            readers[name] = tuple(
                (index, endpoint, endpoint.reader)
                for index, node in enumerate(run.nodes)
                for endpoint in self.registry.of(node)
                if endpoint.reader is not None
            )
            tids[name] = tuple(
                tuple(endpoint.tid for node in run.nodes[first:] for endpoint in self.registry.of(node))
                for first in range(len(run.nodes))
            )
            heads[name] = self.head(run)
        return Wiring(self.version, schedule, readers, tids, heads)

    # ------------------------------------------------------------------ the end

    def stop_all(self) -> None:
        """Tell every registered node the run is over (their loops end; they are not killed)."""
        stop = protocol.Stop().encode()
        for endpoint in self.registry.endpoints():
            endpoint.send(stop)

    def adopt_spawned(self) -> None:
        """Remember threads that node threads started after being raised, so they are put back too.

        A new thread inherits its creator's SCHED_FIFO level and CPUs (a multi-threaded node's
        helpers, say).  Their own original is unknowable; they get their creator's.  Threads the
        app raised itself, and those its process had when its node registered, are left alone.
        Bounded: one listing of ``/proc/<pid>/task`` per registered process.
        """
        known = self.restorer.remembered
        creators = {e.pid: e.tid for e in self.registry.endpoints() if e.tid in known}
        for pid in list(self.preexisting):
            if pid not in creators:
                del self.preexisting[pid]
        for pid, creator in creators.items():
            for tid in threads_of(pid):
                if tid in known or tid in self.preexisting.get(pid, ()):
                    continue
                try:
                    now = read_policy(tid)
                    if now.policy & ~SCHED_RESET_ON_FORK == os.SCHED_FIFO and now.priority in APP_FIFO_LEVELS:
                        self.restorer.remember(tid, original=known[creator])
                except ThreadGone:
                    continue


def _raw(address: bytes | str | None) -> bytes | None:
    if address is None:
        return None
    return address.encode() if isinstance(address, str) else address
