"""The enforcer's JSON-lines log: one object per event, for ``catanc report`` and for tests.

Each line is ``{"t": seconds since start, "event": name, ...fields}``, with
sorted keys; events are ``start``, ``register``, ``gone``, ``compute`` (a
node's measured compute time), ``run`` (a subchain's run: trigger to last
node done), ``lost``, ``resolve`` (every re-plan: why, how long it took,
the compute times it used and the plan it made), ``status`` (periodic
per-subchain rates, p95s, late runs, steals) and ``stop``.

``compute`` and ``run`` come hundreds of times a second, so they are
written in batches at each flush (about once a second): one
``compute_batch`` line per node and one ``run_batch`` line per subchain,
each field a column and ``at`` the samples' times.  Encoding a line per
sample cost the enforcer about 0.03 cores on nav2d.  :func:`read_log`
expands batches back into single events.

The ``start`` event carries ``format`` (:data:`LOG_FORMAT`), bumped when a
reader of the log (``catanc profile``) would misread an older one.  A
``compute`` sample's ``threads`` is how many threads its run used (its
``ms`` is already one-thread time, converted with the spec's speedup).
Its ``age_ms`` is the run's end minus its origin, in ms: the origin is when
the data the run carries was sensed (a ROS ``header.stamp``, reported by the
node), or, for a triggered head's run that reports none, its start; null for
a later node's run without one.  A chain's response is the age of its last
node's runs.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from catanc.errors import CatancError, ExitCode, UsageError

LOG_FORMAT = 1
"""The log's format version, in its ``start`` event (logs without one are older)."""

BATCHED: dict[str, tuple[str, tuple[tuple[str, int | None], ...]]] = {
    "compute": ("node", (("ms", 4), ("reported_ms", None), ("kernel_ms", 4), ("threads", None), ("age_ms", 3))),
    "run": ("subchain", (("seq", None), ("latency_ms", 3))),
}
"""Sampled events: the field that names what was sampled, and the value fields with their rounding."""
BATCH_SUFFIX = "_batch"


class LogError(CatancError):
    """The log cannot be written where asked (a link, not a regular file, no permission)."""

    exit_code = ExitCode.BAD_INPUT


