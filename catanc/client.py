"""The app side of ``catanc run``: a node thread that runs when the enforcer triggers it.

An app node does not know about cores or rates.  It registers its thread
under its DAG node name, waits for a trigger, runs once, and says so::

    from catanc.client import Node

    with Node("LM") as node:   # registers this thread; the socket comes from $CATANC_SOCKET
        for trigger in node:   # blocks until triggered; ends when the enforcer stops
            do_work()
            node.done()        # reports the thread CPU time used since the trigger arrived

The enforcer (``catanc run``) pins and prioritises the registered thread
(its native id, :func:`threading.get_native_id`), so the work must run in
the thread that entered the ``with`` block.  :meth:`Node.wait` takes a
timeout; :meth:`Node.done` takes the compute time when the node measures
it itself; :meth:`Node.interrupt` ends the loop from another thread or a
signal handler.  Calling :meth:`Node.wait` (or the next loop step) without
:meth:`Node.done` reports the pending run as done.  Triggers are delivered
in the order sent, one per run.

Multi-threaded nodes: ``trigger.threads`` is how many threads the plan
gives this run (more than 1 only for a node whose spec lists a speedup, on
a subchain with dedicated cores).  Spread the work over that many threads
and report the run's time with ``node.done(compute_ms=...)`` (wall time,
or the registered thread's CPU time if it works throughout): the enforcer
turns it back into one-thread time with the spec's speedup.  Only the
registered thread is pinned and prioritised; register helper threads as
nodes of their own if they must be too.

This module and :mod:`catanc.runtime.protocol` use only the standard
library: importing them loads no solver.

ROS 2, rclpy
------------
Replace the node's wall timer with a thread that runs the timer callback's
body on each trigger::

    import threading

    import rclpy.node
    from catanc.client import Node as Triggers

    class LocalMapper(rclpy.node.Node):
        def __init__(self) -> None:
            super().__init__("LM")
            # was: self.create_timer(0.05, self.step)
            self.triggers = Triggers("LM")
            threading.Thread(target=self.run_triggered, daemon=True).start()

        def run_triggered(self) -> None:
            with self.triggers:              # registers *this* thread: the one catanc schedules
                for _ in self.triggers:
                    self.step()              # the old timer callback's body
                    self.triggers.done()

        def step(self) -> None: ...

    # on shutdown: node.triggers.interrupt() ends the loop.

``step`` runs in that thread, not in the executor: publishing is
thread-safe; guard state the subscription callbacks also touch.

ROS 2, rclcpp (or any language)
-------------------------------
The protocol is just JSON datagrams (:mod:`catanc.runtime.protocol`):

1. ``socket(AF_UNIX, SOCK_DGRAM)``; bind with an empty address
   (``addrlen = sizeof(sa_family_t)``: Linux autobind gives a unique
   abstract name, so the enforcer can answer); ``connect`` to the path in
   ``$CATANC_SOCKET``.
2. From the thread that runs the callback, send
   ``{"v":1,"type":"hello","node":"LM","pid":<getpid()>,"tid":<gettid()>}``
   and wait for ``{"v":1,"type":"welcome","node":"LM"}`` (or
   ``{"v":1,"type":"reject","node":"LM","reason":"..."}``).
3. Loop on ``recv``: on ``{"v":1,"type":"trigger","node":"LM","seq":17,"threads":1}``
   run the callback body (on ``threads`` threads if it can use more than one), then send
   ``{"v":1,"type":"done","node":"LM","tid":<tid>,"seq":17,"compute_ms":3.2}``
   (``compute_ms``: ``CLOCK_THREAD_CPUTIME_ID`` elapsed since the trigger,
   or ``null``); on ``{"v":1,"type":"stop"}`` leave the loop.
4. When leaving on your own, send ``{"v":1,"type":"bye","node":"LM","tid":<tid>}``.

Keep each datagram under 1 KiB; ignore messages you do not know.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import ClassVar, Self

from catanc.errors import CatancError
from catanc.runtime.protocol import (
    MAX_DATAGRAM,
    SOCKET_ENV,
    Bye,
    Done,
    Hello,
    Message,
    ProtocolError,
    Reject,
    SetCores,
    Stop,
    Trigger,
    Welcome,
    decode,
)

__all__ = ["SOCKET_ENV", "ClientError", "Node", "Trigger", "set_cores"]

log = logging.getLogger(__name__)

_INTERRUPTED = object()


class ClientError(CatancError):
    """A node cannot register with, or lost, the enforcer (the message says which and why)."""


class Node:
    """One DAG node's trigger loop, run by the thread that registers it.

    ``socket_path`` defaults to ``$CATANC_SOCKET``.  ``timeout_s`` bounds
    registration and each send to the enforcer.  While waiting for a trigger
    the node checks every :attr:`PROBE_S` seconds that the enforcer's socket
    is still alive, and raises :class:`ClientError` if it went away without
    a stop.
    """

    PROBE_S: ClassVar[float] = 1.0

    def __init__(self, name: str, *, socket_path: str | os.PathLike[str] | None = None, timeout_s: float = 5.0) -> None:
        try:
            Welcome(name)
        except ProtocolError as exc:
            raise ClientError(f"bad node name: {exc}") from None
        if socket_path is None:
            from_env = os.environ.get(SOCKET_ENV)
            if not from_env:
                raise ClientError(
                    f"no catanc enforcer socket: {SOCKET_ENV} is not set (`catanc run` sets it for the nodes it "
                    "starts) and no socket_path was given"
                )
            socket_path = from_env
        self.name = name
        self.socket_path = Path(socket_path)
        self.timeout_s = timeout_s
        self.tid: int | None = None
        """The registered thread's native id (set by :meth:`register`)."""
        self.trigger: Trigger | None = None
        """The trigger being worked on (until :meth:`done`)."""
        self._started = 0.0
        self._thread: int | None = None
        self._sock: socket.socket | None = None
        self._enforcer: tuple[int, int] | None = None
        self._hello_sent = False
        self._registered = False
        self._ended = False  # the enforcer stopped or rejected us, or went away
        self._interrupted = False
        self._closed = False
        self._lock = threading.RLock()
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)

    @property
    def registered(self) -> bool:
        """True once the enforcer welcomed this node."""
        return self._registered

    @property
    def stopped(self) -> bool:
        """True once the enforcer said stop, or :meth:`interrupt` was called: :meth:`wait` returns None."""
        return self._ended or self._interrupted

    def register(self) -> None:
        """Register the calling thread as this node; wait up to ``timeout_s`` for the enforcer's welcome."""
        if self._sock is not None or self._closed:
            raise ClientError(f"node {self.name!r} is already registered (or closed): use a new Node")
        self.tid = threading.get_native_id()
        self._thread = threading.get_ident()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            sock.bind("")  # Linux autobind: a unique abstract address the enforcer can answer
            sock.connect(os.fspath(self.socket_path))  # and only the enforcer can send to
            info = self.socket_path.stat()
        except OSError as exc:
            sock.close()
            self.close()
            raise ClientError(self._absent(exc.strerror or str(exc))) from None
        sock.settimeout(self.timeout_s)
        self._sock = sock
        self._enforcer = (info.st_dev, info.st_ino)
        try:
            self._send(Hello(self.name, os.getpid(), self.tid))
            self._hello_sent = True
            deadline = time.monotonic() + self.timeout_s
            while not self.stopped:
                message = self._receive(deadline)
                if message is None:
                    if self.stopped:
                        break  # interrupted while registering
                    raise ClientError(self._absent(f"no answer in {self.timeout_s:g} s"))
                if isinstance(message, Welcome) and message.node == self.name:
                    self._registered = True
                    return
                if isinstance(message, Reject) and message.node == self.name:
                    self._ended = True
                    raise ClientError(
                        f"the catanc enforcer at {self.socket_path} rejected node {self.name!r}: {message.reason}"
                    )
                self._other(message)
        except BaseException:
            self.close()
            raise

    def wait(self, timeout_s: float | None = None) -> Trigger | None:
        """The next trigger; None after ``timeout_s`` seconds, or once :attr:`stopped`.

        A pending run (a trigger without :meth:`done`) is reported as done first.
        """
        self._check_thread("wait")
        if self.trigger is not None:
            self.done()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self.stopped:
            message = self._receive(deadline)
            if message is None:
                return None
            if isinstance(message, Trigger) and message.node == self.name:
                self.trigger = message
                self._started = time.thread_time()
                return message
            if isinstance(message, Reject) and message.node == self.name:
                self._ended = True
                raise ClientError(
                    f"the catanc enforcer at {self.socket_path} dropped node {self.name!r}: {message.reason}"
                )
            self._other(message)
        return None

    def done(self, compute_ms: float | None = None) -> None:
        """Report the current run as finished.

        ``compute_ms`` defaults to this thread's CPU time since the trigger
        arrived (:func:`time.thread_time`), which time spent preempted does
        not inflate.
        """
        self._check_thread("done")
        trigger = self.trigger
        if trigger is None:
            raise ClientError(f"node {self.name!r}: done() without a trigger (call it once per run, after wait())")
        if compute_ms is None:
            compute_ms = (time.thread_time() - self._started) * 1000.0
        assert self.tid is not None  # set by register(), which _check_thread requires
        message = Done(self.name, self.tid, trigger.seq, compute_ms)
        self.trigger = None
        self._send(message)

    def interrupt(self) -> None:
        """End the trigger loop: a blocked :meth:`wait` returns None.  Safe from any thread and from signal handlers."""
        with self._lock:
            self._interrupted = True
            if not self._closed:
                with contextlib.suppress(BlockingIOError):  # the pipe is full: a wake-up is pending anyway
                    os.write(self._wake_w, b"!")

    def close(self) -> None:
        """Leave: say bye unless the enforcer ended the node, and release the socket.  Safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            sock, self._sock = self._sock, None
            if sock is not None:
                if self._hello_sent and not self._ended and self.tid is not None:
                    # If the enforcer is gone or busy, it notices the thread is gone anyway.
                    with contextlib.suppress(OSError):
                        sock.send(Bye(self.name, self.tid).encode(), socket.MSG_DONTWAIT)
                sock.close()
            os.close(self._wake_r)
            os.close(self._wake_w)

    def __enter__(self) -> Self:
        self.register()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[Trigger]:
        while (trigger := self.wait()) is not None:
            yield trigger

    def __repr__(self) -> str:
        return f"Node({self.name!r}, socket_path={os.fspath(self.socket_path)!r}, tid={self.tid})"

    # -- internals ---------------------------------------------------------------

    def _absent(self, reason: str) -> str:
        return f"no catanc enforcer at {self.socket_path} ({reason}): is `catanc run` running?"

    def _check_thread(self, what: str) -> None:
        if self._sock is None or not (self._registered or self.stopped):
            raise ClientError(f"node {self.name!r}: register before {what}() (use `with Node(...) as node:`)")
        if threading.get_ident() != self._thread:
            raise ClientError(
                f"node {self.name!r} is registered by thread {self.tid}: call {what}() from that thread "
                "(it is the thread the enforcer schedules)"
            )

    def _other(self, message: Message) -> None:
        if isinstance(message, Stop):
            self._ended = True
        else:
            log.debug("node %r ignores %r", self.name, message)

    def _send(self, message: Message) -> None:
        assert self._sock is not None
        try:
            self._sock.send(message.encode())
        except OSError as exc:
            self._ended = True
            reason = "it takes no messages" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
            raise ClientError(f"lost the catanc enforcer at {self.socket_path}: {reason}") from None

    def _receive(self, deadline: float | None) -> Message | None:
        """The next message from the enforcer, or None at the deadline or on interrupt."""
        sock = self._sock
        assert sock is not None
        poller = select.poll()
        poller.register(sock, select.POLLIN)
        poller.register(self._wake_r, select.POLLIN)
        while True:
            if self._interrupted:
                return None
            wait_s = self.PROBE_S
            if deadline is not None:
                wait_s = min(wait_s, max(deadline - time.monotonic(), 0.0))
            ready = {fd for fd, _ in poller.poll(wait_s * 1000.0)}
            if self._wake_r in ready:
                with contextlib.suppress(BlockingIOError):  # raised once drained
                    while os.read(self._wake_r, 64):
                        pass
                continue
            if sock.fileno() in ready:
                try:
                    data = sock.recv(MAX_DATAGRAM + 1, socket.MSG_DONTWAIT)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    self._ended = True
                    reason = exc.strerror or str(exc)
                    raise ClientError(f"lost the catanc enforcer at {self.socket_path}: {reason}") from None
                try:
                    return decode(data)
                except ProtocolError as exc:
                    log.warning("node %r dropped a bad datagram from the enforcer: %s", self.name, exc)
                    continue
            if deadline is not None and time.monotonic() >= deadline:
                return None
            if not ready and not self._enforcer_alive():
                self._ended = True
                raise ClientError(
                    f"lost the catanc enforcer at {self.socket_path}: it went away without stopping node {self.name!r}"
                )

    def _enforcer_alive(self) -> bool:
        try:
            info = self.socket_path.stat()
        except OSError:
            return False
        if (info.st_dev, info.st_ino) != self._enforcer:
            return False  # a new enforcer: this registration belonged to the old one
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            probe.connect(os.fspath(self.socket_path))
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
    message = SetCores(cores).encode()
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        try:
            sock.sendto(message, path)
        except OSError as exc:
            raise ClientError(f"no catanc enforcer at {path}: {exc.strerror or exc}") from None
