"""ROS 2 nodes (rclpy) under ``catanc run``: one changed line per callback.

::

    from catanc import ros as catanc_ros          # or: import catanc_ros (the copied file)

    # instead of self.create_timer(period_s, self.tick):
    self.timer = catanc_ros.create_timer(self, period_s, self.tick)
    # a node that runs on its input (later in a subchain): wrap the callback
    self.create_subscription(Image, "image", catanc_ros.reported(self, self.on_image), qos)

Without ``$CATANC_SOCKET`` (no ``catanc run``) :func:`create_timer` *is* ``node.create_timer``
and :func:`reported` returns the callback itself: the node runs as plain ROS 2.

Under ``catanc run``:

- :func:`create_timer`: the callback runs in the executor's own thread when catanc triggers
  the DAG node, and the run is reported when it returns.  The executor thread registers (it is
  the thread the enforcer pins and prioritises): a guard condition of the node fires once at
  the first spin to register, and a small watcher thread, started by the executor thread once
  it is placed, waits on the client's socket (:meth:`catanc.client.Node.fd`) and fires the
  guard condition when a trigger arrives; the executor then takes it (``wait(0)``) and runs the
  callback.  When the enforcer stops, dies (noticed within :data:`PROBE_S`), rejects the name,
  or cannot be reached, the node goes on as a plain rclpy timer at ``period_s`` after one log
  line (``on_loss="timer"``), or shuts its context down (``on_loss="exit"``).
- :func:`reported`: each call of the callback is a run of its DAG node, reported with the
  message's ``header.stamp`` (when it has one) as the run's origin.  It registers at the first
  spin (before the first message; at the latest in the first message's callback), saying it
  runs on its input, so no node sends it triggers.
- A run's compute time is its executor thread's CPU since that thread's previous run of a DAG node ended
  (:class:`_ThreadCpu`), not only its callback's: the executor's own work to take, deserialise and start it
  (and to go back to waiting after the run before) is CPU on the node's core that the plan must budget, a
  node's cost of receiving its input (docs/explanation/model.md section 5).  The first run on a thread counts
  its callback only.
- ``name`` defaults to the ROS node's ``catan.node`` parameter (declared if it is not).
- The executor must run every callback of a DAG node in one thread: a
  ``SingleThreadedExecutor`` (``rclpy.spin``), one per thread.  A ``MultiThreadedExecutor``
  gets a :class:`CatancRosError` saying so.
- ``rclpy.shutdown()`` and Ctrl-C: the context's shutdown leaves catanc (bye) and stops the
  watcher; no callback runs after it.  A context that rclpy's signal handler shut down (SIGTERM, or
  SIGINT where Python ignores it) is noticed within :data:`PROBE_S` and the executor woken again.

This file imports rclpy and catanc's standalone client only (Python 3.8+).  To use it without
catanc installed, copy it next to the client: ``cp "$(catanc client --ros)" catanc_ros.py`` and
``cp "$(catanc client --python)" catanc_client.py`` (``client.py`` works too), then
``import catanc_ros``.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, TypeVar

try:
    import rclpy
    from rclpy.executors import MultiThreadedExecutor
except ImportError as _missing:
    raise ImportError(
        f"catanc.ros needs ROS 2's rclpy, which cannot be imported here ({_missing}): "
        'pip install "catanc[ros]" (or source a ROS 2 installation)'
    ) from _missing

if __package__:  # catanc.ros, inside the installed package
    from .client import SOCKET_ENV, ClientError
    from .client import Node as _Client
else:  # a copied catanc_ros.py next to a copied catanc_client.py (or client.py)
    try:
        from catanc_client import SOCKET_ENV, ClientError  # type: ignore[no-redef,import-not-found,unused-ignore]
        from catanc_client import Node as _Client  # type: ignore[no-redef,import-not-found,unused-ignore]
    except ImportError:
        from client import SOCKET_ENV, ClientError  # type: ignore[no-redef,import-not-found,unused-ignore]
        from client import Node as _Client  # type: ignore[no-redef,import-not-found,unused-ignore]

__all__ = ["NAME_PARAMETER", "CatancRosError", "CatancTimer", "create_timer", "reported"]

NAME_PARAMETER = "catan.node"
"""The ROS parameter naming the DAG node a ROS node hosts (params.yaml carries it)."""
PROBE_S = 0.25
"""How often the watcher checks that the enforcer is still there (a killed one sends no stop)."""
ON_LOSS = ("timer", "exit")

T = TypeVar("T")


class CatancRosError(RuntimeError):
    """A ROS node is set up in a way catanc cannot schedule (the message says what works)."""


def _dag_name(node: Any, name: str | None) -> str:
    """``name``, or the node's ``catan.node`` parameter (declared empty if it was not)."""
    if name is not None:
        return name
    if not node.has_parameter(NAME_PARAMETER):
        node.declare_parameter(NAME_PARAMETER, "")
    value = node.get_parameter(NAME_PARAMETER).value
    return value if isinstance(value, str) else ""


