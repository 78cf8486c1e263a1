"""The enforcer's end of the protocol: its socket, and the node threads registered through it.

- :class:`EnforcerSocket` is the socket nodes send to: bound at a path, with ``SO_PASSCRED`` so
  the kernel says who sent each datagram.  It is read without blocking, a bounded batch at a
  time, and it sends nothing but rejects (never blocking, rate-limited per peer).
- :class:`Registry` keeps one :class:`Endpoint` per registered (node, thread).  Each has a
  socket of its own, connected to the node's, through which every message to that node goes:
  a node that never reads fills only its own socket's buffer, never the one other nodes'
  triggers go through.  Each also has its ring (:mod:`catanc.runtime.protocol.ring`), where the node
  reports its runs.  Registrations are checked (who may register which thread), de-duplicated
  and rate-limited before any ``/proc`` read or scheduling call is made for them.

:func:`default_socket_path` puts the socket where only its owner can create files.
"""

from __future__ import annotations

import array
import contextlib
import errno
import os
import socket
import stat
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Self

from catanc.errors import CatancError, ExitCode
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol import ring
from catanc.runtime.protocol.messages import MAX_DATAGRAM, Address, ProtocolError

RECEIVE_BATCH = 64
"""Datagrams read per wake-up at most: a flood is taken a bounded slice at a time."""
REGISTRATIONS_PER_S = 50.0
"""Registrations accepted per second (a burst of twice as many first), over all peers."""
PEER_REGISTRATIONS_PER_S = 10.0
"""... and per sending process."""
MAX_ENDPOINTS = 256
"""Registered node threads at most, over all nodes."""
UCRED = struct.Struct("=iII")  # pid, uid, gid


class SocketPathError(CatancError):
    """The enforcer's socket cannot be bound at the given path."""

    exit_code = ExitCode.BAD_INPUT


@dataclass(frozen=True)
class Credentials:
    """Who sent a datagram, as the kernel says (``SCM_CREDENTIALS``)."""

    pid: int
    uid: int
    gid: int


@dataclass(frozen=True)
class Received:
    data: bytes
    sender: Address | None
    credentials: Credentials | None


# --------------------------------------------------------------------------- where the socket lives


def default_socket_path(app: str) -> Path:
    """``/run/catanc/<app>.sock`` for root; otherwise in a folder of the user's own.

    The folder is made if missing and refused unless it is a real folder (no link) that only its
    owner (root, or this user) can write, so no one else can put a socket or a link there first.
    """
    if os.geteuid() == 0:
        folder = Path("/run/catanc")
        mode = 0o755  # nodes of other users reach the socket; only root makes files here
    else:
        runtime = os.environ.get("XDG_RUNTIME_DIR")
        folder = Path(runtime) / "catanc" if runtime else Path(f"/tmp/catanc-{os.getuid()}")
        mode = 0o700
    with contextlib.suppress(FileExistsError):
        folder.mkdir(mode=mode, parents=False)
    check_private_folder(folder)
    return folder / f"{app}.sock"


