"""What a simulated (or measured) run recorded, before it is summarised into a PolicyResult."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from catanc.control.schedule import RuntimeSchedule
from catanc.sim.policies import Replan


@dataclass
class Records:
    """Per node its completion times and input staleness, per chain its arrivals, per core its busy time."""

    done_ms: Mapping[str, Sequence[float] | npt.NDArray[np.float64]]  # a list, or an array (the compiled kernel's)
    staleness_ms: Mapping[str, Sequence[float] | npt.NDArray[np.float64]]
    arrivals: Sequence[Sequence[tuple[float, float]] | npt.NDArray[np.float64]]
    """Per chain: ``(origin, done)`` at its last node, in completion order (a list, or an (n, 2) array).

    The simulator keeps only the outputs whose origin is newer than any before (the others show no
    response time); measured records may keep every output.
    """
    busy_by_core: dict[int, float]  # core -> time it ran jobs (ms)
    replans: list[Replan]
    schedule: RuntimeSchedule | None  # the schedule in force at the end (catan and static plans)
