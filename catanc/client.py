"""The app side of ``catanc run``: a node thread that runs when it is triggered.

An app node does not know about cores or rates.  It registers its thread under its DAG node
name, waits for a trigger, runs once, and says so::

    from catanc.client import Node

    with Node("LM") as node:   # registers this thread; the socket comes from $CATANC_SOCKET
        for trigger in node:   # blocks until triggered; ends when the enforcer stops
            do_work()
            node.done()        # records the run (its thread CPU time) and wakes the next node

The enforcer (``catanc run``) pins and prioritises the registered thread (its native id), so
the work must run in the thread that entered the ``with`` block.  Only the head of a subchain
is triggered by the enforcer: :meth:`Node.done` wakes the subchain's next node directly (and
yields the CPU to it) and records the run in the node's ring, which the enforcer reads when it
wakes up anyway.
:meth:`Node.wait` takes a timeout; :meth:`Node.done` takes the compute time when the node
measures it itself; :meth:`Node.interrupt` ends the loop from another thread or a signal
handler.  Calling :meth:`Node.wait` without :meth:`Node.done` reports the pending run first.

A node that is not triggered (a ROS subscription callback later in a subchain: its input
wakes it) says so with ``on_input=True``, registers the thread its callback runs in and
reports each run, waiting for nothing; no node sends it a trigger (its message wakes it), and
without ``$CATANC_SOCKET`` it just runs (no enforcer to report to, no warning)::

    node = Node("LP", on_input=True); node.register()  # from the executor thread that runs the callback
    def on_scan(msg):
        with node.run(origin_ns=stamp_ns(msg.header.stamp)):  # or: node.begin(); ...; node.done(origin_ns=...)
            plan(msg)

A run's origin (``done(origin_ns=...)``) is when the data it carries was sensed, in
``CLOCK_REALTIME`` nanoseconds (``time.time_ns()``, the clock of a ROS ``header.stamp``): the
enforcer logs each run's age (its end minus its origin).  An executor that waits on many things
watches :meth:`Node.fd` (readable when a datagram waits), takes the trigger with
``node.wait(0)``, and asks :meth:`Node.alive` whether the enforcer is still there.

Multi-threaded nodes: ``trigger.threads`` is how many threads the plan gives this run.
Spread the work over that many and report the run's time with ``node.done(compute_ms=...)``
(its wall time): the enforcer turns it back into one-thread time with the spec's speedup.

Without an enforcer: ``Node("LM", fallback_period_ms=20.0)`` runs the same loop on its own
timer, every 20 ms, when ``$CATANC_SOCKET`` is unset (after one warning), so one node works
with and without ``catanc run``.  Without a fallback that is an error.  If the enforcer goes
away without stopping the node (it was killed), :meth:`Node.wait` returns None after a warning
and :attr:`Node.lost` says why: the loop ends cleanly.

This file uses only the standard library, imports nothing else of catanc, and runs on Python
3.8 and newer: copy it next to a node if catanc is not installed there (``catanc client
--python`` prints its path).  :mod:`catanc.runtime.protocol.messages` documents the protocol
(``catanc/2``) for clients in other languages; ``catanc client --cflags`` gives the C++
client's include folder.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import math
import mmap
import os
import select
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Iterator, NamedTuple

__all__ = ["SOCKET_ENV", "ClientError", "Node", "Trigger", "set_cores"]

log = logging.getLogger(__name__)

SOCKET_ENV = "CATANC_SOCKET"
PROTOCOL = b"catanc/2"
MAX_DATAGRAM = 512
_FD_SPACE = socket.CMSG_SPACE(4)
_HEADER = struct.Struct("=IIIIQ")
_ENTRY = struct.Struct("=QQQQIIQ")
_RING_MAGIC, _RING_VERSION, _HEADER_SIZE, _ENTRY_SIZE = 0x52544143, 1, 64, 48
_UNKNOWN = 2**64 - 1


class ClientError(RuntimeError):
    """A node cannot register with, or lost, the enforcer (the message says which and why)."""


class Trigger(NamedTuple):
    """Run once: run ``seq`` of the node's subchain, on ``threads`` threads."""

    node: str
    seq: int
    threads: int = 1


