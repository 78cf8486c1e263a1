"""The app's node threads as the enforcer keeps them: registered, placed, routed, and put back.

- **Registering**: a hello passes :meth:`Registry.check` (known node, limits, rate, who may
  register which thread) before anything is read from ``/proc`` or changed; then the thread
  gets its endpoint (socket and ring, :func:`~catanc.runtime.protocol.endpoints.open_endpoint`), its
  original is remembered (for the restore and the watchdog), and it is *placed*: pinned to its
  subchain's CPUs at its resting SCHED_FIFO level (1 shared, 2 dedicated, 3 unscheduled).
- **Routes**: every node of a subchain is told where its runs go next (its successor's
  address and thread count) and whom to accept triggers from (its predecessor): only heads
  are triggered by the enforcer.  Routes are sent again whenever a neighbour comes or goes.
- **Adopting**: threads a raised node thread starts inherit its level and CPUs; once a second
  they are looked for and remembered, so they are put back too.
- **Companions**: a thread of a registered process named ``catanc-<node>`` (catanc.ros's watcher,
  which wakes the executor when a trigger comes) follows ``<node>``'s thread: its CPUs, its
  resting level, raised with it in its subchain's slice, re-pinned with it.
- **Middleware**: a registered process's middleware threads (Fast DDS ``dds.*``, ...) carry every
  message between processes, the hops the plan counts (``hops_ms``): they run at the level of
  nodes on their own clock (3, :data:`MIDDLEWARE_FIFO`), on the CPUs the plan gives the process's
  node threads, so a message is not delivered behind the subchains' work (docs/guide/ros2.md).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from catanc.control.schedule import RuntimeSchedule, SubchainRun, node_priority
from catanc.model.priorities import APP_FIFO_LEVELS, UNSCHEDULED_FIFO
from catanc.runtime.linux.levels import Levels
from catanc.runtime.linux.sched import (
    COMPANION_PREFIX,
    MIDDLEWARE_THREADS,
    SCHED_RESET_ON_FORK,
    Restorer,
    ThreadGone,
    read_policy,
    set_affinity,
    thread_name,
    threads_of,
)
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol.endpoints import Endpoint, EnforcerSocket, Received, Registry, open_endpoint
from catanc.runtime.protocol.ring import RingReader

MIDDLEWARE_FIFO = UNSCHEDULED_FIFO
"""Middleware threads deliver messages when they come, as nodes on their own clock run (docs/guide/ros2.md)."""

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
        self.companions: dict[int, set[int]] = {}  # a node thread -> the threads that serve it (catanc-<node>)
        self.middleware: dict[int, set[int]] = {}  # pid -> its middleware threads, placed
        self.examined: dict[int, set[int]] = {}  # pid -> its threads already looked at by name

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
            self._drop(tid)

    # ------------------------------------------------------------------ placing

    def place(self, endpoint: Endpoint) -> bool:
        """Pin a node thread to its subchain's CPUs at its resting level (CPUs only without RT); False if gone.

        Its companions go with it (one that is gone is forgotten).
        """
        cpus = self._cpus(endpoint)
        level = max(node_priority(self.schedule.subchain_of(endpoint.node)), self._other_roles(endpoint))
        try:
            set_affinity(endpoint.tid, cpus)
        except ThreadGone:
            return False
        if not self.levels.rest(endpoint.tid, level):
            return False
        for tid in list(self.companions.get(endpoint.tid, ())):
            if not self._put(tid, cpus, level):
                self._drop(tid)
        return True

    def _cpus(self, endpoint: Endpoint) -> frozenset[int]:
        run = self.schedule.subchain_of(endpoint.node)
        return self.cpus_of(run.cores if run is not None else range(self.schedule.cores))

    def _put(self, tid: int, cpus: frozenset[int], level: int) -> bool:
        """A thread that is no node's own on ``cpus`` at resting ``level``; False if it is gone."""
        try:
            set_affinity(tid, cpus)
        except ThreadGone:
            return False
        return self.levels.rest(tid, level)

    def _drop(self, tid: int) -> None:
        """Forget a companion or middleware thread (it exited)."""
        self.levels.forget(tid)
        for group in (*self.companions.values(), *self.middleware.values()):
            if tid in group:
                group.discard(tid)
                self.version += 1

    def _other_roles(self, endpoint: Endpoint) -> int:
        """The highest resting level the same thread has as another node (an executor serving several)."""
        levels = [
            node_priority(self.schedule.subchain_of(other.node))
            for other in self.registry.endpoints()
            if other.tid == endpoint.tid and other.node != endpoint.node
        ]
        return max(levels, default=0)

    def place_all(self) -> None:
        """Re-pin every node thread for a new allocation (the caller resets what it had raised), its companions
        and its process's middleware threads."""
        self.levels.reset()
        for endpoint in self.registry.endpoints():
            if not self.place(endpoint):
                self.gone(endpoint)
        for pid in list(self.middleware):
            self._place_middleware(pid)

    def _place_middleware(self, pid: int) -> None:
        cpus = frozenset().union(*(self._cpus(e) for e in self.registry.endpoints() if e.pid == pid))
        for tid in list(self.middleware.get(pid, ())):
            if not cpus or not self._put(tid, cpus, MIDDLEWARE_FIFO):
                self._drop(tid)

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
                tuple(
                    tid
                    for node in run.nodes[first:]
                    for endpoint in self.registry.of(node)
                    for tid in (endpoint.tid, *sorted(self.companions.get(endpoint.tid, ())))
                )
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
        for table in (self.middleware, self.examined):
            for pid in [pid for pid in table if pid not in creators]:
                del table[pid]
        for pid, creator in creators.items():
            tids = threads_of(pid)
            self._name_threads(pid, tids)
            for tid in tids:
                if tid in known or tid in self.preexisting.get(pid, ()):
                    continue
                try:
                    now = read_policy(tid)
                    if now.policy & ~SCHED_RESET_ON_FORK == os.SCHED_FIFO and now.priority in APP_FIFO_LEVELS:
                        self.restorer.remember(tid, original=known[creator])
                except ThreadGone:
                    continue

    def _name_threads(self, pid: int, tids: list[int]) -> None:
        """Place the threads of ``pid`` not looked at yet that are named as companions or middleware (remembered
        first, so they are put back); each thread is looked at once."""
        examined = self.examined.setdefault(pid, set())
        examined &= set(tids)  # a tid of an exited thread may come back as another
        own = {endpoint.tid for endpoint in self.registry.endpoints()}
        for tid in tids:
            if tid in examined or tid in own:
                continue
            examined.add(tid)
            name = thread_name(pid, tid) or ""
            try:
                if name.startswith(COMPANION_PREFIX):
                    self._companion(pid, tid, name)
                elif name.startswith(MIDDLEWARE_THREADS) and self.rt:
                    self.restorer.remember(tid)
                    self.middleware.setdefault(pid, set()).add(tid)
                    self.version += 1
            except ThreadGone:
                continue
        if pid in self.middleware:
            self._place_middleware(pid)

    def _companion(self, pid: int, tid: int, name: str) -> None:
        """``tid`` serves the node thread of ``pid`` its name gives (``catanc-<node>``, cut to 15 bytes)."""
        for endpoint in self.registry.endpoints():
            if endpoint.pid == pid and (COMPANION_PREFIX + endpoint.node)[:15] == name:
                # It inherited the node thread's level and CPUs if that started it: the node thread's original is its.
                self.restorer.remember(tid, original=self.restorer.remembered.get(endpoint.tid))
                self.companions.setdefault(endpoint.tid, set()).add(tid)
                self.version += 1
                self.place(endpoint)
                return


def _raw(address: bytes | str | None) -> bytes | None:
    if address is None:
        return None
    return address.encode() if isinstance(address, str) else address
