"""The slot rule compiled with numba, once, for both engines: :func:`catanc.control.policy.decide` over arrays.

The enforcer's compiled walk (:mod:`catanc.runtime.compiled.walk`) and the simulator's kernel
(:mod:`catanc.sim.kernel`) call :func:`decide` at each boundary of a shared core, over the slot
rules laid out by :mod:`catanc.control.slot_table`.  It writes the boundary's *actions* (whom to
raise, whether the previous owner is lowered, which head to trigger, whether the slot was stolen)
and each engine carries them out its own way: the walk with system calls (levels by
``sched_setscheduler``, triggers by ``send``), the kernel with job priorities and simulated
triggers.  Who is late is each engine's to say (rings read into runs in flight; simulated runs):
it marks the boundary's thieves in ``late`` first.

:mod:`catanc.control.policy` stays the statement and the oracle: tests/control/test_compiled_policy.py
holds this module to it, boundary by boundary, on random schedules and lateness.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt

from catanc.control import slot_table
from catanc.control.slot_table import HANDOVER, LOWER, NONE, RAISE, STEAL, TRIGGER
from catanc.numba_cache import drop_stale_cache

F = TypeVar("F", bound=Callable[..., Any])
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

COMPILED_FROM = (Path(__file__), Path(slot_table.__file__))
"""This module's compiled code depends on these sources (a module that calls it depends on them too)."""


def compiled(function: F) -> F:
    """numba's no-Python mode, cached on disk beside the module, with numpy's error model (no path needs
    Python's exception machinery: the walk's object code runs without numba), inlined into its callers.

    As calls, the shared rule cost the walk ~200 ns a wake-up (4.2%) and the kernel 2.0% of its
    instructions on nav2d (2026-12-02); inlined, the walk is within noise of its own copy of the rule
    and the kernel 1.0% above it (the engines mark every thief's lateness before the decision)."""
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(function))


drop_stale_cache(Path(__file__), COMPILED_FROM)


@compiled
def boundary_ms(
    slot_start: FloatArray,
    slot_length: FloatArray,
    switch: FloatArray,
    nslots: IntArray,
    v: int,
    c: int,
    start: float,
    position: int,
) -> float:
    """:func:`~catanc.control.policy.boundary_ms` for core ``c``'s schedule version ``v`` (slots ``[V, C, M]``, the
    switch and the slot count ``[V, C]``) in a period starting at ``start``."""
    n = nslots[v, c]
    if position < n:
        return float(start + slot_start[v, c, position] - switch[v, c])
    return float(start + slot_start[v, c, n - 1] + slot_length[v, c, n - 1])


@compiled
def triggers(rule_every: IntArray, v: int, c: int, position: int, period_index: int) -> bool:
    """Whether boundary ``position`` triggers its slot's head in period ``period_index``
    (:func:`~catanc.control.policy.needs_wake` of an idle core)."""
    every = rule_every[v, c, position]
    return bool(every > 0 and period_index % every == 0)


@compiled
def hand_over(raised: IntArray, core: int, owner: int, actions: IntArray) -> None:
    """``owner`` runs raised on ``core`` now (``raised[core]``: the subchain raised there; NONE: none): the actions
    :data:`RAISE`, :data:`HANDOVER` and :data:`LOWER`."""
    previous = raised[core]
    actions[RAISE] = owner
    if previous == owner:
        actions[HANDOVER] = 0
        actions[LOWER] = NONE
        return
    raised[core] = owner
    actions[HANDOVER] = 1
    actions[LOWER] = previous


@compiled
def decide(
    rule_sub: IntArray,
    rule_every: IntArray,
    rule_thieves: IntArray,
    v: int,
    c: int,
    position: int,
    period_index: int,
    late: IntArray,
    raised: IntArray,
    core: int,
    actions: IntArray,
) -> None:
    """:func:`~catanc.control.policy.decide` at boundary ``position`` of core ``c``'s rules, version ``v``, in
    period ``period_index``, then :func:`hand_over` the core (``raised`` indexed by ``core``).

    ``late[s]``: 1 if subchain ``s`` is late now; only the boundary's thieves are read (:func:`thieves`).
    """
    sub = rule_sub[v, c, position]
    owner = sub
    trigger = NONE
    if sub != NONE:
        for t in range(rule_thieves.shape[3]):  # best first: the first late one takes the slot
            thief = rule_thieves[v, c, position, t]
            if thief == NONE:
                break
            if late[thief] != 0:
                owner = thief
                break
        if triggers(rule_every, v, c, position, period_index):
            trigger = sub
    actions[TRIGGER] = trigger
    actions[STEAL] = 1 if owner != sub else 0
    hand_over(raised, core, owner, actions)


@compiled
def thieves(rule_thieves: IntArray, v: int, c: int, position: int) -> int:
    """How many thieves boundary ``position`` has: ``rule_thieves[v, c, position, :count]``."""
    count = 0
    for t in range(rule_thieves.shape[3]):
        if rule_thieves[v, c, position, t] == NONE:
            break
        count += 1
    return count
