"""The enforcer's JSON-lines log: one object per event, for ``catanc report`` and for tests.

Each line is ``{"t": seconds since start, "event": name, ...fields}``, with
sorted keys; events are ``start``, ``register``, ``gone``, ``compute`` (a
node's measured compute time), ``run`` (a subchain's run: trigger to last
node done), ``lost``, ``resolve`` (every re-plan: why, how long it took,
the compute times it used and the plan it made), ``status`` (periodic
per-subchain rates, p95s, late runs, steals) and ``stop``.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from types import TracebackType
from typing import IO, Any


class RunLog:
    """Appends events to a file; safe to call from every enforcer thread."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[str] = self.path.open("w", encoding="utf-8")  # one log per run
        self._lock = threading.Lock()

    def write(self, event: str, t: float, fields: dict[str, Any]) -> None:
        line = json.dumps({"t": round(t, 6), "event": event, **fields}, sort_keys=True, allow_nan=False)
        with self._lock:
            self._file.write(line + "\n")  # buffered: the enforcer flushes once a second

    def flush(self) -> None:
        with self._lock:
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()

    def __enter__(self) -> RunLog:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


def read_log(path: str | Path) -> list[dict[str, Any]]:
    """Every event of a log, in order (a torn last line from a killed run is skipped)."""
    events = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            events.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return events
