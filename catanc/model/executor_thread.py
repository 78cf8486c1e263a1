"""What one executor thread serving several subchains does to their rates (docs/explanation/model.md section 6).

A single-threaded executor runs one callback at a time.  Where its nodes head subchains of their
own on a shared core group, a member ``j``'s run holds the thread until its compute ``c_j`` is
done, and a member ``i`` triggered meanwhile waits.  The thread runs in its own slots and, at its
resting level, in every moment the group's other subchains leave of what the app gets: a share
``s0_i = min(1 - s, m (1 - s) - sum_k c_k / p_k)`` of a core over the other subchains ``k`` on the
``m`` cores, where ``s`` is the plan's slack (the share of each core the app's SCHED_FIFO threads
never get: the kernel's RT limit leaves it to others, and the runtime's own CPU is in it).  Once ``i``'s
waiting run is late (its subchain's latency ``l_i`` after its trigger, which comes ``p_i / 2``
into the run on average: ``d_i = p_i / 2 + l_i``), ``i`` steals the slots of the subchains it
outranks (docs/explanation/model.md section 5) and the thread, the only one ``i`` has, runs in them too: a
share ``s1_i`` that leaves out only the subchains outranking ``i``.  So the run holds the thread

    S_ij = c_j / s0_i                          if c_j <= s0_i d_i
    S_ij = d_i + (c_j - s0_i d_i) / s1_i       otherwise

``i`` meets each such hold with ``N`` of its triggers, ``floor`` or ``ceil`` of ``S_ij / p_i`` (any
phase).  The first starts a run that waits; the second is kept as the head's one pending trigger
(a head whose run is in flight is not triggered again, one trigger is held); the rest are lost:
``max(0, S_ij / p_i - 2)`` per run of ``j`` (exact: ``N >= 2`` whenever ``S_ij >= 2 p_i``):

    rate_i = 1 / p_i - sum_{j != i} max(0, S_ij / p_i - 2) / p_j

A subchain ``k`` that ``i`` outranks loses its slots for ``S_ij - d_i`` per run of ``j``: triggered
at its slot every ``p_k``, it loses ``max(0, (S_ij - d_i) / p_k - 2)`` triggers per run of ``j`` the
same way (a batch one loses that share of its time instead).  Holds of two other members are
counted as if they never meet (the sum): the model is meant for an executor whose long run
blocks short ones, as nav2d's GM blocks GL.  Checked against the simulator in the tests (nav2d,
compute times fixed: GL and NC within 7% on 1, 2 and 3 cores).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from catanc.model.metrics import Timing, objective
from catanc.model.problem import Executor, Problem


@dataclass(frozen=True)
class Member:
    """A node of the executor that heads a subchain: how it is triggered, what it computes, what it gets."""

    node: str
    period_ms: float  # its subchain's planned period: one trigger each
    compute_ms: float  # one run's compute (the node's own, not its subchain's)
    latency_ms: float = 0.0  # its subchain's planned latency: a run waiting longer is late
    share: float = 1.0  # of a core the thread gets while a run of this member waits
    stealing_share: float | None = None  # once that run is late and steals (None: no stealing)

    def delay_ms(self) -> float:
        """When a waiting run of this member starts to steal, from the start of the hold, on average."""
        return self.period_ms / 2.0 + self.latency_ms


@dataclass(frozen=True)
class MemberRate:
    """What the thread's turns leave of one member's planned rate."""

    node: str
    planned_hz: float
    rate_hz: float  # triggers that run; the rest are lost while the thread is busy
    longest_wait_ms: float  # the longest hold of another member: what a run of this one may wait
    blocked_by: str  # the member with that hold

    @property
    def lost_share(self) -> float:
        return 1.0 - self.rate_hz / self.planned_hz


def thread_share(others_utilisation: float, cores: int, slack: float = 0.0) -> float:
    """The share of a core the thread gets while it runs: what the other subchains leave of the app's share
    of the cores, ``1 - slack`` each (one core's at most)."""
    app = 1.0 - slack
    return min(app, cores * app - others_utilisation)


def held_ms(blocker: Member, waiter: Member) -> float:
    """How long one run of ``blocker`` holds the thread (wall time) while a run of ``waiter`` waits."""
    before, after = waiter.share, waiter.stealing_share
    delay = waiter.delay_ms()
    if after is None or after <= before or blocker.compute_ms <= before * delay:
        return blocker.compute_ms / before
    return delay + (blocker.compute_ms - before * delay) / after


def stealing_ms(blocker: Member, waiter: Member) -> float:
    """How long ``waiter``'s late run steals slots during one hold of ``blocker`` (0 without stealing)."""
    if waiter.stealing_share is None or waiter.stealing_share <= waiter.share:
        return 0.0
    return max(0.0, held_ms(blocker, waiter) - waiter.delay_ms())


def lost_per_hold(hold_ms: float, period_ms: float) -> float:
    """Triggers every ``period_ms`` lost during one hold: all that meet it but the waiting one and the pending one."""
    return max(0.0, hold_ms / period_ms - 2.0)


def member_rates(members: Sequence[Member]) -> list[MemberRate]:
    """Each member's rate and longest wait when the others' runs hold the thread (in ``members`` order)."""
    if len(members) < 2:
        raise ValueError("an executor's thread is shared by two members or more")
    for member in members:
        for share in (member.share, member.stealing_share):
            if share is not None and not 0.0 < share <= 1.0:
                raise ValueError(f"{member.node}: a thread's share of a core is in (0, 1], not {share}")
    rates = []
    for member in members:
        holds = [(held_ms(other, member), other) for other in members if other is not member]
        lost_hz = math.fsum(1000.0 / other.period_ms * lost_per_hold(hold, member.period_ms) for hold, other in holds)
        longest_ms, longest = holds[0]
        for hold, other in holds[1:]:  # the longest hold, the first of equal ones
            if hold > longest_ms:
                longest_ms, longest = hold, other
        planned = 1000.0 / member.period_ms
        rates.append(MemberRate(member.node, planned, max(0.0, planned - lost_hz), longest_ms, longest.node))
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
    priorities: Mapping[str, int]  # stealing priority: higher steals from lower
    stealing: bool = True
    slack: float = 0.0  # of each core, the share the app never gets (the plan's slack)


@dataclass(frozen=True)
class ExecutorTurns:
    """An executor's thread under a plan's timings: each node's predicted rate, and what its waits steal."""

    executor: Executor
    members: tuple[Member, ...]  # in the executor's node order
    rates: tuple[MemberRate, ...]  # the same order
    stolen_hz: dict[str, float]  # per subchain outside the executor: triggers a second lost to stealing
    stolen_share: dict[str, float]  # per such subchain: the share of its time its slots are stolen

    def member(self, node: str) -> Member:
        return next(member for member in self.members if member.node == node)


@dataclass(frozen=True)
class MemberShape:
    """What of a member does not change with the timings: its node, subchain, compute and the others it ranks
    below and above on its core group."""

    node: str
    subchain: str
    compute_ms: float
    above: tuple[str, ...]  # the group's other subchains outranking it (their load is what it keeps out)
    outranked: tuple[str, ...]  # those its late run steals from (none without stealing)
    heads: bool = True  # whether its node heads its subchain (a trigger it loses is one its subchain loses)


@dataclass(frozen=True)
class ThreadShape:
    """One executor's thread on its core group, as far as the timings do not change it: built once, evaluated at
    many timings (Stage II scores thousands of trigger spacings with one problem and one layout)."""

    executor: Executor
    group: CoreGroup
    others: tuple[str, ...]  # the group's subchains outside the executor, in group order
    members: tuple[MemberShape, ...]  # in the executor's node order
    others_compute_ms: tuple[float, ...]  # per other subchain, its compute per run
    batch: frozenset[str] = frozenset()  # the batch ones among them (they lose slot time, not triggers)


def thread_shape(problem: Problem, executor: Executor, groups: Iterable[CoreGroup]) -> ThreadShape | None:
    """The executor's thread on the core group in ``groups`` holding all its subchains; None unless its nodes
    span two or more subchains of one such group."""
    subs = executor.subchains
    if len(subs) < 2:
        return None
    group = next((group for group in groups if subs[0] in group.subchains), None)
    if group is None or not set(subs) <= set(group.subchains):
        return None
    others = tuple(name for name in group.subchains if name not in subs)
    members: dict[str, MemberShape] = {}
    for name in subs:
        sub = problem.subchain(name)
        rank = group.priorities[name]
        above = tuple(other for other in others if group.priorities[other] > rank)
        outranked = tuple(other for other in others if group.priorities[other] < rank) if group.stealing else ()
        for node, compute in zip(sub.nodes, sub.node_compute_ms, strict=True):
            if node in executor.nodes:
                members[node] = MemberShape(node, name, compute, above, outranked, sub.nodes[0] == node)
    return ThreadShape(
        executor,
        group,
        others,
        tuple(members[node] for node in executor.nodes),
        tuple(problem.subchain(name).compute_ms for name in others),
        frozenset(name for name in others if problem.subchain(name).batch),
    )


def thread_shapes(problem: Problem, groups: Iterable[CoreGroup]) -> tuple[ThreadShape, ...]:
    """Every executor's :func:`thread_shape` that has one, in the problem's executor order."""
    groups = list(groups)
    return tuple(shape for e in problem.executors if (shape := thread_shape(problem, e, groups)) is not None)


def turns_of(shape: ThreadShape, timings: Mapping[str, Timing]) -> ExecutorTurns:
    """The thread's turns at ``timings`` (per subchain)."""
    group = shape.group
    load = {
        name: utilisation(compute, timings[name].period_ms)
        for name, compute in zip(shape.others, shape.others_compute_ms, strict=True)
    }
    share = thread_share(math.fsum(load.values()), group.cores, group.slack)
    built = []
    for member in shape.members:
        timing = timings[member.subchain]
        stealing = None
        if member.outranked:
            stealing = thread_share(math.fsum([load[other] for other in member.above]), group.cores, group.slack)
        built.append(Member(member.node, timing.period_ms, member.compute_ms, timing.latency_ms, share, stealing))
    ordered = tuple(built)
    stolen_hz: dict[str, float] = {}
    stolen_share: dict[str, float] = {}
    for waiter, waiter_shape in zip(ordered, shape.members, strict=True):
        if not waiter_shape.outranked:
            continue
        for blocker in ordered:
            if blocker is waiter:
                continue
            steal = stealing_ms(blocker, waiter)
            runs = 1000.0 / blocker.period_ms
            for name in waiter_shape.outranked:
                lost = runs * lost_per_hold(steal, timings[name].period_ms)
                stolen_hz[name] = stolen_hz.get(name, 0.0) + lost
                stolen_share[name] = stolen_share.get(name, 0.0) + runs * steal / 1000.0
    return ExecutorTurns(shape.executor, ordered, tuple(member_rates(ordered)), stolen_hz, stolen_share)


def executor_turns(
    problem: Problem, executor: Executor, timings: Mapping[str, Timing], groups: Iterable[CoreGroup]
) -> ExecutorTurns | None:
    """The thread's turns at ``timings`` (per subchain); None unless the executor's nodes span two or more
    subchains of one core group in ``groups``."""
    shape = thread_shape(problem, executor, groups)
    return None if shape is None else turns_of(shape, timings)


def periods_as_run(
    problem: Problem,
    timings: Mapping[str, Timing],
    groups: Iterable[CoreGroup],
    *,
    shapes: tuple[ThreadShape, ...] | None = None,
) -> dict[str, float]:
    """Each subchain's period as it runs: where an executor's node heads a subchain, one over its predicted
    rate; where an executor's late run steals a subchain's slots, one over what it keeps; else as planned.

    A node that does not head its subchain waits instead (its head loses the triggers, which the
    model does not count): its subchain keeps its planned period.  Where several executors' threads
    take from one subchain (two processes' executors on one core), their losses add up, as the
    losses to two members of one executor do.  ``shapes``: :func:`thread_shapes` of ``groups``, where the
    caller evaluates many timings.
    """
    if shapes is None:
        shapes = thread_shapes(problem, groups)
    lost_hz: dict[str, float] = {}  # triggers a second lost, per subchain
    lost_share: dict[str, float] = {}  # per batch subchain: the share of its time its slots are stolen
    for shape in shapes:
        turns = turns_of(shape, timings)
        for rate, member in zip(turns.rates, shape.members, strict=True):
            if member.heads and rate.rate_hz < rate.planned_hz:
                lost_hz[member.subchain] = lost_hz.get(member.subchain, 0.0) + rate.planned_hz - rate.rate_hz
        for name, lost in turns.stolen_hz.items():
            if name in shape.batch:  # it runs whenever it has its slots: it loses time, not triggers
                lost_share[name] = lost_share.get(name, 0.0) + turns.stolen_share[name]
            elif lost > 0.0:
                lost_hz[name] = lost_hz.get(name, 0.0) + lost
    result = {name: timing.period_ms for name, timing in timings.items()}
    for name in lost_hz.keys() | lost_share.keys():
        period = _period(max(0.0, 1000.0 / timings[name].period_ms - lost_hz.get(name, 0.0)))
        share = lost_share.get(name, 0.0)
        result[name] = period / (1.0 - share) if share < 1.0 else math.inf
    return result


def as_run_objective(
    problem: Problem,
    timings: Mapping[str, Timing],
    groups: Iterable[CoreGroup],
    *,
    shapes: tuple[ThreadShape, ...] | None = None,
) -> float:
    """The objective at ``timings`` with each period as it runs (:func:`periods_as_run`), latencies as planned."""
    return objective_with_periods(problem, timings, periods_as_run(problem, timings, groups, shapes=shapes))


def objective_with_periods(problem: Problem, timings: Mapping[str, Timing], periods: Mapping[str, float]) -> float:
    """The objective at ``timings`` with each period as in ``periods`` (as run), latencies as planned."""
    return objective(problem, {name: Timing(periods[name], timing.latency_ms) for name, timing in timings.items()})


def _period(rate_hz: float) -> float:
    return 1000.0 / rate_hz if rate_hz > 0.0 else math.inf
