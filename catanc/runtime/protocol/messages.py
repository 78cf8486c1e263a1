"""The trigger protocol between ``catanc run`` (the enforcer) and app nodes, version ``catanc/2``.

This docstring is the protocol's reference (docs/reference/protocol.md says the same, held to
this code by a test): a client in any language that follows it is a catanc node.
:mod:`catanc.client` is the Python client (standard library only) and
``catanc/include/catanc/client.hpp`` the C++ one (``catanc client --cflags``).

Sockets
=======
Unix datagram sockets (``AF_UNIX``, ``SOCK_DGRAM``).  The enforcer binds its socket at a
filesystem path and gives it to the nodes it starts in ``$CATANC_SOCKET``.  Each node thread
makes its own socket and binds it with Linux autobind (``bind`` with an empty address, i.e.
``addrlen = sizeof(sa_family_t)``): the kernel gives it a unique abstract address, which the
enforcer answers and tells other nodes.  A node never ``connect``s: it receives from the
enforcer *and* from its predecessor in its subchain.

Datagrams
=========
One message per datagram, ASCII text, at most :data:`MAX_DATAGRAM` bytes, no trailing newline:
words separated by one space, the first always ``catanc/2`` (the protocol and its version).
Node names are identifiers (``[A-Za-z_][A-Za-z0-9_]*``, at most :data:`MAX_NAME` characters);
numbers are decimal integers; an address is the hexadecimal of a socket's ``sun_path`` bytes as
``getsockname`` returns them (an autobound one is a NUL and five hex digits, so ``003030306131``
for ``"\\0""000a1"``); ``-`` stands for "none".  Unknown message types are
ignored by both sides (so later versions may add some); a datagram whose first word is not
``catanc/2`` is not for this version.

Node -> enforcer (sent to the path in ``$CATANC_SOCKET``)::

    catanc/2 hello NODE PID TID       thread TID of process PID registers as NODE
    catanc/2 hello NODE PID TID input ... as NODE, which runs on its input (a ROS subscription):
                                      no node sends it triggers, its message wakes it
    catanc/2 bye NODE TID             the thread leaves NODE (it takes no more triggers)
    catanc/2 done NODE TID SEQ        run SEQ is over; only when the route asks for it (NOTIFY 1)

Anyone -> enforcer: ``catanc/2 set_cores N`` (plan for N cores; only root or the enforcer's
user may).

Enforcer -> node (each from the node's own *enforcer address*, the sender of its welcome)::

    catanc/2 welcome NODE SLOTS       registered; carries the node's ring (SCM_RIGHTS, one fd)
    catanc/2 route NODE NOTIFY NEXT NEXT_THREADS NEXT_ADDR PREV_ADDR
                                      NEXT_ADDR ``-`` with a NEXT named: NEXT runs on its
                                      input (its hello said ``input``): send it no trigger
    catanc/2 trigger NODE SEQ THREADS run once now, on THREADS threads (run SEQ of its subchain)
    catanc/2 reject NODE REASON...    refused (registration) or dropped; REASON is the rest
    catanc/2 stop                     the enforcer ends: leave the trigger loop

Node -> node: when a run ends, the node sends ``catanc/2 trigger NEXT SEQ NEXT_THREADS`` to
``NEXT_ADDR`` (its route's), with the run's SEQ: only the head of a subchain is triggered by the
enforcer; each later node is woken by the one before it.  A node accepts triggers from its
enforcer address and from its route's ``PREV_ADDR`` only, and everything else from its enforcer
address only (a reject may come from the enforcer's path, before the welcome).  It sends every
datagram with ``MSG_DONTWAIT`` and carries on if a send fails.

A route arrives after the welcome and again whenever it changes (a neighbour registers or
leaves).  ``NOTIFY`` 1 asks the node to send ``done`` after each run (a driver that triggers
every node itself, as ``catanc bench``'s baselines do); ``catanc run`` says 0: completions
reach it through the ring alone, without a wake-up per run.

The ring
========
Each registration gets a ring: a sealed ``memfd`` (it can neither grow nor shrink) passed with
the welcome, ``mmap``-ed read-write by the node, read-only by the enforcer.  The node appends
one entry per run, which the enforcer reads at its slot switches.  Host byte order, naturally
aligned: :mod:`catanc.runtime.protocol.ring` holds the layout (header, then ``SLOTS`` entries).

A client, step by step
======================
1. ``socket(AF_UNIX, SOCK_DGRAM)``, autobind it, and from the thread that will run the node's
   work, ``sendto`` the path in ``$CATANC_SOCKET``: ``catanc/2 hello NODE PID TID`` (``getpid()``,
   ``gettid()``).
2. ``recvmsg`` with room for one descriptor (``CMSG_SPACE(sizeof(int))``).  A ``welcome`` for
   NODE with one ``SCM_RIGHTS`` fd: ``mmap`` the fd (``64 + SLOTS * 48`` bytes, read-write,
   shared), close it, and remember the datagram's sender as the enforcer address.  A ``reject``
   for NODE: registration failed, for the reason given.
3. Loop on ``recvfrom``: keep the latest ``route`` (from the enforcer address); on a ``trigger``
   for NODE (from the enforcer address or the route's ``PREV_ADDR``) note ``CLOCK_MONOTONIC``
   and ``CLOCK_THREAD_CPUTIME_ID``, run, then read what waits in the socket without blocking
   (a newer route, a stop), send the next node its trigger (``NEXT_ADDR``, the run's SEQ,
   ``NEXT_THREADS``), append the run to the ring, send ``done`` if the route says
   ``NOTIFY 1``, and after a trigger sent ``sched_yield()``: the next node runs at this thread's
   priority, so on this CPU it goes first instead of waiting for this thread's next receive.
   On ``stop``, leave the loop (its last run is still appended).
4. A node no trigger starts (a subscription callback) registers with ``input`` in its hello and
   appends a ring entry with SEQ 0 per run.  Its predecessor's route then names it with
   NEXT_ADDR ``-``: the predecessor sends it no trigger (its message wakes it; a trigger
   before the message would start a run on the previous message's data).
5. A run's *origin* is when the data it carries was sensed (a ROS ``header.stamp``): the node
   converts it from ``CLOCK_REALTIME`` to ``CLOCK_MONOTONIC`` (subtract
   ``realtime_now - monotonic_now``) and writes it into the entry (0: none).  The enforcer logs
   each run's age, its end minus its origin (a head's run without one: its start).
6. Leaving on its own, send ``catanc/2 bye NODE TID`` (also if no welcome was read yet: the
   enforcer may have sent one; a bye of a thread it does not know is ignored).  While waiting, check every second or so
   that the path still names a socket that takes datagrams: if not, the enforcer is gone.

Limits the enforcer applies
===========================
A hello is answered only if its sender may register: the credentials the kernel attaches
(``SO_PASSCRED``) must be root's, the enforcer's user's, or those of the owner of process
``PID``, and ``TID`` must be a thread of ``PID``.  One registration per (node, thread): a second
hello replaces the first.  At most :data:`MAX_THREADS_PER_NODE` threads per node, and
registrations are rate-limited.  Anything else from a peer that is not registered is dropped
unanswered.

Only the standard library is used here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar

from catanc.errors import CatancError, ExitCode

PROTOCOL = b"catanc/2"
"""The first word of every datagram: the protocol's name and version."""

