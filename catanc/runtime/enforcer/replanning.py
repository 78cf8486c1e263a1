"""When the enforcer re-plans, and what it asks the re-optimiser (docs/explanation/model.md section 5).

The solvers run in a child process (:class:`~catanc.runtime.enforcer.reoptimiser.PlannerProcess`); the
enforcer's loop never waits for them.  :class:`Replanning` decides what to ask and when: Stage I
for a new number of cores (``set-cores``, or the process's CPU set changed), a re-pin for other
CPUs of the same number, and otherwise the :class:`~catanc.control.policy.Cadence`'s Stage II and
Stage I re-solves, one request at a time; and when the runtime's measured costs call for a
switch_ms or slack 10% above the plan's or 25% below it, a re-plan with them (never below the
spec's).  The loop sends the request, reads the answer when the child's descriptor is readable, and
swaps the new schedule in (an answer with an error keeps the last good plan and its slots).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal

from catanc.control.policy import Cadence
from catanc.runtime.enforcer.costs import measured_profile, rt_limit, this_machine
from catanc.runtime.enforcer.reoptimiser import Answer, PlannerProcess, Request
from catanc.spec.language import Runtime, Schedule
from catanc.spec.machine import costs as machine_costs

COSTS_RISE = 0.10
"""Re-plan with the runtime's measured costs when they call for a switch_ms or slack 10% above the plan's: the
plan no longer covers them."""
COSTS_FALL = 0.25
"""... or 25% below it: the plan reserves more than the runtime costs.  Wider than the rise's band so that a plan
raised to a measurement is not re-planned at the next one a little below it: the enforcer's CPU share moves by
10-20% between re-solves in a busy minute, and each re-plan with new costs searches both stages with Stage II's
models built again and moves the rates and slots a little."""


@dataclass(frozen=True)
class Step:
    """What housekeeping should do about the plan now."""

    request: Request | None = None  # ask the re-optimiser this
    repin: bool = False  # as many CPUs as before, but others: the same plan, pinned to them


class Replanning:
    """The re-optimiser's handle and its cadence; the CPUs plan cores run on."""

    def __init__(self, planner: PlannerProcess, runtime: Runtime, cpus: Iterable[int], note: Callable[[str], None]):
        self.planner = planner
        self.cadence = Cadence.start(runtime)
        self.answer: Answer = planner.initial
        self.asked: Request | None = None  # what the re-optimiser is working on
        self.requested_cores: int | None = None  # from set-cores
        self.last_resolve_s: float | None = None
        self.cpu_ids = sorted(cpus)  # plan core i runs on the i-th CPU this process may use
        self.note = note
        self.rt = rt_limit()
        self.machine = this_machine()

    def measured_costs(self, summary: dict[str, Any], schedule: Schedule) -> tuple[float, float] | None:
        """The ``(switch_ms, slack)`` the runtime's measured costs call for (never below ``schedule``'s), once there
        are enough of them (:func:`~catanc.runtime.enforcer.costs.measured_profile`).

        The machine profile's formulas (:func:`catanc.spec.machine.costs`): the enforcer's own CPU share of
        its core comes off the kernel's real-time budget first; a slot pays its head's hop beyond that CPU.
        """
        profile = measured_profile(summary, rt=self.rt, machine=self.machine)
        if profile is None:
            return None
        found = machine_costs(schedule, profile)
        return None if found.slack >= 1.0 else (found.switch_ms, found.slack)

    def fit_cores(self, cores: int) -> int:
        """``cores``, or fewer if this process may use fewer CPUs: two plan cores never share one CPU."""
        if cores <= len(self.cpu_ids):
            return cores
        self.note(
            f"planning for {len(self.cpu_ids)} core(s), not {cores}: this process may use only CPUs {self.cpu_ids}"
        )
        return len(self.cpu_ids)

    def step(
        self,
        since_ms: float,
        cpus: frozenset[int],
        planned_cores: int,
        estimates: Callable[[], dict[str, float]],
        costs: Callable[[], tuple[float, float] | None] = lambda: None,
    ) -> Step:
        """What to do now (``since_ms`` into the run, ``cpus`` the process may use): nothing while a request is out.

        ``costs``: the ``(switch_ms, slack)`` the runtime's measured costs call for (asked only when a
        re-solve is due); when they rise above the plan's by more than :data:`COSTS_RISE` or fall below
        it by more than :data:`COSTS_FALL`, the re-solve is a reconfigure (both stages, the models built again)
        with them instead.
        """
        if self.asked is not None:
            return Step()
        cores = None
        if self.requested_cores is not None:
            cores, self.requested_cores = self.requested_cores, None
        moved = cpus != frozenset(self.cpu_ids)
        if moved:
            self.cpu_ids = sorted(cpus)
            cores = len(cpus)
        if cores is not None:
            cores = self.fit_cores(cores)
        if cores is not None and cores != planned_cores:
            self.cadence.cores_changed(since_ms)
            return Step(self._request("reallocate", estimates(), cores, "cores"))
        if moved:
            return Step(repin=True)
        stage = self.cadence.due(since_ms)
        if stage is None:
            return Step()
        wanted = costs()
        if wanted is not None and self._costs_changed(wanted):
            self.cadence.solved("stage1", since_ms)
            return Step(self.reconfigure(*wanted, estimates()))
        self.cadence.solved(stage, since_ms)
        return Step(self._request("reallocate" if stage == "stage1" else "resolve", estimates(), None, stage))

    def _costs_changed(self, costs: tuple[float, float]) -> bool:
        summary = self.answer.summary
        current = (float(summary.get("switch_ms", 0.0)), float(summary.get("slack", 0.0)))
        return any(
            new > old * (1.0 + COSTS_RISE) or new < old * (1.0 - COSTS_FALL)
            for new, old in zip(costs, current, strict=True)
        )

    def reconfigure(self, switch_ms: float, slack: float, estimates: dict[str, float]) -> Request:
        """Plan with the runtime's measured costs from now on (``Replanner.reconfigure`` in the re-optimiser)."""
        return self._request("reconfigure", estimates, None, "costs", (switch_ms, slack))

    def _request(
        self,
        kind: Literal["resolve", "reallocate", "reconfigure"],
        estimates: dict[str, float],
        cores: int | None,
        reason: str,
        costs: tuple[float, float] | None = None,
    ) -> Request:
        self.asked = Request(kind, estimates, cores, reason, costs)
        self.planner.send(self.asked)
        return self.asked

    def answered(self, elapsed_s: float) -> tuple[Request | None, Answer]:
        """The answer to the request out (:class:`EOFError` or ``OSError`` if the re-optimiser is gone)."""
        request, self.asked = self.asked, None
        answer = self.planner.receive()
        self.last_resolve_s = elapsed_s
        if answer.error is None:
            self.answer = answer
        return request, answer
