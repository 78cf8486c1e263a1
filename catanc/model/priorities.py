"""The SCHED_FIFO priorities of docs/explanation/model.md section 6, one definition for launchers and enforcer."""

from __future__ import annotations

SHARED_FIFO = 1  # every node thread of a shared core, between its slices
RUNNING_FIFO = 2  # the subchain whose slice it is, and every dedicated subchain
UNSCHEDULED_FIFO = 3  # nodes on their own clock
ENFORCER_FIFO = 4  # the enforcer's trigger and scheduler threads
APP_FIFO_LEVELS = frozenset({SHARED_FIFO, RUNNING_FIFO, UNSCHEDULED_FIFO})


def resting_fifo(shared: bool | None) -> int:
    """The priority a node thread rests at: its subchain is shared or dedicated, or None (unscheduled)."""
    if shared is None:
        return UNSCHEDULED_FIFO
    return SHARED_FIFO if shared else RUNNING_FIFO


def static_policy(shared: bool | None) -> tuple[str, int]:
    """A node thread's policy and priority without the enforcer: ``("SCHED_FIFO", 2)`` or ``("SCHED_OTHER", 0)``.

    A dedicated subchain keeps SCHED_FIFO 2 and a node on its own clock 3, as under the enforcer.
    A shared core's threads go to SCHED_OTHER: with nobody switching slices, equal SCHED_FIFO
    levels would not time-slice (one long run blocks every other subchain of the core), and
    the fair scheduler shares the core while each runs at its planned rate.
    """
    if shared:
        return "SCHED_OTHER", 0
    return "SCHED_FIFO", resting_fifo(shared)
