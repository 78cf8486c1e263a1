"""When the enforcer re-plans with its measured costs (catanc.runtime.enforcer.replanning), on a stand-in re-optimiser.

Holding the highest costs measured over 30 s instead (fewer re-plans) was tried and not kept
(2026-11-28): nav2d on one core, 30 s, re-planned with new costs twice instead of six times, but
held the 0.39 ms switch cost its first measurement saw while starting, and ran its local chain at
82-91 Hz instead of 101-114.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

from catanc.runtime.enforcer.reoptimiser import Answer, PlannerProcess, Request
from catanc.runtime.enforcer.replanning import Replanning
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


def planned_costs(measured: Sequence[tuple[float, float] | None]) -> list[tuple[float, float] | None]:
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


def test_costs_re_plan_when_they_rise_ten_percent_or_fall_twenty_five() -> None:
    # 0.29 ms from the spec's 0.12: re-planned; 0.30 (+3%) kept; slack 0.05 -> 0.158: re-planned; no
    # measurement: kept; 0.20 ms (-31%): re-planned, lower too.
    asked = planned_costs([(0.29, 0.05), (0.30, 0.05), (0.29, 0.158), None, (0.20, 0.158)])
    assert asked == [(0.29, 0.05), None, (0.29, 0.158), None, (0.20, 0.158)]


def test_costs_just_inside_either_band_keep_the_plan_and_just_outside_re_plan() -> None:
    # From a plan at (0.20 ms, 0.10): +9% and -24% kept; +11% re-planned, then from there -26% re-planned.
    base = [(0.20, 0.10)]
    assert planned_costs([*base, (0.218, 0.10), (0.20, 0.076), (0.152, 0.10)]) == [base[0], None, None, None]
    assert planned_costs([*base, (0.20, 0.111), (0.20, 0.082)]) == [base[0], (0.20, 0.111), (0.20, 0.082)]


def test_a_noisy_share_re_plans_once_not_at_every_re_solve() -> None:
    """The enforcer's CPU share in a busy minute, read at each re-solve (slack 0.08-0.10: +-11% about 0.09): a
    symmetric 10% band re-planned at five of the six (0.080, 0.095, 0.082, 0.099, 0.084); this one twice, and
    then holds 0.095, 4% under the highest."""
    noisy = [(0.12, 0.080), (0.12, 0.095), (0.12, 0.082), (0.12, 0.099), (0.12, 0.084), (0.12, 0.090)]
    asked = planned_costs(noisy)
    assert asked == [(0.12, 0.080), (0.12, 0.095), None, None, None, None]