def check_private_folder(folder: Path) -> None:
    """:class:`SocketPathError` unless ``folder`` is a folder (not a link), owned by this user, that no one else
    may write in."""
    try:
        info = folder.lstat()
    except OSError as exc:
        raise SocketPathError(f"cannot use {folder} for the enforcer's socket: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(info.st_mode):
        raise SocketPathError(f"{folder} is not a folder (a link or a file?): refusing to put the socket there")
    if info.st_uid != os.geteuid() or info.st_mode & 0o022:
        raise SocketPathError(
            f"{folder} belongs to uid {info.st_uid} with mode {stat.filemode(info.st_mode)}: only its owner may "
            "create files in the folder of the enforcer's socket (remove it, or pass --socket)"
        )


# --------------------------------------------------------------------------- the socket


class EnforcerSocket:
    """The enforcer's socket: bound at ``path`` (a stale socket there is replaced, anything else refused)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        _remove_stale_socket(self.path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
            self._sock.bind(os.fspath(self.path))
            self.path.chmod(0o666)  # any user's node may send; who may register is checked per datagram
            info = self.path.lstat()
        except OSError as exc:
            self._sock.close()
            raise SocketPathError(f"cannot bind the enforcer's socket at {self.path}: {exc.strerror or exc}") from None
        self._identity: tuple[int, int] | None = (info.st_dev, info.st_ino)
        self._cmsg_size = socket.CMSG_SPACE(UCRED.size)

    def fileno(self) -> int:
        return self._sock.fileno()

    def receive(self, limit: int = RECEIVE_BATCH) -> Iterator[Received]:
        """The datagrams waiting now, at most ``limit``, with who sent them; never blocks."""
        for _ in range(limit):
            try:
                data, ancillary, _flags, sender = self._sock.recvmsg(MAX_DATAGRAM + 1, self._cmsg_size)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ECONNREFUSED reported for an earlier send: nothing to read
                continue
            yield Received(data, sender or None, _credentials(ancillary))

    def reply(self, datagram: bytes, address: Address | None) -> bool:
        """Send from this socket without blocking (rejects only); False if it could not be sent."""
        if not address:
            return False
        try:
            self._sock.sendto(datagram, socket.MSG_DONTWAIT, address)
        except OSError:
            return False
        return True

    def close(self) -> None:
        """Close the socket and remove its file (if no one has replaced it since); safe to call twice."""
        self._sock.close()
        identity, self._identity = self._identity, None
        if identity is None:
            return
        with contextlib.suppress(FileNotFoundError):
            info = self.path.lstat()
            if (info.st_dev, info.st_ino) == identity:
                self.path.unlink()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


def _credentials(ancillary: list[tuple[int, int, bytes]]) -> Credentials | None:
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(data) >= UCRED.size:
            pid, uid, gid = UCRED.unpack_from(data)
            return Credentials(pid, uid, gid)
    return None


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
    path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- who may register


def may_register(credentials: Credentials | None, pid: int, tid: int, *, own_uid: int | None = None) -> str | None:
    """Why a peer may not register thread ``tid`` of process ``pid``; None if it may.

    Root and the enforcer's own user may register any thread; anyone else only threads of a
    process whose real or effective user is theirs.  ``tid`` must be a thread of ``pid``.
    """
    if credentials is None:
        return "the kernel gave no credentials for the datagram"
    if not Path(f"/proc/{pid}/task/{tid}").is_dir():
        return f"thread {tid} is not a thread of process {pid}"
    uid = credentials.uid
    if uid == 0 or uid == (os.geteuid() if own_uid is None else own_uid):
        return None
    try:
        status = Path(f"/proc/{pid}/status").read_text(encoding="ascii", errors="replace")
    except OSError:
        return f"process {pid} is gone"
    for line in status.splitlines():
        if line.startswith("Uid:"):
            real, effective = (int(word) for word in line.split()[1:3])
            if uid in (real, effective):
                return None
            return f"process {pid} belongs to uid {effective}, not to the sender's uid {uid}"
    return f"cannot tell who owns process {pid}"  # pragma: no cover - every status has a Uid line


class RateLimit:
    """A token bucket: :meth:`take` is True at most ``rate`` times a second, after a burst of ``burst``."""

    __slots__ = ("_at", "_tokens", "burst", "rate")

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = rate, burst
        self._tokens = burst
        self._at = time.monotonic()

    def take(self, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
        self._at = now
        if self._tokens < 1.0 - 1e-9:  # refills summed in floats: half a token twice is a token
            return False
        self._tokens -= 1.0
        return True


# --------------------------------------------------------------------------- registered threads


@dataclass(eq=False)
class Endpoint:
    """One registered node thread: its socket to the node, and its ring."""

    node: str
    pid: int
    tid: int
    address: bytes | str | None  # None: attached (no protocol), triggers are never sent
    sock: socket.socket | None = None
    reader: ring.RingReader | None = None
    ring_fd: int | None = None
    route: protocol.Route | None = None  # the last route sent
    owner_uid: int = 0
    failed: bool = field(default=False)  # a send failed: the node does not take datagrams
    kernel_mark_ns: int | None = None  # its thread's CPU time at the last check of a suspicious report
    shares_thread: bool = False  # its thread hosts another registered node too: the thread's CPU is not its own
    error: str = "closed"  # why the last send failed
    on_input: bool = False  # it runs on its input (a subscription): no node sends it triggers

    def send(self, datagram: bytes) -> bool:
        """Send without blocking; False (and :attr:`failed`) if the node is gone or not reading."""
        if self.sock is None:
            return False
        try:
            self.sock.send(datagram, socket.MSG_DONTWAIT)
        except OSError as exc:
            self.failed = True
            self.error = exc.strerror or str(exc)
            return False
        return True

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None
        if self.ring_fd is not None:
            os.close(self.ring_fd)
            self.ring_fd = None
        if self.sock is not None:
            self.sock.close()
            self.sock = None


def open_endpoint(node: str, pid: int, tid: int, address: Address, *, on_input: bool = False) -> Endpoint:
    """A new endpoint for a node thread at ``address``: its socket connected there, its ring made and welcomed.

    Raises ``OSError`` if the node's socket is gone already (nothing is left open then).
    """
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC)
    fd = None
    try:
        sock.bind("")
        sock.connect(address)
        fd = ring.create(name=f"catanc-{node}-{tid}")
        welcome = protocol.Welcome(node, ring.SLOTS).encode()
        fds = array.array("i", [fd])
        sock.sendmsg([welcome], [(socket.SOL_SOCKET, socket.SCM_RIGHTS, fds.tobytes())], socket.MSG_DONTWAIT)
        reader = ring.RingReader(fd)
    except BaseException:
        sock.close()
        if fd is not None:
            os.close(fd)
        raise
    return Endpoint(node, pid, tid, address, sock, reader, fd, on_input=on_input)


class Registry:
    """Registered node threads by (node, tid), with the checks and limits a registration passes first."""

    def __init__(self, nodes: set[str], *, own_uid: int | None = None) -> None:
        self.nodes = nodes
        self.own_uid = os.geteuid() if own_uid is None else own_uid
        self.by_key: dict[tuple[str, int], Endpoint] = {}
        self.by_node: dict[str, list[Endpoint]] = {}
        self._overall = RateLimit(REGISTRATIONS_PER_S, 2 * REGISTRATIONS_PER_S)
        self._peers: dict[int, RateLimit] = {}

    def endpoints(self) -> Iterator[Endpoint]:
        return iter(list(self.by_key.values()))

    def of(self, node: str) -> list[Endpoint]:
        return self.by_node.get(node, [])

    def speaker(self, node: str) -> Endpoint | None:
        """``node``'s first registered thread that speaks the protocol (triggers go to it)."""
        for endpoint in self.by_node.get(node, ()):
            if endpoint.sock is not None and not endpoint.failed:
                return endpoint
        return None

    def check(self, hello: protocol.Hello, credentials: Credentials | None) -> tuple[str | None, bool]:
        """Whether ``hello`` may register: ``(why not, answer)``, ``why not`` None if it may.

        ``answer`` says whether a refusal is worth a reject (a peer over its rate gets none).
        """
        peer = credentials.pid if credentials is not None else 0
        limit = self._peers.get(peer)
        if limit is None:
            if len(self._peers) > 4 * MAX_ENDPOINTS:
                self._peers.clear()
            limit = self._peers[peer] = RateLimit(PEER_REGISTRATIONS_PER_S, 2 * PEER_REGISTRATIONS_PER_S)
        if not limit.take() or not self._overall.take():
            return "too many registrations: slow down", False  # not even a reject: a flood gets no answers
        if hello.node not in self.nodes:
            return f"no node {hello.node!r} in this app (its nodes: {', '.join(sorted(self.nodes))})", True
        key = (hello.node, hello.tid)
        if key not in self.by_key:
            if len(self.by_node.get(hello.node, ())) >= protocol.MAX_THREADS_PER_NODE:
                return f"node {hello.node!r} has {protocol.MAX_THREADS_PER_NODE} threads registered already", True
            if len(self.by_key) >= MAX_ENDPOINTS:
                return f"{MAX_ENDPOINTS} threads are registered already", True
        return may_register(credentials, hello.pid, hello.tid, own_uid=self.own_uid), True

    def add(self, endpoint: Endpoint) -> Endpoint | None:
        """Register ``endpoint``; the one it replaces (the same node and thread), if any, is returned (not closed)."""
        key = (endpoint.node, endpoint.tid)
        previous = self.by_key.pop(key, None)
        if previous is not None:
            self.by_node[endpoint.node].remove(previous)
        self.by_key[key] = endpoint
        self.by_node.setdefault(endpoint.node, []).append(endpoint)
        self._mark_shared(endpoint.tid)
        return previous

    def remove(self, endpoint: Endpoint) -> bool:
        """Forget ``endpoint`` (and close it); False if it was not registered."""
        key = (endpoint.node, endpoint.tid)
        if self.by_key.get(key) is not endpoint:
            return False
        del self.by_key[key]
        self.by_node[endpoint.node].remove(endpoint)
        endpoint.close()
        self._mark_shared(endpoint.tid)
        return True

    def _mark_shared(self, tid: int) -> None:
        """Say of each node on thread ``tid`` whether another node runs in it too (an executor's one thread)."""
        hosted = [endpoint for endpoint in self.by_key.values() if endpoint.tid == tid]
        for endpoint in hosted:
            endpoint.shares_thread = len(hosted) > 1

    def find(self, node: str, tid: int) -> Endpoint | None:
        return self.by_key.get((node, tid))

    def from_address(self, address: Address | None, node: str) -> Endpoint | None:
        """The endpoint of ``node`` whose node socket is ``address`` (who may say bye or done for it)."""
        for endpoint in self.by_node.get(node, ()):
            if endpoint.address == address:
                return endpoint
        return None

    def close(self) -> None:
        for endpoint in list(self.by_key.values()):
            endpoint.close()
        self.by_key.clear()
        self.by_node.clear()


def decode_or_none(data: bytes) -> tuple[protocol.Message | None, str | None]:
    """A datagram as a message, or why it is not one."""
    try:
        return protocol.decode(data), None
    except ProtocolError as exc:
        return None, str(exc)
