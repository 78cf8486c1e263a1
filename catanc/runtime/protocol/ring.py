"""A node's ring: where its runs are reported without waking the enforcer (protocol ``catanc/2``).

The enforcer makes one ring per registered node thread (a ``memfd``, sealed so that it can
neither grow nor shrink: a node cannot make the enforcer's mapping fault) and passes it with
the welcome.  The node appends an entry when a run ends; the enforcer reads what is new when it
wakes up anyway (a slot switch, a clock trigger), so a run costs it no wake-up.

Layout (host byte order, every field naturally aligned; offsets in bytes)::

    header, HEADER_SIZE = 64 bytes
      0   u32  magic           0x52544143 ("CATR" in little-endian memory)
      4   u32  layout version  1
      8   u32  slots           N, the number of entries
      12  u32  entry size      48
      16  u64  written         entries written so far (only the node writes it)
      24..63   zero
    entry k (k = 0, 1, ...) at HEADER_SIZE + (k mod N) * 48
      0   u64  seq         the run's seq from its trigger; 0: a run nothing triggered (a
                           subscription callback), taken as the oldest run waiting at the node
      8   u64  start_ns    CLOCK_MONOTONIC when the run started (the trigger was taken)
      16  u64  end_ns      CLOCK_MONOTONIC when it ended
      24  u64  compute_ns  the run's compute time as the node measured it (its thread's CPU
                           time; a run on several threads: its wall time), or 2**64-1: unknown
      32  u32  threads     threads the run used
      36  u32  zero
      40  u64  origin_ns   CLOCK_MONOTONIC when the data the run carries was sensed (a ROS
                           header.stamp, converted from CLOCK_REALTIME by the node), or 0: none

``origin_ns`` was a zero word in the first clients: they write "none", so the layout version
stays 1 (a reader need not tell them apart, and an older enforcer ignores the word).

To append entry ``k = written``: write the entry, then store ``written = k + 1`` (in C or C++ a
release store, so the entry is visible first).  The reader takes entries ``max(last, w - N)``
to ``w - 1`` for the ``w`` it read, then reads ``written`` again and drops those an overtaking
writer may have overwritten meanwhile.  The enforcer trusts nothing in a ring: an entry counts
only if its seq is a run in flight at that node, and its times are clamped to what the enforcer
saw (a run cannot take more CPU than the time since its trigger on the threads it had).
"""

from __future__ import annotations

import contextlib
import fcntl
import mmap
import os
import struct
from typing import NamedTuple

MAGIC = 0x52544143
LAYOUT_VERSION = 1
HEADER_SIZE = 64
ENTRY_SIZE = 48
SLOTS = 64
"""Entries per ring: a node runs at most once per trigger, and the enforcer reads at least every period."""
UNKNOWN = 2**64 - 1
"""``compute_ns`` of a run the node did not measure."""

HEADER = struct.Struct("=IIIIQ")
ENTRY = struct.Struct("=QQQQIIQ")
WRITTEN_OFFSET = 16


def ring_size(slots: int = SLOTS) -> int:
    return HEADER_SIZE + slots * ENTRY_SIZE


class Entry(NamedTuple):
    """One run a node reported."""

    seq: int
    start_ns: int
    end_ns: int
    compute_ns: int  # UNKNOWN when not measured
    threads: int
    origin_ns: int = 0  # CLOCK_MONOTONIC when its data was sensed; 0: none

    @property
    def compute_ms(self) -> float | None:
        return None if self.compute_ns == UNKNOWN else self.compute_ns / 1e6


def create(slots: int = SLOTS, name: str = "catanc-ring") -> int:
    """A new, sealed ring's file descriptor (close-on-exec), its header written."""
    fd = os.memfd_create(name, os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    try:
        size = ring_size(slots)
        os.ftruncate(fd, size)
        os.pwrite(fd, HEADER.pack(MAGIC, LAYOUT_VERSION, slots, ENTRY_SIZE, 0), 0)
        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL)
    except BaseException:
        os.close(fd)
        raise
    return fd


_CLOSED = memoryview(bytes(24)).cast("Q")
"""What a closed reader reads: a header whose ``written`` is 0 (nothing new, ever)."""


class RingReader:
    """The enforcer's view of one ring: :meth:`new` gives the entries written since the last call."""

    __slots__ = ("_map", "_view", "last", "overrun", "slots", "words")

    def __init__(self, fd: int, slots: int = SLOTS) -> None:
        self.slots = slots
        self._map = mmap.mmap(fd, ring_size(slots), mmap.MAP_SHARED, mmap.PROT_READ)
        self._view = memoryview(self._map)
        self.words = self._view.cast("Q")  # words[2] is `written`: new entries when it differs from `last`
        self.last = 0
        self.overrun = 0  # entries the node wrote faster than they were read (lost)

    def written(self) -> int:
        return int(self.words[2])

    def pending(self) -> bool:
        """Whether the node wrote anything since the last :meth:`new` (one memory read)."""
        return self.words[2] != self.last

    def new(self) -> list[Entry]:
        """The entries written since the last call, oldest first."""
        written = int(self.words[2])
        if written == self.last:
            return []
        if written < self.last:  # a node that rewound its counter: start over from it
            self.last = written
            return []
        first = max(self.last, written - self.slots)
        self.overrun += first - self.last
        found = []
        for k in range(first, written):
            offset = HEADER_SIZE + (k % self.slots) * ENTRY_SIZE
            seq, start, end, compute, threads, _, origin = ENTRY.unpack_from(self._map, offset)
            found.append((k, Entry(seq, start, end, compute, threads, origin)))
        again = int(self.words[2])
        self.last = written
        return [entry for k, entry in found if k >= again - self.slots]

    def close(self) -> None:
        """Unmap the ring; the reader stays usable and finds nothing new (whoever still holds it)."""
        words, self.words = self.words, _CLOSED
        self.last = 0
        words.release()
        self._view.release()
        with contextlib.suppress(BufferError):
            self._map.close()


class RingWriter:
    """A node's side of a ring (the tests' and the Python client's layout, kept here as the reference)."""

    def __init__(self, fd: int) -> None:
        header = os.pread(fd, HEADER.size, 0)
        magic, version, slots, entry_size, written = HEADER.unpack(header)
        if (magic, version, entry_size) != (MAGIC, LAYOUT_VERSION, ENTRY_SIZE):
            raise ValueError(f"not a catanc ring (magic {magic:#x}, version {version}, entry {entry_size})")
        self.slots = slots
        self._map = mmap.mmap(fd, ring_size(slots), mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        # `written` is stored as one aligned 8-byte word: struct's pack_into zeroes the field, then
        # writes it a byte at a time, and a reader in between saw the counter go back (to 0).
        self._header = memoryview(self._map)[:HEADER_SIZE].cast("Q")
        self.written = written

    def append(
        self, seq: int, start_ns: int, end_ns: int, compute_ns: int = UNKNOWN, threads: int = 1, *, origin_ns: int = 0
    ) -> None:
        offset = HEADER_SIZE + (self.written % self.slots) * ENTRY_SIZE
        ENTRY.pack_into(self._map, offset, seq, start_ns, end_ns, compute_ns, threads, 0, origin_ns)
        self.written += 1
        self._header[WRITTEN_OFFSET // 8] = self.written

    def close(self) -> None:
        self._header.release()
        self._map.close()
