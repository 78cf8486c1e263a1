"""The trigger protocol between ``catanc run`` (the enforcer) and app nodes.

App nodes know nothing about cores or rates: a node thread registers, waits
for its trigger, runs once, and reports completion.  The enforcer decides
when each node runs and on which cores its thread may run.

Transport: Unix datagram sockets (``AF_UNIX``, ``SOCK_DGRAM``), one JSON
object per datagram, UTF-8, at most :data:`MAX_DATAGRAM` bytes, always with
``"v": 1`` and a ``"type"``.  The enforcer binds a socket at a filesystem
path and passes it to nodes in the environment variable ``CATANC_SOCKET``.
Each node thread binds its own socket with Linux autobind (``bind("")``: a
unique abstract address), so the enforcer answers the datagram's sender.

Messages (JSON on the wire; the dataclasses below)::

    node -> enforcer   {"v":1,"type":"hello","node":"LM","pid":4242,"tid":4245}
                       {"v":1,"type":"done","node":"LM","tid":4245,"seq":17,"compute_ms":3.2}
                       {"v":1,"type":"bye","node":"LM","tid":4245}
    enforcer -> node   {"v":1,"type":"welcome","node":"LM"}
                       {"v":1,"type":"trigger","node":"LM","seq":17,"threads":1}
                       {"v":1,"type":"reject","node":"LM","reason":"unknown node 'LM'"}
                       {"v":1,"type":"stop"}
    anyone -> enforcer {"v":1,"type":"set_cores","cores":3}

``compute_ms`` may be ``null`` (the node does not measure itself).  A
trigger's ``threads`` (optional, 1 when absent) is how many threads the plan
gives the run: a multi-threaded node spreads its work over that many and
reports the run's time; the enforcer multiplies it by the spec's speedup for
those threads to get back the one-thread time the planner budgets.  Field
rules, checked when a message is built or decoded: node names are 1 to
:data:`MAX_NAME` printable characters; ``pid``, ``tid`` and ``cores`` are
positive integers (``threads`` too) and ``seq`` a non-negative one (all below 2**63);
``compute_ms`` is a finite number >= 0 or null; a reject's ``reason`` is
shortened so that the datagram fits.  Unknown fields are refused: a change
of shape is a new version.

Only the standard library is used here: :mod:`catanc.client`, which app
nodes import, builds on this module.
"""

from __future__ import annotations

import errno
import functools
import json
import logging
import math
import os
import socket
import stat
import time
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, Self

from catanc.errors import CatancError, ExitCode

VERSION = 1
"""The protocol version every message carries as ``"v"``."""

SOCKET_ENV = "CATANC_SOCKET"
"""The environment variable naming the enforcer's socket path."""

MAX_DATAGRAM = 1024
"""The largest datagram, in bytes, that is sent or accepted."""

MAX_NAME = 128
"""The longest node name, in characters."""

STOP_GRACE_S = 2.0
"""After a Stop, how long the enforcer keeps its socket open for the done messages of runs still
going: a node in the middle of a run when the run ends reports it before its loop ends."""

_MAX_INT = 2**63 - 1

Address = str | bytes | None
"""A datagram sender: a path, an abstract address (bytes), or None for an unbound socket (cannot be answered)."""

log = logging.getLogger(__name__)


class ProtocolError(CatancError, ValueError):
    """A datagram or message that breaks the protocol (the message says how)."""

    exit_code = ExitCode.BAD_INPUT


class SocketPathError(CatancError):
    """The enforcer's socket cannot be bound at the given path."""

    exit_code = ExitCode.BAD_INPUT


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_name(kind: str, value: object) -> str:
    if not isinstance(value, str) or not 1 <= len(value) <= MAX_NAME or not value.isprintable():
        raise ProtocolError(f"{kind}.node: a node name is 1 to {MAX_NAME} printable characters, got {_show(value)}")
    return value


