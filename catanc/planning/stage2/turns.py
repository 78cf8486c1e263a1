"""An executor's thread on a shared core: its members' trigger spacing ``k`` traded, searched exactly.

Where an executor's nodes head subchains on one shared core, a run of one member holds the
thread while the others' triggers come and go (:mod:`catanc.model.executor_thread`): the plan's
objective as run (:func:`~catanc.model.executor_thread.as_run_objective`) is its objective with the
periods the thread's turns leave.  Triggering a member less often (a longer ``k``, so ``p = k T``)
lengthens its own period and shortens every other member's losses: the trade made here, once
Stage II has chosen the runs and schedule lengths (docs/explanation/executor-planning.md: those are still
chosen for the slot model's objective, so the plan is the best over ``k`` at them, not over
every plan).

The members' ``k`` are searched upward from the least that fits
(:func:`~catanc.planning.stage2.base.aligned_every`), depth first.  A floor ends each member's
search: the objective with the members at their planned periods (the deeper ones at their least)
and every other subchain at its period as run with the members spaced out the most.  A member's
period as run is never below its planned one, and another subchain's only shortens as the members
space out (fewer holds of the thread, later stealing, less load on the core), so no longer ``k``
beats the best found as run once the floor reaches it.  (The planned objective alone is a floor
too, but far lower where another thread's losses weigh: nav2d's Navigator walked ~230 ``k`` per
re-solve, 9 with this one.)  So does a ``k`` where a bound no longer holds (bounds only tighten
with periods).  Only the
members' ``k`` are searched: every other subchain keeps the least, whose own period a longer ``k``
only lengthens.  A member whose period nothing weighs could be spaced out for ever:
:data:`MOST_STEPS` ends it.  Its objective as run only falls with its ``k`` (the others lose less, and
nothing counts its own period), so its best is at the longest ``k`` allowed and its least ``k`` as
good is bisected: walked up one by one, two such members nested cost a million objectives as run.

The last member's search also ends where the objective as run stops falling once that member
loses no trigger itself.  Along its ``p = k T``, the others fixed: the thread's shares do not
depend on it (they count only the subchains outside the executor); each other member's rate
``1/p_i - loss/p`` and each victim's ``1/p_v - lost/p`` (or a batch victim's ``1 - steal/p``
share) make periods of the form ``1/(a - b/p)``, convex and falling in ``p``; its own period is
``p`` while it loses nothing, and it keeps losing nothing for longer ``p`` (its holds' count
``S/p`` only falls); a chain's response is a sum of periods and a maximum of them, convex and
growing in each.  So the objective as run is convex in ``k`` from there, and its first rise is
past its least.  (A member that loses triggers itself has a period ``p/(A + B p)`` there,
concave: the search goes on.)

Where several threads take turns on a layout's cores (nav2d's Mapper and Navigator processes), one
thread's members are searched exactly as above at a time, the others' ``k`` where their last search
left them, in rounds until a round gains nothing (:data:`MOST_ROUNDS` at most): nested, their
searches multiplied (nav2d, 2 cores: 713 objectives as run per plan instead of 78, the same ``k``).
The rounds are exact per thread, not over every thread's ``k`` at once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

from catanc.model.executor_thread import (
    CoreGroup,
    ThreadShape,
    as_run_objective,
    objective_with_periods,
    periods_as_run,
    thread_shapes,
)
from catanc.model.metrics import Timing, bound_scale, objective
from catanc.model.problem import Problem
from catanc.planning.order import priorities
from catanc.planning.stage2.base import Layout
from catanc.spec.language import Schedule

MOST_STEPS = 1000
"""At most this many ``k`` above the least per member (reached only where its period weighs nothing)."""

MOST_ROUNDS = 4
"""Rounds over the threads where several executors' threads share a layout's cores (each searched exactly)."""

ROUND_GAIN = 1e-9
"""A round that lowers the objective as run by less than this share ends the rounds."""


class Spacing(NamedTuple):
    """The trade's answer: the objective as run, each member's ``k``, and every subchain's period as run there
    (what the objective as run scored: the plan reports them without scoring them again)."""

    as_run: float
    every: dict[str, int]
    periods: dict[str, float]


def member_blocks(problem: Problem, members: tuple[str, ...]) -> list[tuple[str, ...]]:
    """The members by the thread whose turns they take: executors that share a member's subchain are one
    (their losses meet in it), each block in ``members``' order."""
    blocks: list[set[str]] = []
    for executor in problem.executors:
        block = {name for name in executor.subchains if name in members}
        for other in [b for b in blocks if b & block]:
            block |= other
            blocks.remove(other)
        if block:
            blocks.append(block)
    order = {name: index for index, name in enumerate(members)}
    return sorted((tuple(sorted(block, key=order.__getitem__)) for block in blocks), key=lambda b: order[b[0]])