def _stamp_ns(message: Any) -> int | None:
    """A message's ``header.stamp`` in ns (CLOCK_REALTIME in ROS), or None if it has none."""
    stamp = getattr(getattr(message, "header", None), "stamp", None)
    try:
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)  # type: ignore[union-attr]
    except (AttributeError, TypeError, ValueError):
        return None
    return ns if ns > 0 else None


def _check_executor(node: Any, dag: str) -> None:
    if isinstance(node.executor, MultiThreadedExecutor):
        raise CatancRosError(
            f"catanc: ROS node {node.get_name()!r} (DAG node {dag!r}) is spun by a MultiThreadedExecutor, which "
            "runs callbacks in any of its threads; catanc schedules the one thread that runs a DAG node. Spin it "
            "with a SingleThreadedExecutor (rclpy.spin), one per thread if the process needs several."
        )


class _ThreadCpu:
    """The calling thread's CPU time (``time.thread_time``) when its last run of a DAG node ended, per thread.

    Between two runs an executor thread blocks (no CPU) or does the executor's own work for them: back to
    its wait set after a run, then taking, deserialising and dispatching the next one.  That work runs on
    the node's core at its level, so a run is charged with it: its compute is the thread's CPU from the end
    of the run before (or its callback's start, the first time) to its own end.
    """

    _local = threading.local()

    @classmethod
    def since(cls) -> float:
        """Where the calling thread's current run counts its CPU from."""
        now = time.thread_time()
        last = getattr(cls._local, "end", None)
        return now if last is None or last > now else last

    @classmethod
    def spent_ms(cls, since: float) -> float:
        """The calling thread's CPU since ``since``, in ms; the current run ends now (the next counts from here)."""
        now = time.thread_time()
        cls._local.end = now
        return max(now - since, 0.0) * 1000.0


class _ShutdownWatch:
    """Wakes a context's executors once rclpy's signal handler has shut the context down.

    On SIGINT or SIGTERM rclpy's own handler thread first wakes the executors (a guard condition), then
    shuts the context down (in C, without Python's ``on_shutdown`` callbacks).  An executor thread that
    catanc raised to SCHED_FIFO on the same CPU takes the wake-up in between, finds the context still up
    and waits again; a node that runs on its input then sleeps until its next message, which never
    comes once the app is stopping (a timer node is woken by its triggers or timer).  This thread, one
    per context, at the process's own level, looks every :data:`PROBE_S` and wakes them again.
    """

    _lock: ClassVar[threading.Lock] = threading.Lock()
    _by_context: ClassVar[dict[int, _ShutdownWatch]] = {}

    def __init__(self, context: Any) -> None:
        self.context = context
        self.registrations: list[_Registration] = []
        self.thread = threading.Thread(target=self._watch, name="catanc-shutdown", daemon=True)

    @classmethod
    def add(cls, registration: _Registration) -> None:
        context = registration.node.context
        with cls._lock:
            watch = cls._by_context.get(id(context))
            if watch is None:
                watch = cls._by_context[id(context)] = cls(context)
                watch.thread.start()
            watch.registrations.append(registration)

    def _watch(self) -> None:
        try:
            while self.context.ok():
                time.sleep(PROBE_S)
        except Exception:  # the context was destroyed under the watch: nothing is left to wake
            return
        finally:
            with self._lock:
                if self._by_context.get(id(self.context)) is self:
                    del self._by_context[id(self.context)]
        for registration in list(self.registrations):
            registration.woken_after_shutdown()