def _check_int(kind: str, field: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= _MAX_INT:
        what = "a positive" if minimum > 0 else "a non-negative"
        raise ProtocolError(f"{kind}.{field}: expected {what} integer, got {_show(value)}")
    return value


@dataclass(frozen=True)
class _Message:
    TYPE: ClassVar[str] = ""

    def _body(self) -> dict[str, Any]:
        body: dict[str, Any] = {"v": VERSION, "type": self.TYPE}
        for name in FIELD_NAMES[self.TYPE]:
            body[name] = getattr(self, name)
        return body

    def _raw(self) -> bytes:
        return json.dumps(self._body(), ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode("utf-8")

    def encode(self) -> bytes:
        """This message as one datagram (compact JSON, UTF-8)."""
        data = self._raw()
        if len(data) > MAX_DATAGRAM:  # pragma: no cover - field checks keep every message smaller
            raise ProtocolError(f"{self.TYPE}: {len(data)} bytes encoded; a datagram holds at most {MAX_DATAGRAM}")
        return data


@dataclass(frozen=True)
class Hello(_Message):
    """Node -> enforcer: thread ``tid`` of process ``pid`` registers as DAG node ``node``."""

    TYPE: ClassVar[str] = "hello"
    node: str
    pid: int
    tid: int

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)
        _check_int(self.TYPE, "pid", self.pid, 1)
        _check_int(self.TYPE, "tid", self.tid, 1)


@dataclass(frozen=True)
class Done(_Message):
    """Node -> enforcer: finished the run triggered with ``seq``; ``compute_ms`` is the node's own measurement."""

    TYPE: ClassVar[str] = "done"
    node: str
    tid: int
    seq: int
    compute_ms: float | None

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)
        _check_int(self.TYPE, "tid", self.tid, 1)
        _check_int(self.TYPE, "seq", self.seq, 0)
        value: object = self.compute_ms
        if value is None:
            return
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
            raise ProtocolError(f"done.compute_ms: expected a finite number >= 0 or null, got {_show(value)}")
        object.__setattr__(self, "compute_ms", float(value))


@dataclass(frozen=True)
class Bye(_Message):
    """Node -> enforcer: the thread leaves (it will not answer triggers any more)."""

    TYPE: ClassVar[str] = "bye"
    node: str
    tid: int

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)
        _check_int(self.TYPE, "tid", self.tid, 1)


@dataclass(frozen=True)
class Welcome(_Message):
    """Enforcer -> node: the registration of ``node`` is accepted."""

    TYPE: ClassVar[str] = "welcome"
    node: str

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)


@dataclass(frozen=True)
class Trigger(_Message):
    """Enforcer -> node: run once now; answer with a :class:`Done` carrying the same ``seq``.

    ``threads`` is how many threads the plan gives this run (Eq. 1's q, where the node's
    speedup gains from more than one; optional in a datagram, 1 when absent).
    """

    TYPE: ClassVar[str] = "trigger"
    node: str
    seq: int
    threads: int = 1

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)
        _check_int(self.TYPE, "seq", self.seq, 0)
        _check_int(self.TYPE, "threads", self.threads, 1)


@functools.lru_cache(maxsize=1024)  # an app has tens of nodes
def _trigger_parts(node: str, threads: int) -> tuple[bytes, bytes]:
    """A trigger's bytes before and after its ``seq``, made once per node and thread count."""
    probe = json.dumps(
        {"v": VERSION, "type": Trigger.TYPE, "node": node, "seq": 0, "threads": threads},
        ensure_ascii=False,
        separators=(",", ":"),
    ).encode("utf-8")
    before, after = probe.rsplit(b'"seq":0,', 1)
    return before + b'"seq":', b"," + after