@dataclass(frozen=True)
class LayoutTurns:
    """The executors whose threads a layout's shared cores share: their core groups and searched members."""

    groups: tuple[CoreGroup, ...]
    members: tuple[str, ...]  # non-batch shared subchains holding an executor's node, in problem order
    shapes: tuple[ThreadShape, ...]  # the threads on these groups (built once: scored thousands of times)

    @staticmethod
    def of(problem: Problem, layout: Layout, schedule: Schedule) -> LayoutTurns | None:
        """None where no executor spans two subchains of one shared core (nothing lost to a thread).

        Such a layout's plans are scored as run even where no member has a ``k`` to trade (every member
        batch): its ``members`` are then empty.
        """
        core_of = {name: core.core for core in layout.shared for name in core.subchains}
        shared_thread = False
        members: set[str] = set()
        for executor in problem.executors:
            subs = executor.subchains
            if len(subs) < 2 or not all(name in core_of for name in subs):
                continue
            if len({core_of[name] for name in subs}) == 1:
                shared_thread = True
                members.update(name for name in subs if not problem.subchain(name).batch)
        if not shared_thread:
            return None
        ranks = priorities(problem, schedule, problem.importance())  # only where a thread is shared
        groups = tuple(
            CoreGroup(
                core.subchains, 1, {name: ranks[name] for name in core.subchains}, schedule.stealing, schedule.slack
            )
            for core in layout.shared
        )
        members_in_order = tuple(sub.name for sub in problem.subchains if sub.name in members)
        return LayoutTurns(groups, members_in_order, thread_shapes(problem, groups))

    def as_run(self, problem: Problem, timings: Mapping[str, Timing]) -> float:
        return as_run_objective(problem, timings, self.groups, shapes=self.shapes)

    def periods(self, problem: Problem, timings: Mapping[str, Timing]) -> dict[str, float]:
        """Each subchain's period as run at ``timings`` (:func:`periods_as_run` over these core groups)."""
        return periods_as_run(problem, timings, self.groups, shapes=self.shapes)

    def best_spacing(
        self,
        problem: Problem,
        timings: Mapping[str, Timing],
        lengths: Mapping[str, float],
        least: Mapping[str, int],
        allowed_scale: float,
        *,
        hint: Mapping[str, int] | None = None,
    ) -> Spacing | None:
        """The least objective as run over the members' ``k >= least``, those ``k`` and the periods as run there,
        each member's period ``k T`` with ``T = lengths[member]`` (None: ``least`` itself misses the bounds scaled
        by ``allowed_scale``).

        ``timings`` holds every subchain's timing with the members at ``least``; latencies do not change.
        ``hint`` (a re-solve's last ``k``): where the last member loses no trigger at its least, the objective
        as run is convex along its ``k`` (the module's docstring), so its search walks downhill from the hint
        instead of up from the least: the same ``k`` (the least of the best), in a few steps where the hint is
        near it.
        """
        if not self.members:  # nothing to trade: the objective as run at ``timings``
            if bound_scale(problem, timings) > allowed_scale:
                return None
            periods = self.periods(problem, timings)
            return Spacing(objective_with_periods(problem, timings, periods), dict(least), periods)
        blocks = member_blocks(problem, self.members)
        # Scored spacings by every member's k: one block's search meets points of another's (its start, at
        # least: the others where their search left them).
        scored: dict[tuple[int, ...], tuple[float, dict[str, float]]] = {}
        if len(blocks) == 1:
            return self._exact(
                problem, timings, lengths, least, allowed_scale, names=self.members, hint=hint, scored=scored
            )
        # One thread's members at a time, the others where the last search left them, until none gains.
        best: Spacing | None = None
        spacing = dict(least)
        searched_at: dict[tuple[str, ...], dict[str, int]] = {}  # per block: the others' k when it was searched
        for _ in range(MOST_ROUNDS):
            gained = False
            for block in blocks:
                fixed = {name: spacing[name] for name in self.members if name not in block}
                if searched_at.get(block) == fixed:
                    continue  # the same search again
                searched_at[block] = fixed
                placed = {
                    name: Timing(spacing[name] * lengths[name], timing.latency_ms) if name in self.members else timing
                    for name, timing in timings.items()
                }
                found = self._exact(
                    problem, placed, lengths, {**least, **fixed}, allowed_scale, names=block, hint=hint, scored=scored
                )
                if found is not None and (best is None or found.as_run < best.as_run * (1 - ROUND_GAIN)):
                    best, spacing, gained = found, dict(found.every), True
            if not gained:
                break
        return best

    def _floor_periods(
        self,
        problem: Problem,
        timings: Mapping[str, Timing],
        lengths: Mapping[str, float],
        least: Mapping[str, int],
        names: tuple[str, ...],
    ) -> dict[str, float]:
        """Each subchain's period as run with ``names`` at the longest ``k`` searched: a floor, for every other
        subchain, of its period as run at any ``k`` of theirs searched.  A longer member period means fewer holds
        of the thread, a later start of a waiting member's stealing and less load on the core, so another
        subchain only loses less (:mod:`catanc.model.executor_thread`)."""
        spaced = dict(timings)
        for name in names:
            spaced[name] = Timing((least[name] + MOST_STEPS) * lengths[name], timings[name].latency_ms)
        return self.periods(problem, spaced)

    def _exact(
        self,
        problem: Problem,
        timings: Mapping[str, Timing],
        lengths: Mapping[str, float],
        least: Mapping[str, int],
        allowed_scale: float,
        *,
        names: tuple[str, ...],
        hint: Mapping[str, int] | None,
        scored: dict[tuple[int, ...], tuple[float, dict[str, float]]],
    ) -> Spacing | None:
        """:meth:`best_spacing` over ``names`` alone, depth first; every other member stays at ``least``.

        ``scored`` holds the objectives and periods as run already scored, by every member's ``k`` (``timings``
        is the same at the same ``k``: each member's period is its ``k`` times its ``T``)."""
        trial = dict(timings)
        best: Spacing | None = None
        spacing = dict(least)
        importance = problem.importance()
        weightless = {name for name in names if importance[name] == 0.0}
        floor: dict[str, float] = {}  # built at its first use: a hint's downhill walk needs none

        def lower_bound() -> float:
            """No objective as run over ``k`` at least the placed ones is below this: ``names`` at their planned
            periods, every other subchain at its period as run with ``names`` spaced out the most."""
            if not floor:
                floor.update(self._floor_periods(problem, timings, lengths, least, names))
            return objective(
                problem,
                {
                    key: t if key in names else Timing(max(t.period_ms, floor[key]), t.latency_ms)
                    for key, t in trial.items()
                },
            )

        def place(name: str, every: int) -> None:
            spacing[name] = every
            trial[name] = Timing(every * lengths[name], trial[name].latency_ms)

        def as_run_now() -> tuple[float, dict[str, float]]:
            """The objective as run at ``trial``, and the periods as run it scores."""
            key = tuple(spacing[name] for name in self.members)  # walks meet again
            if key not in scored:
                periods = self.periods(problem, trial)
                scored[key] = objective_with_periods(problem, trial, periods), periods
            return scored[key]

        def as_run_at(name: str, every: int) -> tuple[float, bool] | None:
            """The objective as run with ``name`` at ``every`` and whether ``name`` loses no trigger there
            (None: a bound no longer holds, nor for any longer ``k``)."""
            place(name, every)
            if bound_scale(problem, trial) > allowed_scale:
                return None
            value, periods = as_run_now()
            return value, periods[name] <= trial[name].period_ms

        def offer() -> None:
            """The spacing placed, scored already, if it is the best so far."""
            nonlocal best
            value, periods = as_run_now()
            if best is None or value < best.as_run:
                best = Spacing(value, dict(spacing), periods)

        def descend(name: str, start: int) -> bool:
            """The last member's best ``k`` by walking downhill from ``start``; False where its objective as
            run is not known to be convex (it loses triggers at its least)."""
            low, high = least[name], least[name] + MOST_STEPS
            found = as_run_at(name, low)
            if found is None:  # no k meets the bounds
                place(name, low)
                return True
            if not found[1]:
                return False
            values = {low: found[0]}

            def at(every: int) -> float:  # +inf past the bounds: still convex over the integers
                if every not in values:
                    here = as_run_at(name, every)
                    values[every] = math.inf if here is None else here[0]
                return values[every]

            every = min(max(start, low), high)
            while every > low and at(every - 1) <= at(every):
                every -= 1  # to the least of equal values, as the upward search keeps the first
            while every < high and at(every + 1) < at(every):
                every += 1
            if math.isfinite(at(every)):
                place(name, every)
                offer()
            place(name, low)
            return True

        def reset_below(level: int) -> None:
            for deeper in names[level + 1 :]:
                place(deeper, least[deeper])

        def exact_below(level: int) -> float:
            """The least objective as run over the members below ``level``, the others placed (no outer bound)."""
            nonlocal best
            if level == len(names) - 1:
                return as_run_now()[0]
            outer, best = best, None
            visit(level + 1)
            found, best = best, outer
            return math.inf if found is None else found.as_run

        def spread(level: int) -> None:
            """A member whose period nothing weighs: the objective as run only falls with its ``k`` (the others
            lose less), so its best is at the longest ``k`` the bounds and :data:`MOST_STEPS` allow, and the
            least ``k`` as good is found by bisection: ~10 searches below it instead of up to 1000."""
            name = names[level]

            def fits(every: int) -> bool:
                place(name, every)
                reset_below(level)
                return bound_scale(problem, trial) <= allowed_scale

            def value(every: int) -> float:
                fits(every)
                return exact_below(level)

            low, high = least[name], least[name] + MOST_STEPS
            if not fits(low) or (best is not None and lower_bound() >= best.as_run):
                place(name, low)  # no k meets the bounds; or none beats the best (its planned objective is flat)
                return
            while low < high:  # the longest k that meets the bounds (they only tighten with periods)
                middle = (low + high + 1) // 2
                low, high = (middle, high) if fits(middle) else (low, middle - 1)
            target = value(high)
            low = least[name]
            while low < high:
                middle = (low + high) // 2
                low, high = (low, middle) if value(middle) <= target else (middle + 1, high)
            fits(low)
            if level == len(names) - 1:
                offer()
            else:
                visit(level + 1)
            place(name, least[name])

        def visit(level: int) -> None:
            name, last = names[level], level == len(names) - 1
            if name in weightless:
                spread(level)
                return
            if last and hint is not None and name in hint and descend(name, hint[name]):
                return
            previous = math.inf
            for every in range(least[name], least[name] + MOST_STEPS + 1):
                place(name, every)
                for deeper in names[level + 1 :]:
                    place(deeper, least[deeper])
                if bound_scale(problem, trial) > allowed_scale:
                    break  # and every longer k: bounds only tighten with periods
                if not last:
                    if best is not None and lower_bound() >= best.as_run:
                        break  # and every longer k: the planned objective grows, the one as run is above it
                    visit(level + 1)
                    continue
                value, periods = as_run_now()
                if best is None or value < best.as_run:
                    offer()  # its planned objective is below it: no need to look
                elif lower_bound() >= best.as_run:
                    break  # as above
                if value >= previous and periods[name] <= trial[name].period_ms:
                    break  # convex from here on (the module's docstring): past its least
                previous = value
            place(name, least[name])

        visit(0)
        return best
