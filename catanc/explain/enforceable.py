"""Whether a plan's shared cores can be enforced with the spec's assumed switch cost
(docs/explanation/model.md section 5).

A shared core's schedule budgets ``switch_ms`` per slot: the enforcer's
priority changes and the head's wake-up.  Without a machine profile that
figure is an assumption, and the only reserve against it being wrong is the
core's slack (``slack * T``), which by default is the kernel's own 5%
SCHED_FIFO reserve.  The criterion: a core whose slots spend more time
switching than its slack (``n * switch_ms > slack * T``) is flagged, because
real switches twice as dear as assumed would push it past its slack and into
the kernel's RT throttle.  VR's 1-core plan (three slots in a 4.6 ms
period: 0.36 ms of switching against 0.23 ms of slack) is the example.
With a profile the costs are measured and planned for, so nothing is flagged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from catanc.spec.language import Schedule

if TYPE_CHECKING:
    from catanc.planning.types import Plan


@dataclass(frozen=True)
class ShortSlots:
    """A shared core whose switching outweighs its slack."""

    core: int
    slots: int
    period_ms: float
    switching_ms: float  # slots * switch_ms
    slack_ms: float  # slack * T

    @property
    def warning(self) -> str:
        share = self.switching_ms / self.period_ms
        return (
            f"slices too short to enforce with assumed costs: core {self.core} spends {self.switching_ms:.3f} ms "
            f"({share:.1%}) of its {self.period_ms:.3f} ms period on {self.slots} switches at the spec's "
            f"switch_ms, more than its slack of {self.slack_ms:.3f} ms: switches twice as dear would run it into "
            "Linux's SCHED_FIFO throttle; measure the machine (catanc calibrate) and plan with --machine FILE, "
            "or raise schedule.min_slice_ms"
        )


def short_slots(plan: Plan, schedule: Schedule) -> list[ShortSlots]:
    """Shared cores whose planned switching (``n * switch_ms``) exceeds their slack (``slack * T``)."""
    found = []
    for core in sorted(plan.shared_cores, key=lambda c: c.core):
        slots = len(core.order)
        switching = slots * schedule.switch_ms
        reserve = schedule.slack * core.period_ms
        if switching > reserve:
            found.append(ShortSlots(core.core, slots, core.period_ms, switching, reserve))
    return found
