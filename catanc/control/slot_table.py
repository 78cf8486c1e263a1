"""The slot rules as arrays: the one layout the enforcer's compiled walk and the simulator's kernel decide over.

:func:`catanc.control.policy.slot_rules` states what each boundary of a shared core's period decides;
:func:`lay_out_rules` writes those rules, for one schedule version of one core, into three arrays
indexed ``[version, core, boundary]`` (:func:`empty_rules` makes them), and
:mod:`catanc.control.compiled_policy` decides over them, writing a boundary's actions (:data:`ACTIONS`).
numpy only: the enforcer that links the walk's object code imports no numba.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from catanc.control.policy import SlotRule

IntArray = npt.NDArray[np.int64]

NONE = -1
"""An integer that is not there: no subchain (the end of the last slice), no thief, nothing raised."""

# What a boundary does, as the compiled policy writes it: actions[...], an int64 array of ACTIONS.
RAISE = 0  # the subchain whose threads run raised on the core now (NONE: none, at the end of the last slice)
HANDOVER = 1  # 1 if the core changes owner: the previous owner's threads go back to their resting level
LOWER = 2  # the previous owner when it changes (NONE: none was raised, or the owner stays)
TRIGGER = 3  # the subchain whose head is triggered now, at its slot (NONE: none)
STEAL = 4  # 1 if the owner is a late subchain that took another's slot
ACTIONS = 5


def empty_rules(versions: int, cores: int, slots: int) -> tuple[IntArray, IntArray, IntArray]:
    """Room for ``versions`` schedules of ``cores`` cores with up to ``slots`` slots each, no rule in it yet.

    - ``rule_sub`` ``[V, C, M + 1]``: the slot's subchain; :data:`NONE` at the end of the last slice;
    - ``rule_every`` ``[V, C, M + 1]``: its head is triggered there every k periods (0: never);
    - ``rule_thieves`` ``[V, C, M + 1, M]``: the subchains that take the slot when late, best first, NONE-padded.
    """
    return (
        np.full((versions, cores, slots + 1), NONE, dtype=np.int64),
        np.zeros((versions, cores, slots + 1), dtype=np.int64),
        np.full((versions, cores, slots + 1, slots), NONE, dtype=np.int64),
    )


def lay_out_rules(
    arrays: tuple[IntArray, IntArray, IntArray],
    v: int,
    c: int,
    rules: tuple[SlotRule, ...],
    index: Mapping[str, int],
) -> None:
    """Write ``rules`` (a core's :func:`~catanc.control.policy.slot_rules`) as version ``v`` of core ``c``;
    ``index``: a subchain's number in the arrays."""
    rule_sub, rule_every, rule_thieves = arrays
    if len(rules) > rule_sub.shape[2]:
        raise ValueError(f"{len(rules) - 1} slots on a core, room for {rule_sub.shape[2] - 1}")
    rule_sub[v, c] = NONE
    rule_every[v, c] = 0
    rule_thieves[v, c] = NONE
    for j, rule in enumerate(rules):
        if rule.subchain is None:
            continue
        rule_sub[v, c, j] = index[rule.subchain]
        rule_every[v, c, j] = rule.every or 0
        for t, thief in enumerate(rule.thieves):
            rule_thieves[v, c, j, t] = index[thief]
