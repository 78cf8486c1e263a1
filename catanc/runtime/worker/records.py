"""Each run of a worker, as ``--record`` writes it (JSON lines, written atomically) and ``catanc bench`` reads it."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple


class RunRecord(NamedTuple):
    """One run of a node, as ``--record`` writes it: CLOCK_MONOTONIC times, shared by every process."""

    node: str
    start_ns: int  # the trigger arrived: the run reads its inputs
    end_ns: int  # the work is done (just before the node reports done)
    cpu_ns: int  # CPU time the run used, over all the threads it burned on
    # The node's thread's CPU clock (CLOCK_THREAD_CPUTIME_ID) at the start and once it has reported
    # the run done (0: not recorded): the CPU it spends around its runs is what lies between.
    thread_cpu_start_ns: int = 0
    thread_cpu_done_ns: int = 0


def write_records(path: str | os.PathLike[str], records: Iterable[RunRecord]) -> None:
    """Write ``records`` as JSON lines, atomically (a temporary file renamed over ``path``)."""
    target = Path(path)
    partial = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    partial.write_text(records_text(records), encoding="utf-8")
    partial.replace(target)


def records_text(records: Iterable[RunRecord]) -> str:
    """``records`` as the JSON lines :func:`write_records` writes."""
    return "".join(json.dumps(record._asdict(), separators=(",", ":")) + "\n" for record in records)


def read_records(path: str | os.PathLike[str]) -> list[RunRecord]:
    """The runs :func:`write_records` wrote; ValueError naming the line if one is not a run."""
    records = []
    for number, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), start=1):
        try:
            data = json.loads(line)
            record = RunRecord(
                str(data["node"]),
                int(data["start_ns"]),
                int(data["end_ns"]),
                int(data["cpu_ns"]),
                int(data.get("thread_cpu_start_ns", 0)),
                int(data.get("thread_cpu_done_ns", 0)),
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}:{number}: not a run record ({exc})") from None
        records.append(record)
    return records