VERSION = 2

SOCKET_ENV = "CATANC_SOCKET"
"""The environment variable naming the enforcer's socket path."""

MAX_DATAGRAM = 512
"""The largest datagram, in bytes, that is sent or accepted."""

MAX_NAME = 128
"""The longest node name, in characters."""

MAX_THREADS_PER_NODE = 16
"""Threads that may register as one node at a time (a further one is rejected)."""

STOP_GRACE_S = 2.0
"""After a stop, how long the enforcer keeps its socket open for the runs still going: a node in
the middle of one finishes and reports it before its loop ends."""

NAME_RE = re.compile(rb"[A-Za-z_][A-Za-z0-9_]{0,127}")
ADDRESS_RE = re.compile(rb"(?:[0-9a-f]{2}){1,108}")
_MAX_INT = 2**63 - 1

Address = str | bytes
"""A socket address: a path, or an abstract address (bytes starting with NUL)."""


class ProtocolError(CatancError, ValueError):
    """A datagram or message that breaks the protocol (the message says how)."""

    exit_code = ExitCode.BAD_INPUT


def _show(value: bytes | str) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_name(value: str) -> str:
    """``value`` if it is a node name the protocol carries; :class:`ProtocolError` otherwise."""
    if not isinstance(value, str) or not NAME_RE.fullmatch(value.encode("utf-8", "replace")):
        raise ProtocolError(f"a node name is an identifier of 1 to {MAX_NAME} characters, got {_show(value)}")
    return value