class _Registration:
    """A DAG node's client, registered from the executor thread at the first spin (a guard condition)."""

    def __init__(
        self,
        node: Any,
        name: str | None,
        *,
        on_input: bool,
        callback_group: Any,
        on_guard: Callable[[], None] | None = None,
    ) -> None:
        self.node = node
        self.name = _dag_name(node, name)
        self.on_input = on_input
        self.client: _Client | None = None
        self.thread: int | None = None
        self.failed = False  # no enforcer for this node: it runs on its own (after one log line)
        self.closed = False
        self.lock = threading.RLock()  # held through a run: a shutdown from another thread waits for its report
        self.guard = node.create_guard_condition(on_guard or self._on_guard, callback_group=callback_group)
        node.context.on_shutdown(self.close)
        _ShutdownWatch.add(self)
        self.guard.trigger()  # registers at the first spin, in the executor's thread

    def _on_guard(self) -> None:
        self.register()

    def register(self) -> bool:
        """Register the calling (executor) thread once; False where the node runs without the enforcer."""
        if self.client is not None or self.failed or self.closed:
            return self.client is not None
        _check_executor(self.node, self.name or "?")
        logger = self.node.get_logger()
        if not self.name:
            logger.error(
                f"catanc: ROS node {self.node.get_name()!r} names no DAG node: set its {NAME_PARAMETER!r} parameter "
                "(params.yaml) or pass name=; it runs on its own, unscheduled"
            )
            self.failed = True
            return False
        try:
            client = _Client(self.name, on_input=self.on_input, quiet=True)
            client.register()
        except ClientError as exc:
            logger.error(f"catanc: ROS node {self.node.get_name()!r}: {exc}; it runs on its own, unscheduled")
            self.failed = True
            return False
        self.client = client
        self.thread = threading.get_ident()
        return True

    def check_thread(self) -> None:
        if threading.get_ident() != self.thread:
            _check_executor(self.node, self.name)
            raise CatancRosError(
                f"catanc: DAG node {self.name!r} of ROS node {self.node.get_name()!r} was registered by another thread "
                "than the one running its callback now: spin its node in one SingleThreadedExecutor"
            )

    def holds(self, client: _Client) -> bool:
        """Whether ``client`` is still this node's (not closed by a shutdown meanwhile)."""
        return self.client is client

    def woken_after_shutdown(self) -> None:
        """The context is down (rclpy's signal handler): leave catanc, and wake the executor to see it."""
        self.close()
        with contextlib.suppress(Exception):  # the guard condition is gone already: so is the executor's wait
            self.guard.trigger()

    def close(self) -> None:
        """Leave catanc (a bye), once; from the context's shutdown too."""
        with self.lock:
            if self.closed:
                return
            self.closed = True
            client, self.client = self.client, None
        if client is not None:
            client.interrupt()
            client.close()


