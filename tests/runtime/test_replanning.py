"""When the enforcer re-plans with its measured costs (catanc.runtime.replanning), on a stand-in re-optimiser.

Holding the highest costs measured over 30 s instead (fewer re-plans) was tried and not kept
(2026-11-28): nav2d on one core, 30 s, re-planned with new costs twice instead of six times, but
held the 0.39 ms switch cost its first measurement saw while starting, and ran its local chain at
82-91 Hz instead of 101-114.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any, cast

from catanc.runtime.planning import Answer, PlannerProcess, Request
from catanc.runtime.replanning import Replanning
from catanc.spec.language import Runtime


@dataclass
class StandIn:
    """A re-optimiser that answers each request with the costs it was asked to plan with."""

    costs: tuple[float, float] = (0.12, 0.05)  # the spec's
    sent: list[Request] = field(default_factory=list)

    @property
    def initial(self) -> Answer:
        return self.answer()

    def answer(self) -> Answer:
        summary: dict[str, Any] = {"switch_ms": self.costs[0], "slack": self.costs[1]}
        return Answer(schedule=cast(Any, None), layout=(), summary=summary, solve_ms=1.0)

    def send(self, request: Request) -> None:
        self.sent.append(request)
        if request.costs is not None:
            self.costs = request.costs

    def receive(self) -> Answer:
        return self.answer()


def planned_costs(measured: list[tuple[float, float] | None]) -> list[tuple[float, float] | None]:
    """The costs each re-solve, 5 s apart from 2 s, re-planned with (None: it kept the plan's)."""
    stand_in = StandIn()
    replanning = Replanning(cast(PlannerProcess, stand_in), Runtime(), [0], lambda _: None)
    asked = []
    for index, costs in enumerate(measured):
        now = 2000.0 + 5000.0 * index
        step = replanning.step(now, frozenset([0]), 1, dict, functools.partial(lambda found: found, costs))
        assert step.request is not None  # a re-solve is due every 5 s
        asked.append(step.request.costs)
        replanning.answered(now / 1000.0)
    return asked


def test_costs_re_plan_when_they_move_more_than_ten_percent() -> None:
    # 0.29 ms from the spec's 0.12: re-planned; 0.30 (+3%) kept; slack 0.05 -> 0.158: re-planned; no
    # measurement: kept; 0.20 ms (-31%): re-planned, lower too.
    asked = planned_costs([(0.29, 0.05), (0.30, 0.05), (0.29, 0.158), None, (0.20, 0.158)])
    assert asked == [(0.29, 0.05), None, (0.29, 0.158), None, (0.20, 0.158)]
