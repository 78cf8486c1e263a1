"""The SCHED_FIFO priorities of catan-model.md section 6, one definition for the launchers and the enforcer."""

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