def trigger_datagram(node: str, seq: int, threads: int = 1) -> bytes:
    """``Trigger(node, seq, threads).encode()`` without building a message or JSON per call.

    The enforcer sends hundreds of triggers a second, and encoding each through ``json``
    was a tenth of its CPU; the bytes are the same (a property test holds them to it).
    """
    before, after = _trigger_parts(node, threads)
    return before + str(seq).encode("ascii") + after


@dataclass(frozen=True)
class Reject(_Message):
    """Enforcer -> node: the registration of ``node`` is refused, and why.

    A reason too long for one datagram is shortened (ending in ``...``) when
    the message is built, so every reject can be sent.
    """

    TYPE: ClassVar[str] = "reject"
    node: str
    reason: str

    def __post_init__(self) -> None:
        _check_name(self.TYPE, self.node)
        if not isinstance(self.reason, str):
            raise ProtocolError(f"reject.reason: expected a string, got {_show(self.reason)}")
        try:
            self.reason.encode("utf-8")
        except UnicodeEncodeError:
            raise ProtocolError("reject.reason: not encodable as UTF-8 (a lone surrogate?)") from None
        while (excess := len(self._raw()) - MAX_DATAGRAM) > 0:
            # Each character takes at least one byte, so cutting `excess` more characters makes room.
            keep = max(len(self.reason) - excess - 3, 0)
            object.__setattr__(self, "reason", self.reason[:keep] + "...")


@dataclass(frozen=True)
class Stop(_Message):
    """Enforcer -> node: the enforcer is shutting down; leave the trigger loop."""

    TYPE: ClassVar[str] = "stop"


@dataclass(frozen=True)
class SetCores(_Message):
    """Control -> enforcer: plan for ``cores`` cores from now on."""

    TYPE: ClassVar[str] = "set_cores"
    cores: int

    def __post_init__(self) -> None:
        _check_int(self.TYPE, "cores", self.cores, 1)


Message = Hello | Done | Bye | Welcome | Trigger | Reject | Stop | SetCores
"""Any protocol message."""

MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Done, Bye, Welcome, Trigger, Reject, Stop, SetCores)
}
"""Message classes by their ``"type"``."""

FIELD_NAMES: dict[str, tuple[str, ...]] = {
    kind: tuple(field.name for field in fields(cls)) for kind, cls in MESSAGE_TYPES.items()
}
"""Each message type's fields, in order (looked up once: the enforcer decodes hundreds of datagrams a second)."""

REQUIRED_FIELDS: dict[str, frozenset[str]] = {
    kind: frozenset(f.name for f in fields(cls) if f.default is MISSING) for kind, cls in MESSAGE_TYPES.items()
}
"""The fields a datagram must carry; the others have defaults."""


def decode(data: bytes) -> Message:
    """Parse and check one datagram; raise :class:`ProtocolError` (and nothing else) if it is not a message."""
    if len(data) > MAX_DATAGRAM:
        raise ProtocolError(f"a datagram of {len(data)}+ bytes; at most {MAX_DATAGRAM} are accepted")
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"not UTF-8 (byte {exc.start})") from None
    try:
        body = json.loads(text)
    except (ValueError, RecursionError) as exc:
        reason = exc.msg if isinstance(exc, json.JSONDecodeError) else str(exc)
        raise ProtocolError(f"not JSON: {reason}") from None
    if not isinstance(body, dict):
        raise ProtocolError(f"a message is a JSON object, got {type(body).__name__}")
    version = body.pop("v", None)
    if version is None:
        raise ProtocolError(f'no protocol version: a message carries "v": {VERSION}')
    if isinstance(version, bool) or not isinstance(version, int) or version != VERSION:
        raise ProtocolError(f"protocol version {_show(version)}; this catanc speaks version {VERSION}")
    kind = body.pop("type", None)
    cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        known = ", ".join(MESSAGE_TYPES)
        what = "no message type" if kind is None else f"unknown message type {_show(kind)}"
        raise ProtocolError(f"{what} (expected one of: {known})")
    names = FIELD_NAMES[cls.TYPE]
    missing = [name for name in names if name in REQUIRED_FIELDS[cls.TYPE] and name not in body]
    if missing:
        raise ProtocolError(f"{cls.TYPE}: missing field(s): {', '.join(missing)}")
    unknown = sorted(name for name in body if name not in names)
    if unknown:
        listed = ", ".join(_show(name) for name in unknown[:5])
        raise ProtocolError(f"{cls.TYPE}: unknown field(s): {listed} (expected: {', '.join(names) or 'none'})")
    return cls(**body)


