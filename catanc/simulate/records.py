"""What a simulated (or measured) run recorded, before it is summarised into a PolicyResult."""

from __future__ import annotations

from dataclasses import dataclass

from catanc.runtime.schedule import RuntimeSchedule
from catanc.simulate.policies import Replan


@dataclass
class Records:
    """Per node its completion times and input staleness, per chain its arrivals, per core its busy time."""

    done_ms: dict[str, list[float]]
    staleness_ms: dict[str, list[float]]
    arrivals: list[list[tuple[float, float]]]  # per chain: (origin, done) at its last node, in completion order
    busy_by_core: dict[int, float]  # core -> time it ran jobs (ms)
    replans: list[Replan]
    schedule: RuntimeSchedule | None  # the schedule in force at the end (catan and static plans)