def _check_int(field: str, value: int, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= _MAX_INT:
        what = "a positive" if minimum > 0 else "a non-negative"
        raise ProtocolError(f"{field}: expected {what} integer, got {value!r}")
    return value


def format_address(address: Address | None) -> str:
    """An address as the protocol writes it: the hex of its bytes, ``-`` for none."""
    if address is None:
        return "-"
    raw = address.encode() if isinstance(address, str) else bytes(address)
    return raw.hex() if raw else "-"


def parse_address(text: str) -> bytes | None:
    """:func:`format_address` undone; :class:`ProtocolError` for a malformed one."""
    if text == "-":
        return None
    if not ADDRESS_RE.fullmatch(text.encode("ascii", "replace")):
        raise ProtocolError(f"an address is hex digits (pairs) or '-', got {_show(text)}")
    return bytes.fromhex(text)


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class _Message:
    TYPE: ClassVar[str] = ""
    FIELDS: ClassVar[tuple[str, ...]] = ()

    def words(self) -> list[str]:
        return [str(getattr(self, name)) for name in self.FIELDS]

    def encode(self) -> bytes:
        """This message as one datagram."""
        data = b" ".join([PROTOCOL, self.TYPE.encode(), *(word.encode("utf-8") for word in self.words())])
        if len(data) > MAX_DATAGRAM:  # pragma: no cover - field checks keep every message smaller
            raise ProtocolError(f"{self.TYPE}: {len(data)} bytes encoded; a datagram holds at most {MAX_DATAGRAM}")
        return data


HELLO_INPUT = "input"
"""A hello's optional last word: the node runs on its input (no node-to-node trigger for it)."""


@dataclass(frozen=True)
class Hello(_Message):
    """Node -> enforcer: thread ``tid`` of process ``pid`` registers as DAG node ``node``; ``on_input``:
    the node runs on its input (a subscription callback), so no node sends it triggers."""

    TYPE: ClassVar[str] = "hello"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "pid", "tid")
    node: str
    pid: int
    tid: int
    on_input: bool = False

    def __post_init__(self) -> None:
        check_name(self.node)
        _check_int("hello.pid", self.pid, 1)
        _check_int("hello.tid", self.tid, 1)

    def words(self) -> list[str]:
        return [*super().words(), *([HELLO_INPUT] if self.on_input else [])]


@dataclass(frozen=True)
class Bye(_Message):
    """Node -> enforcer: the thread leaves (it will not answer triggers any more)."""

    TYPE: ClassVar[str] = "bye"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "tid")
    node: str
    tid: int

    def __post_init__(self) -> None:
        check_name(self.node)
        _check_int("bye.tid", self.tid, 1)


@dataclass(frozen=True)
class Done(_Message):
    """Node -> enforcer: run ``seq`` is over (sent only when the route asks for it)."""

    TYPE: ClassVar[str] = "done"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "tid", "seq")
    node: str
    tid: int
    seq: int

    def __post_init__(self) -> None:
        check_name(self.node)
        _check_int("done.tid", self.tid, 1)
        _check_int("done.seq", self.seq, 0)


@dataclass(frozen=True)
class SetCores(_Message):
    """Control -> enforcer: plan for ``cores`` cores from now on."""

    TYPE: ClassVar[str] = "set_cores"
    FIELDS: ClassVar[tuple[str, ...]] = ("cores",)
    cores: int

    def __post_init__(self) -> None:
        _check_int("set_cores.cores", self.cores, 1)


@dataclass(frozen=True)
class Welcome(_Message):
    """Enforcer -> node: registered; the datagram carries the node's ring (``slots`` entries) as an fd."""

    TYPE: ClassVar[str] = "welcome"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "slots")
    node: str
    slots: int

    def __post_init__(self) -> None:
        check_name(self.node)
        _check_int("welcome.slots", self.slots, 1)


@dataclass(frozen=True)
class Route(_Message):
    """Enforcer -> node: where its runs go next (``next_node`` at ``next_address`` on ``next_threads`` threads;
    no address: the next node runs on its input, send it nothing), who may trigger it besides the enforcer
    (``prev_address``), and whether to send ``done`` after each run."""

    TYPE: ClassVar[str] = "route"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "notify", "next_node", "next_threads", "next_address", "prev_address")
    node: str
    notify: bool = False
    next_node: str | None = None
    next_threads: int = 1
    next_address: bytes | None = None
    prev_address: bytes | None = None

    def __post_init__(self) -> None:
        check_name(self.node)
        if self.next_node is not None:
            check_name(self.next_node)
        _check_int("route.next_threads", self.next_threads, 1)
        if self.next_node is None and self.next_address is not None:
            raise ProtocolError("route: a next address needs its next node")

    def words(self) -> list[str]:
        return [
            self.node,
            "1" if self.notify else "0",
            self.next_node or "-",
            str(self.next_threads),
            format_address(self.next_address),
            format_address(self.prev_address),
        ]


