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


def write_records(path: str | os.PathLike[str], records: Iterable[RunRecord]) -> None:
    """Write ``records`` as JSON lines, atomically (a temporary file renamed over ``path``)."""
    target = Path(path)
    partial = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    with partial.open("w", encoding="utf-8") as out:
        for record in records:
            out.write(json.dumps(record._asdict(), separators=(",", ":")) + "\n")
    partial.replace(target)


def read_records(path: str | os.PathLike[str]) -> list[RunRecord]:
    """The runs :func:`write_records` wrote; ValueError naming the line if one is not a run."""
    records = []
    for number, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), start=1):
        try:
            data = json.loads(line)
            record = RunRecord(str(data["node"]), int(data["start_ns"]), int(data["end_ns"]), int(data["cpu_ns"]))
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}:{number}: not a run record ({exc})") from None
        records.append(record)
    return records