class EnforcerSocket:
    """The enforcer's end: a datagram socket bound at ``path``.

    Binding removes a stale socket file left by a crashed enforcer, but
    refuses to touch anything else at ``path``: a file that is not a socket,
    or the socket of an enforcer that is still running.  :meth:`receive`
    skips datagrams that are not messages (logging them and counting them in
    :attr:`dropped`), so garbage never reaches the caller.  :meth:`close`
    removes the socket file if it is still this socket's.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.dropped = 0
        _remove_stale_socket(self.path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self._sock.bind(os.fspath(self.path))
            info = self.path.stat()
        except OSError as exc:
            self._sock.close()
            reason = exc.strerror or str(exc)
            raise SocketPathError(f"cannot bind the enforcer's socket at {self.path}: {reason}") from None
        self._identity: tuple[int, int] | None = (info.st_dev, info.st_ino)

    def fileno(self) -> int:
        """The socket's file descriptor, for ``selectors``."""
        return self._sock.fileno()

    def receive(self, timeout_s: float | None) -> tuple[Message, Address] | None:
        """The next message and its sender, or None if none arrives within ``timeout_s`` (None: wait forever)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            self._sock.settimeout(remaining)
            try:
                data, sender = self._sock.recvfrom(MAX_DATAGRAM + 1)
            except (TimeoutError, BlockingIOError):  # BlockingIOError: timeout_s == 0
                return None
            try:
                return decode(data), sender
            except ProtocolError as exc:
                self.dropped += 1
                log.warning("dropped a datagram from %r: %s", sender, exc)

    def send(self, message: Message, address: Address) -> bool:
        """Send without blocking; False if the receiver is gone, unbound, or not taking datagrams."""
        return self.send_bytes(message.encode(), address)

    def send_bytes(self, datagram: bytes, address: Address) -> bool:
        """:meth:`send` for an already encoded message (see :func:`trigger_datagram`)."""
        if address is None:
            return False
        try:
            self._sock.sendto(datagram, socket.MSG_DONTWAIT, address)
        except OSError as exc:
            log.debug("could not send %r to %r: %s", datagram[:60], address, exc)
            return False
        return True

    def close(self) -> None:
        """Close the socket and remove its file (if no one has replaced it since); safe to call twice."""
        self._sock.close()
        identity, self._identity = self._identity, None
        if identity is None:
            return
        try:
            info = self.path.lstat()
            if (info.st_dev, info.st_ino) == identity:
                self.path.unlink()
        except FileNotFoundError:
            pass

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


def _remove_stale_socket(path: Path) -> None:
    try:
        info = path.lstat()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise SocketPathError(f"cannot use {path} for the enforcer's socket: {exc.strerror or exc}") from None
    if not stat.S_ISSOCK(info.st_mode):
        raise SocketPathError(f"{path} exists and is not a socket: refusing to replace it with the enforcer's socket")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        probe.connect(os.fspath(path))
    except OSError as exc:
        if exc.errno not in (errno.ECONNREFUSED, errno.ENOENT):
            raise SocketPathError(f"cannot check the socket at {path}: {exc.strerror or exc}") from None
    else:
        raise SocketPathError(f"another catanc enforcer is running at {path} (its socket answers)")
    finally:
        probe.close()
    log.info("removing the stale socket %s", path)
    path.unlink(missing_ok=True)