def _trigger_prefix(node: str) -> bytes:
    """A trigger of ``node`` up to its numbers: ``prefix + b"%d %d" % (seq, threads)`` is the datagram."""
    return b"%s trigger %s " % (PROTOCOL, node.encode("ascii", "replace"))


def _yield_cpu() -> Callable[[], object]:
    """sched_yield(2), letting go of the interpreter lock: ``os.sched_yield`` keeps it before Python
    3.10, so a next node in another thread of this process could not run (ctypes' calls let go)."""
    if sys.version_info >= (3, 10):
        return os.sched_yield
    try:
        import ctypes  # noqa: PLC0415 - only where os.sched_yield keeps the lock

        return ctypes.CDLL(None).sched_yield
    except (ImportError, OSError, AttributeError):
        return os.sched_yield


_sched_yield = _yield_cpu()


def _check_name(name: str) -> None:
    ok = isinstance(name, str) and 0 < len(name) <= 128 and name.isascii() and name.isidentifier()
    if not ok:
        raise ClientError(f"bad node name {name!r}: an identifier of 1 to 128 characters")


def _sender_bytes(sender: object) -> bytes:
    """A datagram's sender as bytes: a node's abstract address already is; the enforcer's socket has a path."""
    return sender if isinstance(sender, bytes) else os.fsencode(sender) if isinstance(sender, str) else b""


def _address(text: bytes) -> bytes | None:
    return None if text == b"-" else bytes.fromhex(text.decode("ascii"))


def _monotonic_origin(origin_ns: int | None) -> int:
    """A ``CLOCK_REALTIME`` origin as ``CLOCK_MONOTONIC`` ns, the ring's clock (0: none, or not a time)."""
    if origin_ns is None or isinstance(origin_ns, bool) or not isinstance(origin_ns, int) or origin_ns <= 0:
        return 0
    monotonic = origin_ns - time.time_ns() + time.monotonic_ns()
    return min(max(monotonic, 1), _UNKNOWN - 1)