class RunLog:
    """Appends events to a file; safe to call from every enforcer thread."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[str] = open_log(self.path)  # one log per run
        self._lock = threading.Lock()
        self._samples: deque[tuple[str, float, str, tuple[Any, ...]]] = deque()

    def write(self, event: str, t: float, fields: dict[str, Any]) -> None:
        line = json.dumps({"t": round(t, 6), "event": event, **fields}, sort_keys=True, allow_nan=False)
        with self._lock:
            self._file.write(line + "\n")  # buffered: the enforcer flushes once a second

    def sample(self, event: str, t: float, key: str, values: tuple[Any, ...]) -> None:
        """Record one ``compute`` or ``run`` sample (``values`` in :data:`BATCHED`'s order) for the next flush."""
        self._samples.append((event, t, key, values))  # deque.append is atomic: no lock on the hot path

    def flush(self) -> None:
        with self._lock:
            for line in _batch_lines(self._samples):
                self._file.write(line + "\n")
            self._file.flush()

    def close(self) -> None:
        self.flush()
        with self._lock:
            self._file.close()

    def __enter__(self) -> RunLog:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


def open_log(path: Path) -> IO[str]:
    """``path`` opened for writing, emptied, refusing a link (root must not overwrite a planted link's target)
    and anything that is not a regular file (a FIFO would block, a device would not be a log)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise LogError(f"{path}: is a symbolic link; refusing to write the log through it") from None
        raise LogError(f"{path}: cannot write the log: {exc.strerror or exc}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise LogError(f"{path}: not a regular file; refusing to write the log there")
        os.set_blocking(fd, True)
        os.ftruncate(fd, 0)
        return os.fdopen(fd, "w", encoding="utf-8")
    except BaseException:
        os.close(fd)
        raise


class Throttle:
    """At most one report a second per kind: :meth:`due` says when, and how many were left out meanwhile."""

    def __init__(self, every_ms: float = 1000.0) -> None:
        self.every_ms = every_ms
        self._last: dict[str, float] = {}
        self._left_out: dict[str, int] = {}

    def due(self, kind: str, now_ms: float) -> int | None:
        """None: leave this one out; else report it, with the count left out since the last report."""
        last = self._last.get(kind)
        if last is not None and now_ms - last < self.every_ms:
            self._left_out[kind] = self._left_out.get(kind, 0) + 1
            return None
        self._last[kind] = now_ms
        return self._left_out.pop(kind, 0)


class Notes:
    """The run's notes for people: short texts for the live status (the last ten), log lines, samples.

    Times in the log are seconds since ``started_ms`` on ``clock``; nothing is written before
    :attr:`log` is set (it is opened once the socket is ours: never truncate another run's log).
    """

    def __init__(self, clock: Callable[[], float], started_ms: float) -> None:
        self.clock = clock
        self.started_ms = started_ms
        self.log: RunLog | None = None
        self.texts: list[str] = []
        self.throttle = Throttle()

    def note(self, text: str) -> None:
        self.texts = [*self.texts[-9:], text]

    def throttled(self, kind: str, text: str) -> None:
        """A note (and a log line) at most once a second per kind, saying how many were left out."""
        suppressed = self.throttle.due(kind, self.clock())
        if suppressed is None:
            return
        more = f" (and {suppressed} more like it)" if suppressed else ""
        self.note(text + more)
        self.write("dropped", kind=kind, text=text, more=suppressed)

    def write(self, event: str, **fields: Any) -> None:
        if self.log is not None:
            self.log.write(event, (self.clock() - self.started_ms) / 1000.0, fields)

    def sample(self, event: str, at_ms: float, key: str, values: tuple[Any, ...]) -> None:
        if self.log is not None:
            self.log.sample(event, (at_ms - self.started_ms) / 1000.0, key, values)

    def flush(self) -> None:
        if self.log is not None:
            self.log.flush()

    def close(self) -> None:
        if self.log is not None:
            log, self.log = self.log, None
            log.close()


def _batch_lines(samples: deque[tuple[str, float, str, tuple[Any, ...]]]) -> list[str]:
    """Drain ``samples`` into one line per event and key, the first-seen key first."""
    groups: dict[tuple[str, str], list[tuple[float, tuple[Any, ...]]]] = {}
    for _ in range(len(samples)):  # only what is there now: appends during the drain wait for the next flush
        event, t, key, values = samples.popleft()
        groups.setdefault((event, key), []).append((t, values))
    lines = []
    for (event, key), rows in groups.items():
        key_field, value_fields = BATCHED[event]
        body: dict[str, Any] = {"t": round(rows[-1][0], 6), "event": event + BATCH_SUFFIX, key_field: key}
        body["at"] = [round(t, 6) for t, _ in rows]
        for index, (name, digits) in enumerate(value_fields):
            column = [values[index] for _, values in rows]
            body[name] = column if digits is None else [None if v is None else round(v, digits) for v in column]
        lines.append(json.dumps(body, sort_keys=True, allow_nan=False))
    return lines


def read_log(path: str | Path) -> list[dict[str, Any]]:
    """Every event of a log, in order, batches expanded (a torn last line from a killed run is skipped)."""
    return log_events(Path(path).read_text(encoding="utf-8"))


def read_log_text(path: Path) -> str:
    """The text of the log at ``path``; :class:`~catanc.errors.UsageError` naming it if it cannot be read."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"{path}: no such log file") from None
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, not a log file") from None
    except UnicodeDecodeError:
        raise UsageError(f"{path}: cannot read the log: not UTF-8 text") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot read the log: {exc.strerror or exc}") from None


def log_events(text: str) -> list[dict[str, Any]]:
    """Every event of a log's text, in order, batches expanded (a torn last line from a killed run is skipped)."""
    events: list[dict[str, Any]] = []
    for line in text.splitlines():
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            continue
        events.extend(expand(event))
    return events


def expand(event: Any) -> list[Any]:
    """A batch line as its single events; any other line (even a malformed one) as itself."""
    name = event.get("event") if isinstance(event, dict) else None
    if not isinstance(name, str) or not name.endswith(BATCH_SUFFIX) or name[: -len(BATCH_SUFFIX)] not in BATCHED:
        return [event]
    single = name[: -len(BATCH_SUFFIX)]
    key_field, value_fields = BATCHED[single]
    times = event.get("at")
    if not isinstance(times, list):
        return [event]
    # A column an older catanc did not write (``threads``) reads as unknown in every sample.
    columns = [event.get(field, [None] * len(times)) for field, _ in value_fields]
    if not all(isinstance(c, list) and len(c) == len(times) for c in columns):
        return [event]  # not a batch this catanc wrote: the report skips what it cannot read
    return [
        {"t": t, "event": single, key_field: event.get(key_field)}
        | {field: column[i] for (field, _), column in zip(value_fields, columns, strict=True)}
        for i, t in enumerate(times)
    ]