@dataclass(frozen=True)
class Trigger(_Message):
    """Enforcer (or the previous node) -> node: run once now, as run ``seq`` of its subchain, on ``threads`` threads."""

    TYPE: ClassVar[str] = "trigger"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "seq", "threads")
    node: str
    seq: int
    threads: int = 1

    def __post_init__(self) -> None:
        check_name(self.node)
        _check_int("trigger.seq", self.seq, 0)
        _check_int("trigger.threads", self.threads, 1)


@dataclass(frozen=True)
class Reject(_Message):
    """Enforcer -> node: the registration of ``node`` is refused (or dropped), and why (shortened to fit)."""

    TYPE: ClassVar[str] = "reject"
    FIELDS: ClassVar[tuple[str, ...]] = ("node", "reason")
    node: str
    reason: str

    def __post_init__(self) -> None:
        check_name(self.node)
        reason = " ".join(str(self.reason).split()) or "no reason given"
        room = MAX_DATAGRAM - len(PROTOCOL) - len(self.TYPE) - len(self.node) - 3
        encoded = reason.encode("utf-8", "replace")
        if len(encoded) > room:
            reason = encoded[: room - 3].decode("utf-8", "ignore") + "..."
        object.__setattr__(self, "reason", reason)


@dataclass(frozen=True)
class Stop(_Message):
    """Enforcer -> node: the enforcer is shutting down; leave the trigger loop."""

    TYPE: ClassVar[str] = "stop"


Message = Hello | Bye | Done | SetCores | Welcome | Route | Trigger | Reject | Stop

MESSAGE_TYPES: dict[bytes, type[Message]] = {
    cls.TYPE.encode(): cls for cls in (Hello, Bye, Done, SetCores, Welcome, Route, Trigger, Reject, Stop)
}


def trigger_datagram(node: str, seq: int, threads: int = 1) -> bytes:
    """``Trigger(node, seq, threads).encode()`` without building a message (the enforcer's hot path)."""
    return b"%s trigger %s %d %d" % (PROTOCOL, node.encode(), seq, threads)


def _int(kind: bytes, field: str, word: bytes) -> int:
    if not word.isdigit() or len(word) > 19:
        raise ProtocolError(f"{kind.decode()}.{field}: expected a decimal integer, got {_show(word)}")
    return int(word)


def decode(data: bytes) -> Message:
    """Parse and check one datagram; raise :class:`ProtocolError` (and nothing else) if it is not a message."""
    if len(data) > MAX_DATAGRAM:
        raise ProtocolError(f"a datagram of {len(data)}+ bytes; at most {MAX_DATAGRAM} are accepted")
    words = bytes(data).split(b" ")
    if words[0] != PROTOCOL:
        if words[0].startswith(b"catanc/") or data[:1] == b"{":
            raise ProtocolError(f"not protocol {PROTOCOL.decode()} (an older or newer catanc client?)")
        raise ProtocolError(f"not a catanc datagram (it starts {_show(data[:20])})")
    if len(words) < 2:
        raise ProtocolError("no message type")
    kind, args = words[1], words[2:]
    cls = MESSAGE_TYPES.get(kind)
    if cls is None:
        raise ProtocolError(f"unknown message type {_show(kind)}")
    try:
        if cls is Reject:
            if not args:
                raise ProtocolError("reject: missing its node")
            return Reject(args[0].decode("ascii"), b" ".join(args[1:]).decode("utf-8", "replace"))
        if cls is Hello and len(args) == 4 and args[3] == HELLO_INPUT.encode():
            return Hello(args[0].decode("ascii"), _int(kind, "pid", args[1]), _int(kind, "tid", args[2]), True)
        if len(args) != len(cls.FIELDS):
            raise ProtocolError(f"{kind.decode()}: expected {len(cls.FIELDS)} fields ({' '.join(cls.FIELDS)})")
        if cls is Route:
            notify = args[1]
            if notify not in (b"0", b"1"):
                raise ProtocolError(f"route.notify: expected 0 or 1, got {_show(notify)}")
            return Route(
                args[0].decode("ascii"),
                notify == b"1",
                None if args[2] == b"-" else args[2].decode("ascii"),
                _int(kind, "next_threads", args[3]),
                parse_address(args[4].decode("ascii")),
                parse_address(args[5].decode("ascii")),
            )
        values: list[str | int] = []
        for name, word in zip(cls.FIELDS, args, strict=True):
            values.append(word.decode("ascii") if name == "node" else _int(kind, name, word))
        return cls(*values)  # type: ignore[arg-type]
    except UnicodeDecodeError:
        raise ProtocolError(f"{kind.decode('ascii', 'replace')}: a field is not ASCII") from None