class Node:
    """One DAG node's trigger loop, run by the thread that registers it.

    ``socket_path`` defaults to ``$CATANC_SOCKET``.  ``timeout_s`` bounds registration.  While
    waiting for a trigger the node checks every :attr:`PROBE_S` seconds that the enforcer's
    socket is still there; if it went away without a stop, :meth:`wait` returns None and
    :attr:`lost` says why.  ``fallback_period_ms``: where neither ``socket_path`` nor
    ``$CATANC_SOCKET`` names an enforcer, trigger this node every that many ms on its own.
    ``on_input``: the node runs on its input (:meth:`begin` and :meth:`done`, never :meth:`wait`):
    it tells the enforcer, so no node sends it triggers; without an enforcer it runs unreported.
    ``quiet``: write nothing to stderr when the enforcer is lost (the caller logs :attr:`lost` itself).
    """

    PROBE_S = 1.0

    def __init__(
        self,
        name: str,
        *,
        socket_path: str | os.PathLike[str] | None = None,
        timeout_s: float = 5.0,
        fallback_period_ms: float | None = None,
        on_input: bool = False,
        quiet: bool = False,
    ):
        _check_name(name)
        if on_input and fallback_period_ms is not None:
            raise ClientError(f"node {name!r}: a node that runs on its input has no fallback timer (on_input=True)")
        period_ok = isinstance(fallback_period_ms, (int, float)) and 0 < fallback_period_ms < math.inf
        if fallback_period_ms is not None and (isinstance(fallback_period_ms, bool) or not period_ok):
            raise ClientError(f"node {name!r}: fallback_period_ms is a number of ms > 0, not {fallback_period_ms!r}")
        self.fallback_period_ms: float | None = None
        """The period of the node's own timer when no enforcer runs (None: with an enforcer)."""
        self.on_input = bool(on_input)
        self.quiet = quiet  # the caller tells of a lost enforcer itself (catanc.ros, in the node's log)
        """The node runs on its input (no trigger starts it); without an enforcer it runs unreported."""
        self.standalone = False
        """An ``on_input`` node without an enforcer: its runs are reported to no one."""
        if socket_path is None:
            socket_path = os.environ.get(SOCKET_ENV)
            if not socket_path and on_input:
                self.standalone = True
            elif not socket_path:
                if fallback_period_ms is None:
                    raise ClientError(
                        f"no catanc enforcer socket: {SOCKET_ENV} is not set (`catanc run` sets it for the nodes it "
                        "starts) and no socket_path was given (or give a fallback_period_ms to run on a timer)"
                    )
                self.fallback_period_ms = float(fallback_period_ms)
        self.name = name
        self.socket_path = os.fspath(socket_path or "")
        self.timeout_s = timeout_s
        self.lost: str | None = None
        """Why the node lost its enforcer (it went away without a stop), or None."""
        self.tid: int | None = None
        """The registered thread's native id (set by :meth:`register`)."""
        self.trigger: Trigger | None = None
        """The trigger being worked on (until :meth:`done`)."""
        self.routed = False
        """True once the enforcer sent the node its route: it is placed (pinned, prioritised) by then."""
        self._start_ns = 0
        self._cpu_start = 0.0
        self._origin_ns = 0  # the pending run's origin given to begin() (CLOCK_MONOTONIC; 0: none)
        self._thread: int | None = None
        self._sock: socket.socket | None = None
        self._poller: select.poll | None = None  # the socket and the interrupt pipe, made once: waiting is the hot path
        self._readable: select.poll | None = None  # the socket alone: is a datagram waiting before a send?
        self._trigger_prefix = _trigger_prefix(name)
        self._own: bytes | None = None  # this node's own address: a datagram from it is interrupt()'s wake-up
        self._enforcer: bytes | None = None  # the address the enforcer talks to this node from
        self._identity: tuple[int, int] | None = None
        self._ring: mmap.mmap | None = None
        self._header: memoryview | None = None  # the ring's header as 8-byte words; [2] is `written`
        self._slots = 0
        self._written = 0
        self._next: tuple[bytes, bytes, int] | None = None  # (address, trigger prefix, threads): where a run goes next
        self._prev: bytes | None = None
        self._notify = False
        self._queued: collections.deque[Trigger] = collections.deque(maxlen=64)  # bounded: a node that never waits
        self._registered = False
        self._next_tick_ns = 0  # the fallback timer's next trigger (CLOCK_MONOTONIC)
        self._ticks = 0
        self._ended = False  # the enforcer stopped or rejected us, or went away
        self._interrupted = False
        self._closed = False
        self._lock = threading.RLock()
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
            os.set_inheritable(fd, False)

    @property
    def registered(self) -> bool:
        """True once the enforcer welcomed this node."""
        return self._registered

    @property
    def stopped(self) -> bool:
        """True once the enforcer said stop, or :meth:`interrupt` was called: :meth:`wait` returns None."""
        return self._ended or self._interrupted

    # -- registering ---------------------------------------------------------------

    def register(self) -> None:
        """Register the calling thread as this node; wait up to ``timeout_s`` for the enforcer's welcome."""
        if self._sock is not None or self._thread is not None or self._closed:
            raise ClientError(f"node {self.name!r} is already registered (or closed): use a new Node")
        self.tid = threading.get_native_id()
        self._thread = threading.get_ident()
        if self.fallback_period_ms is not None:
            sys.stderr.write(
                f"catanc: {SOCKET_ENV} is not set: node {self.name!r} runs on its own timer every "
                f"{self.fallback_period_ms:g} ms (no enforcer)\n"
            )
            self._next_tick_ns = time.monotonic_ns()
            return
        if self.standalone:
            return
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            sock.settimeout(None)  # blocking whatever socket.setdefaulttimeout() says: waiting blocks in the receive
            sock.bind("")  # Linux autobind: a unique abstract address the enforcer and the previous node send to
            info = Path(self.socket_path).stat()
            hello = b"%s hello %s %d %d" % (PROTOCOL, self.name.encode(), os.getpid(), self.tid)
            sock.sendto(hello + b" input" if self.on_input else hello, self.socket_path)
        except OSError as exc:
            sock.close()
            self.close()
            raise ClientError(self._absent(exc.strerror or str(exc))) from None
        self._sock = sock
        self._identity = (info.st_dev, info.st_ino)
        self._poller, self._readable = select.poll(), select.poll()
        self._poller.register(sock, select.POLLIN)
        self._poller.register(self._wake_r, select.POLLIN)
        self._readable.register(sock, select.POLLIN)
        try:
            deadline = time.monotonic() + self.timeout_s
            while not self.stopped and not self._registered:
                if not self._receive(deadline):
                    if self.lost is not None:
                        raise ClientError(self.lost)
                    if self.stopped:
                        break  # interrupted while registering
                    raise ClientError(self._absent(f"no answer in {self.timeout_s:g} s"))
            if self._registered:
                self._block_in_receive(sock)
        except BaseException:
            self.close()
            raise

    def _block_in_receive(self, sock: socket.socket) -> None:
        """From now on a wait blocks in the receive itself, one system call a wake-up instead of a poll
        and a receive: the receive times out every PROBE_S to look for the enforcer, and
        :meth:`interrupt` wakes it with a datagram to the node's own address."""
        seconds, fraction = divmod(self.PROBE_S, 1.0)
        try:
            timeout = struct.pack("@ll", int(seconds), int(fraction * 1e6))  # a struct timeval
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeout)
        except (OSError, struct.error):
            return  # the poll path, which needs neither
        self._own = sock.getsockname()

    def _welcome(self, words: list[bytes], fds: list[int], sender: bytes) -> None:
        if len(words) != 4 or words[2].decode("ascii", "replace") != self.name or len(fds) != 1:
            for fd in fds:
                os.close(fd)
            return
        fd = fds[0]
        try:
            magic, version, slots, entry_size, written = _HEADER.unpack(os.pread(fd, _HEADER.size, 0))
            if (magic, version, entry_size) != (_RING_MAGIC, _RING_VERSION, _ENTRY_SIZE):
                raise ClientError(f"node {self.name!r}: the enforcer's ring is of another layout (version {version})")
            self._ring = mmap.mmap(fd, _HEADER_SIZE + slots * _ENTRY_SIZE)
            # `written` is stored as one aligned 8-byte word: struct's pack_into zeroes the field,
            # then writes it a byte at a time, and the enforcer reading in between saw it go back.
            self._header = memoryview(self._ring)[:_HEADER_SIZE].cast("Q")
        finally:
            os.close(fd)
        self._slots, self._written = slots, written
        self._enforcer = sender
        self._registered = True

    # -- running -------------------------------------------------------------------

    def wait(self, timeout_s: float | None = None) -> Trigger | None:
        """The next trigger; None after ``timeout_s`` seconds, or once :attr:`stopped`.

        A pending run (a trigger without :meth:`done`) is reported as done first.
        """
        self._check_thread("wait")
        if self.trigger is not None:
            self.done()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        if self.fallback_period_ms is not None:
            return self._tick(deadline)
        while not self.stopped:
            if self._queued:
                trigger: Trigger | None = self._queued.popleft()
            elif deadline is None and self._own is not None:
                trigger = self._await()
                if trigger is None:
                    continue
            elif not self._receive(deadline):
                return None
            else:
                continue
            self.trigger = trigger
            self._start_ns = time.monotonic_ns()
            self._cpu_start = time.thread_time()
            return trigger
        return None

    def _tick(self, deadline: float | None) -> Trigger | None:
        """The fallback timer's next trigger, at ``period * k`` after registering (a late run skips
        the ticks it overran, as a timer does)."""
        period_ns = max(int((self.fallback_period_ms or 0.0) * 1e6), 1)
        now = time.monotonic_ns()
        if now - self._next_tick_ns > period_ns:
            self._next_tick_ns += (now - self._next_tick_ns) // period_ns * period_ns
        while not self._interrupted:
            now = time.monotonic_ns()
            if now >= self._next_tick_ns:
                self._next_tick_ns += period_ns
                self._ticks += 1
                self.trigger = Trigger(self.name, self._ticks, 1)
                self._start_ns = now
                self._cpu_start = time.thread_time()
                return self.trigger
            wait_s = (self._next_tick_ns - now) / 1e9
            if deadline is not None:
                wait_s = min(wait_s, deadline - time.monotonic())
                if wait_s <= 0:
                    return None
            if select.select([self._wake_r], [], [], wait_s)[0]:
                with contextlib.suppress(BlockingIOError):
                    while os.read(self._wake_r, 64):
                        pass
        return None

    def begin(self, origin_ns: int | None = None) -> int:
        """Start a run nothing triggered (a subscription callback): its CLOCK_MONOTONIC start in ns.

        ``origin_ns``: when its data was sensed (``CLOCK_REALTIME`` ns), unless :meth:`done` says.
        """
        self._check_thread("begin")
        self.trigger = Trigger(self.name, 0, 1)
        self._start_ns = time.monotonic_ns()
        self._cpu_start = time.thread_time()
        self._origin_ns = _monotonic_origin(origin_ns)
        return self._start_ns

    @contextlib.contextmanager
    def run(self, origin_ns: int | None = None) -> Iterator[None]:
        """``with node.run(): body``: :meth:`begin`, the body, then :meth:`done` (with ``origin_ns``)."""
        self.begin(origin_ns)
        try:
            yield
        finally:
            self.done()

    def fd(self) -> int | None:
        """The registered socket's descriptor, readable when a datagram (a trigger, a route, a stop) waits:
        for an executor that waits on it with other things, then takes the trigger with ``wait(0)``.
        None without an enforcer (on a fallback timer, or an ``on_input`` node without one)."""
        return None if self._sock is None else self._sock.fileno()

    def alive(self) -> bool:
        """Whether the enforcer is still there: registered, not stopped, not lost, and its socket takes
        datagrams (a stat and a connect: ask it now and then, not per run).  False without an enforcer."""
        if self._sock is None or self._ended or not self._registered:
            return False
        if not self._enforcer_alive():
            self._lose(f"it went away without stopping node {self.name!r}")
            return False
        return True

    def done(self, compute_ms: float | None = None, *, origin_ns: int | None = None) -> None:
        """Report the current run as finished, and wake the subchain's next node (on this CPU it
        runs before this returns: this thread yields to it).

        ``compute_ms`` defaults to this thread's CPU time since the trigger arrived, which time
        spent preempted does not inflate.  ``origin_ns``: when the data the run carries was sensed,
        in ``CLOCK_REALTIME`` ns (``time.time_ns()``; a ROS ``header.stamp``), or None: the one
        :meth:`begin` took, else none (the enforcer then takes a head's start).
        """
        self._check_thread("done")
        trigger = self.trigger
        if trigger is None:
            raise ClientError(f"node {self.name!r}: done() without a trigger (call it once per run, after wait())")
        self.trigger = None
        end_ns = time.monotonic_ns()
        origin = self._origin_ns if origin_ns is None else _monotonic_origin(origin_ns)
        self._origin_ns = 0
        if compute_ms is None:
            compute_ns = int((time.thread_time() - self._cpu_start) * 1e9)
        elif math.isfinite(compute_ms) and compute_ms >= 0:
            compute_ns = min(int(compute_ms * 1e6), _UNKNOWN - 1)
        else:
            compute_ns = _UNKNOWN
        readable = self._readable
        if readable is not None and readable.poll(0):  # asked here, not in _drain: this is the hop's path
            self._drain()  # a route that changed while the run went on
        sock = self._sock
        after = self._next
        woke_next = False
        if after is not None and sock is not None and not self._ended and trigger.seq:
            address, prefix, threads = after
            try:
                sock.sendto(prefix + b"%d %d" % (trigger.seq, threads), socket.MSG_DONTWAIT, address)
                woke_next = True
            except OSError:  # the next node is gone: the enforcer sees its run lost
                pass
        self._record(trigger, end_ns, compute_ns, origin)  # after a stop too: the enforcer reads its last runs' reports
        if sock is None or self._ended:
            return
        if self._notify:
            done = b"%s done %s %d %d" % (PROTOCOL, self.name.encode(), self.tid or 0, trigger.seq)
            with contextlib.suppress(OSError):
                sock.sendto(done, socket.MSG_DONTWAIT, self.socket_path)
        if woke_next:
            # The next node shares this thread's priority (its subchain's), so on this CPU it would wait
            # until this thread blocks in its next wait: let it run first, this thread's way back after.
            _sched_yield()

    def _record(self, trigger: Trigger, end_ns: int, compute_ns: int, origin_ns: int = 0) -> None:
        ring, header = self._ring, self._header
        if ring is None or header is None:
            return
        offset = _HEADER_SIZE + (self._written % self._slots) * _ENTRY_SIZE
        _ENTRY.pack_into(ring, offset, trigger.seq, self._start_ns, end_ns, compute_ns, trigger.threads, 0, origin_ns)
        self._written += 1
        header[2] = self._written  # after the entry: the enforcer reads up to `written`

    def interrupt(self) -> None:
        """End the trigger loop: a blocked :meth:`wait` returns None.  Safe from any thread and from signal handlers."""
        with self._lock:
            self._interrupted = True
            if not self._closed:
                with contextlib.suppress(BlockingIOError):  # the pipe is full: a wake-up is pending anyway
                    os.write(self._wake_w, b"!")
                sock, own = self._sock, self._own
                if sock is not None and own is not None:  # a wait blocked in the receive
                    with contextlib.suppress(OSError):  # the queue is full: a datagram wakes it anyway
                        sock.sendto(b"", socket.MSG_DONTWAIT, own)

    def close(self) -> None:
        """Leave: say bye unless the enforcer ended the node, and release the socket.  Safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            sock, self._sock = self._sock, None
            if sock is not None:
                if not self._ended and self.tid is not None:
                    # Registered or not (interrupted before the welcome was read, the enforcer may have
                    # registered it).  If the enforcer is gone or busy, it notices the thread is gone anyway.
                    with contextlib.suppress(OSError):
                        bye = b"%s bye %s %d" % (PROTOCOL, self.name.encode(), self.tid)
                        sock.sendto(bye, socket.MSG_DONTWAIT, self.socket_path)
                sock.close()
            if self._ring is not None:
                if self._header is not None:
                    self._header.release()
                    self._header = None
                self._ring.close()
                self._ring = None
            os.close(self._wake_r)
            os.close(self._wake_w)

    def __enter__(self) -> Node:
        self.register()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[Trigger]:
        while True:
            trigger = self.wait()
            if trigger is None:
                return
            yield trigger

    def __repr__(self) -> str:
        return f"Node({self.name!r}, socket_path={self.socket_path!r}, tid={self.tid})"

    # -- internals -----------------------------------------------------------------

    def _absent(self, reason: str) -> str:
        return f"no catanc enforcer at {self.socket_path} ({reason}): is `catanc run` running?"

    def _check_thread(self, what: str) -> None:
        on_timer = (self.fallback_period_ms is not None or self.standalone) and self._thread is not None
        on_timer = on_timer and not self._closed
        if not on_timer and (self._sock is None or not (self._registered or self.stopped)):
            raise ClientError(f"node {self.name!r}: register before {what}() (use `with Node(...) as node:`)")
        if threading.get_ident() != self._thread:
            raise ClientError(
                f"node {self.name!r} is registered by thread {self.tid}: call {what}() from that thread "
                "(it is the thread the enforcer schedules)"
            )

    def _drain(self) -> None:
        """Take every datagram waiting now (routes, stop; triggers are queued for :meth:`wait`), once a poll
        said one waits: a receive that finds nothing raises, and this runs between a run's end and the next
        node's start."""
        sock, readable = self._sock, self._readable
        while sock is not None and readable is not None and not self._ended:
            try:
                self._take(sock)
            except OSError:  # nothing after all, or the socket failed: the next wait sees it
                return
            if not readable.poll(0):
                return

    def _take(self, sock: socket.socket) -> None:
        """Receive one datagram and act on it; a trigger from the enforcer or the previous node the short way."""
        if not self._registered:  # the welcome brings the ring's descriptor
            data, ancillary, _flags, sender = sock.recvmsg(MAX_DATAGRAM + 1, _FD_SPACE, socket.MSG_DONTWAIT)
            self._handle(data, ancillary, sender)
            return
        # No room for descriptors once registered: the kernel closes any a peer sends.
        data, received_from = sock.recvfrom(MAX_DATAGRAM + 1, socket.MSG_DONTWAIT)
        trigger = self._accept(data, received_from)
        if trigger is not None:
            self._queued.append(trigger)

    def _await(self) -> Trigger | None:
        """Block in the receive until a datagram comes: a trigger, or None once it was something else
        (handled), interrupt()'s wake-up, PROBE_S without one, or the enforcer lost."""
        sock = self._sock
        assert sock is not None
        try:
            data, received_from = sock.recvfrom(MAX_DATAGRAM + 1)
        except BlockingIOError:  # SO_RCVTIMEO: PROBE_S went by without a datagram
            if not self._enforcer_alive():
                self._lose(f"it went away without stopping node {self.name!r}")
            return None
        except InterruptedError:
            return None
        except OSError as exc:
            self._lose(exc.strerror or str(exc))
            return None
        # The previous node's trigger parsed here, not in _accept: the hop's path, where each Python call
        # costs a few us in a process that other processes' runs left cold.
        prefix = self._trigger_prefix
        if received_from == self._prev and data.startswith(prefix):
            words = data[len(prefix) :].split(b" ")
            if len(words) == 2 and words[0].isdigit() and words[1].isdigit():
                return Trigger(self.name, int(words[0]), max(int(words[1]), 1))
        return self._accept(data, received_from)

    def _accept(self, data: bytes, received_from: object) -> Trigger | None:
        """A registered node's datagram: a trigger from the enforcer or the previous node the short way;
        anything else handled (None)."""
        sender = _sender_bytes(received_from)
        prefix = self._trigger_prefix
        if data.startswith(prefix) and (sender == self._enforcer or (self._prev and sender == self._prev)):
            words = data[len(prefix) :].split(b" ")
            if len(words) == 2 and words[0].isdigit() and words[1].isdigit():
                return Trigger(self.name, int(words[0]), max(int(words[1]), 1))
        if sender != self._own:  # the node's own datagram is interrupt()'s wake-up: nothing to handle
            self._handle(data, [], sender)
        return None

    def _receive(self, deadline: float | None) -> bool:
        """Wait for and handle datagrams until something changed (a trigger queued, registered, ended);
        False at the deadline or on interrupt."""
        sock, poller = self._sock, self._poller
        assert sock is not None
        assert poller is not None
        wake_r = self._wake_r
        while True:
            if self._interrupted:
                return False
            wait_s = self.PROBE_S
            if deadline is not None:
                wait_s = min(wait_s, max(deadline - time.monotonic(), 0.0))
            ready = [fd for fd, _ in poller.poll(wait_s * 1000.0)]
            if wake_r in ready:
                with contextlib.suppress(BlockingIOError):
                    while os.read(wake_r, 64):
                        pass
                continue
            if ready:
                before = (len(self._queued), self._registered, self._ended)
                try:
                    self._take(sock)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    self._lose(exc.strerror or str(exc))
                    return False
                if (len(self._queued), self._registered, self._ended) != before:
                    return True
                continue
            if deadline is not None and time.monotonic() >= deadline:
                return False
            if not ready and not self._enforcer_alive():
                self._lose(f"it went away without stopping node {self.name!r}")
                return False

    def _lose(self, reason: str) -> None:
        """The enforcer is gone: end the loop (wait() returns None), and say so once."""
        self._ended = True
        self.lost = f"lost the catanc enforcer at {self.socket_path}: {reason}"
        if not self.quiet:
            sys.stderr.write(f"catanc: {self.lost}\n")

    def _handle(self, data: bytes, ancillary: list[tuple[int, int, bytes]], sender: object) -> None:
        fds: list[int] = []
        for level, what, payload in ancillary:
            if level == socket.SOL_SOCKET and what == socket.SCM_RIGHTS:
                fds += list(struct.unpack(f"={len(payload) // 4}i", payload[: len(payload) // 4 * 4]))
        address = _sender_bytes(sender)
        words = data.split(b" ")
        if words[0] != PROTOCOL or len(words) < 2:
            for fd in fds:
                os.close(fd)
            log.warning("node %r dropped a datagram that is not %s", self.name, PROTOCOL.decode())
            return
        kind = words[1]
        if kind == b"welcome" and not self._registered:
            self._welcome(words, fds, address)
            return
        for fd in fds:
            os.close(fd)
        from_enforcer = self._registered and address == self._enforcer
        if kind == b"reject" and len(words) >= 3 and words[2].decode("ascii", "replace") == self.name:
            if from_enforcer or not self._registered:
                self._ended = True
                reason = b" ".join(words[3:]).decode("utf-8", "replace")
                verb = "dropped" if self._registered else "rejected"
                raise ClientError(f"the catanc enforcer at {self.socket_path} {verb} node {self.name!r}: {reason}")
        elif kind == b"trigger" and len(words) == 5 and (from_enforcer or (self._prev and address == self._prev)):
            if words[2].decode("ascii", "replace") == self.name and words[3].isdigit() and words[4].isdigit():
                self._queued.append(Trigger(self.name, int(words[3]), max(int(words[4]), 1)))
        elif kind == b"route" and len(words) == 8 and from_enforcer and words[2] == self.name.encode():
            try:
                next_address, prev_address = _address(words[6]), _address(words[7])
                threads = int(words[5])
            except ValueError:
                return
            self._notify = words[3] == b"1"
            self.routed = True
            self._prev = prev_address
            next_prefix = _trigger_prefix(words[4].decode("ascii"))
            self._next = None if next_address is None else (next_address, next_prefix, threads)
        elif kind == b"stop" and from_enforcer:
            self._ended = True

    def _enforcer_alive(self) -> bool:
        try:
            info = Path(self.socket_path).stat()
        except OSError:
            return False
        if (info.st_dev, info.st_ino) != self._identity:
            return False  # a new enforcer: this registration belonged to the old one
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            probe.connect(self.socket_path)
        except OSError as exc:
            return exc.errno not in (errno.ECONNREFUSED, errno.ENOENT)
        finally:
            probe.close()
        return True


def set_cores(cores: int, socket_path: str | None = None) -> None:
    """Tell a running enforcer to plan for ``cores`` cores from now on (Stage I again, then re-pinning)."""
    path = socket_path or os.environ.get(SOCKET_ENV)
    if not path:
        raise ClientError(f"no enforcer socket: pass one or set {SOCKET_ENV}")
    if isinstance(cores, bool) or not isinstance(cores, int) or cores < 1:
        raise ClientError(f"set_cores: a number of cores >= 1, not {cores!r}")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        try:
            sock.sendto(b"%s set_cores %d" % (PROTOCOL, cores), path)
        except OSError as exc:
            raise ClientError(f"no catanc enforcer at {path}: {exc.strerror or exc}") from None