class CatancTimer:
    """What :func:`create_timer` returns under ``catanc run``: the DAG node's triggered callback, then (once the
    enforcer is gone) a plain rclpy timer, :attr:`timer`.  ``cancel()`` and ``destroy()`` end both."""

    def __init__(
        self, node: Any, period_s: float, callback: Callable[[], Any], *, name: str | None, group: Any, on_loss: str
    ) -> None:
        self.node = node
        self.period_s = period_s
        self.callback = callback
        self.callback_group = group
        self.on_loss = on_loss
        self.timer: Any | None = None
        """The plain rclpy timer the node runs on once it has no enforcer (None until then)."""
        self._canceled = False
        self._taken = threading.Event()
        self._watcher: threading.Thread | None = None
        self._registration = _Registration(node, name, on_input=False, callback_group=group, on_guard=self._on_guard)

    @property
    def timer_period_ns(self) -> int:
        return int(self.period_s * 1e9)

    def is_canceled(self) -> bool:
        return self._canceled

    def cancel(self) -> None:
        self._canceled = True
        self._registration.close()
        if self.timer is not None:
            self.timer.cancel()

    def destroy(self) -> None:
        self.cancel()
        if self.timer is not None:
            self.node.destroy_timer(self.timer)
            self.timer = None
        self.node.destroy_guard_condition(self._registration.guard)

    # -- in the executor's thread ----------------------------------------------------

    def _on_guard(self) -> None:
        """The guard condition: register (first), or take and run what arrived, or fall back."""
        registration = self._registration
        try:
            if self._canceled or self.timer is not None or registration.closed:
                return
            if registration.client is None:
                if registration.register():
                    self._start_watcher()
                else:
                    self._fall_back(None)
                return
            registration.check_thread()
            self._take()
        finally:
            self._taken.set()

    def _take(self) -> None:
        registration = self._registration
        client = registration.client
        if client is None:
            return
        context = self.node.context
        while context.ok():
            with registration.lock:
                if not registration.holds(client):
                    return  # closed: the context shut down
                trigger = client.wait(0)
                if trigger is None:
                    break
                since = _ThreadCpu.since()
                try:
                    self.callback()
                finally:
                    if registration.holds(client):  # unless the callback shut the context down
                        client.done(_ThreadCpu.spent_ms(since))
        if client.stopped and not registration.closed:
            self._fall_back(client.lost or "the enforcer stopped")

    def _fall_back(self, why: str | None) -> None:
        self._registration.close()
        if not self.node.context.ok():
            return
        logger = self.node.get_logger()
        if self.on_loss == "exit":
            if why is not None:
                logger.warning(f"catanc: DAG node {self._registration.name!r}: {why}; shutting down (on_loss='exit')")
            try:
                rclpy.try_shutdown(context=self.node.context)
            except RuntimeError:  # rclpy's signal thread shut it down between try_shutdown's check and its shutdown
                if self.node.context.ok():
                    raise
            return
        if why is not None:
            logger.warning(
                f"catanc: DAG node {self._registration.name!r}: {why}; it runs on its own timer every "
                f"{self.period_s:g} s"
            )
        self.timer = self.node.create_timer(self.period_s, self.callback, callback_group=self.callback_group)

    def _start_watcher(self) -> None:
        """Started by the executor thread once it is registered and placed, so the watcher inherits its CPUs
        and SCHED_FIFO level (a trigger must not wait for the CPU behind the subchain it starts)."""
        client = self._registration.client
        assert client is not None
        deadline = time.monotonic() + 1.0
        while not getattr(client, "routed", True) and time.monotonic() < deadline:
            trigger = client.wait(0.01)  # the route comes once the enforcer placed the thread
            if trigger is not None:
                self.callback()
                client.done()
        self._watcher = threading.Thread(target=self._watch, name=f"catanc-{client.name}", daemon=True)
        self._watcher.start()

    # -- in the watcher thread -------------------------------------------------------

    def _watch(self) -> None:
        """Fire the guard condition when a datagram waits, and once the enforcer is gone; then wait until the
        executor took it (the socket stays readable until then)."""
        registration = self._registration
        client = registration.client
        fd = None if client is None else client.fd()
        if client is None or fd is None:
            return
        _name_thread(f"catanc-{client.name}")  # the enforcer raises and pins it with the executor thread
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        try:
            while not registration.closed:
                ready = poller.poll(PROBE_S * 1000.0)
                if registration.closed:
                    return
                if not ready and client.alive():
                    continue
                self._taken.clear()
                self._registration.guard.trigger()
                while not self._taken.wait(PROBE_S):
                    if registration.closed or not self.node.context.ok():
                        return
                if client.stopped:
                    return
        except Exception:  # the context shut down under the watcher: nothing to wake any more
            return


def _name_thread(name: str) -> None:
    """The calling thread's name in /proc (its first 15 bytes): ``catanc-<node>`` tells the enforcer it serves the
    node's thread (catanc.runtime.enforcer.nodes)."""
    with contextlib.suppress(OSError):
        Path(f"/proc/self/task/{threading.get_native_id()}/comm").write_text(name.encode()[:15].decode(errors="ignore"))


def create_timer(
    node: Any,
    period_s: float,
    callback: Callable[[], Any],
    *,
    name: str | None = None,
    callback_group: Any = None,
    on_loss: str = "timer",
) -> Any:
    """``node.create_timer(period_s, callback)`` that catanc triggers under ``catanc run`` (see the module)."""
    if on_loss not in ON_LOSS:
        raise ValueError(f"on_loss is 'timer' or 'exit', not {on_loss!r}")
    if not os.environ.get(SOCKET_ENV):
        return node.create_timer(period_s, callback, callback_group=callback_group)
    return CatancTimer(node, period_s, callback, name=name, group=callback_group, on_loss=on_loss)


def reported(node: Any, callback: Callable[[T], Any], *, name: str | None = None) -> Callable[[T], Any]:
    """``callback`` (a subscription's), each call reported as a run of its DAG node under ``catanc run``."""
    if not os.environ.get(SOCKET_ENV):
        return callback
    registration = _Registration(node, name, on_input=True, callback_group=None)

    def run(message: T) -> Any:
        if registration.client is None and not registration.register():
            return callback(message)
        client = registration.client
        if client is None:  # closed: the context is shutting down
            return callback(message)
        registration.check_thread()
        with registration.lock:
            if not registration.holds(client):
                return callback(message)
            since = _ThreadCpu.since()
            client.begin(_stamp_ns(message))
            try:
                return callback(message)
            finally:
                if registration.holds(client):  # unless the callback shut the context down
                    client.done(_ThreadCpu.spent_ms(since))

    return run
