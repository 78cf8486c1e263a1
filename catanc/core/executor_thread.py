"""What one executor thread serving several subchains does to their rates (catan-model.md section 6).

A single-threaded executor runs one callback at a time.  Where its nodes head subchains of
their own on a shared core, a member ``j``'s run holds the thread for its *span*
``S_j = c_j / s``: its compute at the share ``s`` of a core the thread gets while it runs.  The
thread runs in its own slots and, at its resting level, in every moment the core's other
subchains leave free, so ``s`` is what they leave: ``min(1, m - sum_k c_k / p_k)`` over the other
subchains ``k`` on the ``m`` cores, and never less than its own slices.

A member ``i`` triggered every ``p_i`` (its subchain's period) meets each of ``j``'s spans with
``N`` of its triggers, ``floor`` or ``ceil`` of ``S_j / p_i`` (any phase), ``S_j / p_i`` on average.
The first starts a run that waits for the thread; the second is kept as the head's one pending
trigger (catan-model.md section 6: a head whose run is in flight is not triggered again, one
trigger is held); the rest are lost.  So ``i`` loses ``max(0, S_j / p_i - 2)`` triggers per run of
``j`` (exactly: ``N >= 2`` whenever ``S_j >= 2 p_i``):

    rate_i = 1 / p_i - sum_{j != i} max(0, S_j / p_i - 2) / p_j

and a run of ``i`` waits up to ``max_j S_j``.  Spans of two other members are counted as if they
never meet (the sum): the model is meant for an executor whose long run blocks short ones, as
nav2d's GM blocks GL.  The share is a floor: the others may leave more than their planned
utilisation while a run holds the thread (the simulator's nav2d on 1 core: GM's 150 ms take
~205 ms, not the 265 ms this share gives).  Pure arithmetic, checked against
the simulator in the tests.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from catanc.core.problem import Executor, Problem


@dataclass(frozen=True)
class Member:
    """A node of the executor that heads a subchain: how often it is triggered and what it computes."""

    node: str
    period_ms: float  # its subchain's planned period: one trigger each
    compute_ms: float  # one run's compute (the node's own, not its subchain's)


@dataclass(frozen=True)
class MemberRate:
    """What the thread's turns leave of one member's planned rate."""

    node: str
    planned_hz: float
    rate_hz: float  # triggers that run; the rest are lost while the thread is busy
    longest_wait_ms: float  # the longest span of another member: what a run of this one may wait
    blocked_by: str  # the member with that span

    @property
    def lost_share(self) -> float:
        return 1.0 - self.rate_hz / self.planned_hz


def thread_share(own_share: float, others_utilisation: float, cores: int) -> float:
    """The share of a core the thread gets while it runs: what the other subchains leave, at least its slices."""
    return min(1.0, max(own_share, cores - others_utilisation))


def span_ms(member: Member, share: float) -> float:
    """How long one run of ``member`` holds the thread (wall time) at ``share`` of a core."""
    return member.compute_ms / share


def member_rates(members: Sequence[Member], share: float) -> list[MemberRate]:
    """Each member's rate and longest wait when the others' runs hold the thread (in ``members`` order)."""
    if not 0.0 < share <= 1.0:
        raise ValueError(f"a thread's share of a core is in (0, 1], not {share}")
    if len(members) < 2:
        raise ValueError("an executor's thread is shared by two members or more")
    rates = []
    for member in members:
        others = [other for other in members if other is not member]
        lost_hz = math.fsum(
            1000.0 / other.period_ms * max(0.0, span_ms(other, share) / member.period_ms - 2.0) for other in others
        )
        longest = max(others, key=lambda other: span_ms(other, share))
        planned = 1000.0 / member.period_ms
        rates.append(
            MemberRate(
                node=member.node,
                planned_hz=planned,
                rate_hz=max(0.0, planned - lost_hz),
                longest_wait_ms=span_ms(longest, share),
                blocked_by=longest.node,
            )
        )
    return rates


def utilisation(compute_ms: float, period_ms: float) -> float:
    """A subchain's busy share of a core: one run's compute every period."""
    return compute_ms / period_ms if math.isfinite(period_ms) else 0.0


# --------------------------------------------------------------------------- on a planned problem


@dataclass(frozen=True)
class CoreGroup:
    """Shared subchains on one set of cores: the core group an executor's subchains sit in."""

    subchains: tuple[str, ...]
    cores: int


@dataclass(frozen=True)
class ExecutorTurns:
    """An executor's thread under a plan's periods: its share of a core and each node's predicted rate."""

    executor: Executor
    share: float  # of a core, while one of its runs holds the thread
    rates: tuple[MemberRate, ...]  # in the executor's node order
    compute_ms: dict[str, float]  # each node's run


def executor_turns(
    problem: Problem, executor: Executor, periods: Mapping[str, float], groups: Iterable[CoreGroup]
) -> ExecutorTurns | None:
    """The thread's turns at ``periods`` (per subchain, ms); None unless the executor's nodes span two or
    more subchains of one core group in ``groups``.

    The share is what the group's other subchains leave (it is never below the executor's own
    slices, which fit beside the others' utilisation in every plan).
    """
    subs = executor.subchains
    if len(subs) < 2:
        return None
    group = next((group for group in groups if subs[0] in group.subchains), None)
    if group is None or not set(subs) <= set(group.subchains):
        return None
    others = math.fsum(
        utilisation(problem.subchain(name).compute_ms, periods[name]) for name in group.subchains if name not in subs
    )
    share = thread_share(0.0, others, group.cores)
    members: dict[str, Member] = {}
    for name in subs:
        sub = problem.subchain(name)
        for node, compute in zip(sub.nodes, sub.node_compute_ms, strict=True):
            if node in executor.nodes:
                members[node] = Member(node, periods[name], compute)
    ordered = [members[node] for node in executor.nodes]
    return ExecutorTurns(
        executor, share, tuple(member_rates(ordered, share)), {member.node: member.compute_ms for member in ordered}
    )


def periods_as_run(problem: Problem, periods: Mapping[str, float], groups: Iterable[CoreGroup]) -> dict[str, float]:
    """Each subchain's period as it runs: where an executor's node heads a subchain and loses triggers
    to the others' runs, one over its predicted rate; every other period as planned.

    A node that does not head its subchain waits instead (its head loses the triggers, which the
    model does not count): its subchain keeps its planned period.
    """
    groups = list(groups)
    result = dict(periods)
    for executor in problem.executors:
        turns = executor_turns(problem, executor, periods, groups)
        if turns is None:
            continue
        for rate in turns.rates:
            sub = next(sub for sub in problem.subchains if rate.node in sub.nodes)
            if sub.nodes[0] == rate.node and rate.rate_hz < rate.planned_hz:
                result[sub.name] = 1000.0 / rate.rate_hz if rate.rate_hz > 0.0 else math.inf
    return result
