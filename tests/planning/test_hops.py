"""Hops in the plan (docs/explanation/model.md section 5):
each edge inside a subchain adds its measured hop to ``c(S)``.

The expected numbers are worked by hand from the model's formulas, never read off the planner.
"""

from __future__ import annotations

import pytest

from catanc.control.schedule import RuntimeSchedule, runtime_schedule
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.planning.planner import plan
from catanc.runtime.enforcer.runs import RunBook

FACE = """catan: 1
app: face
nodes:
  camera: {compute_ms: 25}
  detection: {compute_ms: 58}
  planning: {compute_ms: 1}
  motor: {scheduled: false}
edges: [[camera, detection], [detection, planning], [planning, motor]]
subchains:
  tracking: [camera, detection, planning]
objective:
  - {chain: [camera, detection, planning, motor], weight: 1.0}
"""
HOPS = """hops_ms:
  camera -> detection: 1.5      # a ROS 2 topic between two processes
  detection->planning: 0.25
  planning -> motor: 7          # outside every subchain: in no c(S)
"""


@pytest.mark.parametrize(
    ("hops", "cores", "period", "response"),
    [
        # 1 core, Eq. 1 with q = 1: c(S) = 25 + 58 + 1 = 84 ms (+ 1.75 ms of hops), period c(S) / 0.95 (the slack),
        # response = latency c(S) + period.
        ("", 1, 84 / 0.95, 84 + 84 / 0.95),
        (HOPS, 1, 85.75 / 0.95, 85.75 + 85.75 / 0.95),
        # 2 cores, q = 1: period max(58, 85.75 / 2) / 0.95 = 58 / 0.95; the hops lengthen the latency only.
        (HOPS, 2, 58 / 0.95, 85.75 + 58 / 0.95),
    ],
)
def test_a_dedicated_subchain_counts_one_hop_per_edge_inside_it(
    hops: str, cores: int, period: float, response: float
) -> None:
    result = plan(parse_spec(FACE + hops), cores)
    tracking = result.subchains["tracking"]
    assert tracking.period_ms == pytest.approx(period)
    assert tracking.latency_ms == pytest.approx(response - period)
    assert result.chains[0].response_ms == pytest.approx(response)


SHARED = """catan: 1
app: shared
nodes:
  a1: {compute_ms: 2}
  a2: {compute_ms: 3}
  b: {compute_ms: 4}
edges: [[a1, a2]]
hops_ms: {a1 -> a2: 1}
subchains: {A: [a1, a2], B: [b]}
objective: [{node: a1, weight: 1}, {node: b, weight: 1}]
"""


def test_a_shared_subchains_slice_and_the_cores_period_hold_its_hops() -> None:
    # One core, both subchains once a period (f = 1): T = (c(A) + c(B) + 2 switches) / (1 - slack) with
    # c(A) = 2 + 3 + 1 (the hop) = 6 and c(B) = 4.  Every other choice is worse by hand: f_A = 1/2 gives
    # 2 T' + T' = 3 (3 + 4 + 0.24) / 0.95 = 22.9 > 2 * 10.24 / 0.95 = 21.6; f_B = 1/2 gives 3 (6 + 2 + 0.24) / 0.95.
    result = plan(parse_spec(SHARED), 1)
    period = (6 + 4 + 2 * 0.12) / 0.95
    assert result.subchains["A"].period_ms == pytest.approx(period)
    assert result.subchains["B"].period_ms == pytest.approx(period)
    assert result.objective == pytest.approx(2 * period)
    slots = {slot.subchain: slot.length_ms for slot in _schedule(SHARED, 1).shared[0].slots}
    assert slots == pytest.approx({"A": 6.0, "B": 4.0})


def _schedule(text: str, cores: int) -> RuntimeSchedule:
    spec = parse_spec(text)
    problem = build_problem(spec)
    return runtime_schedule(plan(spec, cores), problem, spec.schedule)


@pytest.mark.parametrize(("hops", "late"), [("", True), (HOPS, False)])
def test_a_run_is_late_only_against_the_latency_with_its_hops(hops: str, late: bool) -> None:
    # Dedicated on one core: a run's planned latency is c(S) = 84 ms, or 85.75 ms with the hops.  A run
    # still in flight 85 ms after its trigger is late without hops in the spec, in time with them.
    run = _schedule(FACE + hops, 1).subchains["tracking"]
    book = RunBook(["tracking"], {}, lambda _: None)
    assert book.trigger(run, 1000.0, None) is not None
    assert book.late("tracking", 1000.0 + 85.0, run) is late


DISPATCH = """dispatch_ms:
  camera: 2.0                   # a ROS 2 head's trigger -> its callback (catanc.ros)
"""


@pytest.mark.parametrize(
    ("extra", "cores", "period", "response"),
    [
        # 1 core, Eq. 1 with q = 1: c(S) = 84 ms of compute + 2 ms of the head's dispatch = 86 ms.
        (DISPATCH, 1, 86 / 0.95, 86 + 86 / 0.95),
        # With the inside hops too: 84 + 2 + 1.75 = 87.75 ms.
        (DISPATCH + HOPS, 1, 87.75 / 0.95, 87.75 + 87.75 / 0.95),
        # 2 cores, q = 1: period max(58, 87.75 / 2) / 0.95 = 58 / 0.95; the latency holds the dispatch.
        (DISPATCH + HOPS, 2, 58 / 0.95, 87.75 + 58 / 0.95),
    ],
)
def test_a_dedicated_subchain_counts_its_heads_dispatch(extra: str, cores: int, period: float, response: float) -> None:
    result = plan(parse_spec(FACE + extra), cores)
    tracking = result.subchains["tracking"]
    assert tracking.period_ms == pytest.approx(period)
    assert tracking.latency_ms == pytest.approx(response - period)
    assert result.chains[0].response_ms == pytest.approx(response)


def test_a_shared_subchains_slice_holds_its_heads_dispatch() -> None:
    # SHARED with b's dispatch 0.5 ms: c(B) = 4.5, T = (6 + 4.5 + 2 * 0.12) / 0.95, both once a period (the
    # alternatives worked in the test above stay worse: each adds a whole slice of the other per period).
    result = plan(parse_spec(SHARED + "dispatch_ms: {b: 0.5}\n"), 1)
    period = (6 + 4.5 + 2 * 0.12) / 0.95
    assert result.subchains["B"].period_ms == pytest.approx(period)
    slots = {slot.subchain: slot.length_ms for slot in _schedule(SHARED + "dispatch_ms: {b: 0.5}\n", 1).shared[0].slots}
    assert slots == pytest.approx({"A": 6.0, "B": 4.5})


@pytest.mark.parametrize(("extra", "late"), [(HOPS, True), (HOPS + DISPATCH, False)])
def test_a_run_is_late_only_against_the_latency_with_its_dispatch(extra: str, late: bool) -> None:
    # c(S) = 85.75 ms with the hops, 87.75 ms with the head's dispatch too: a run in flight 87 ms after its
    # trigger is late without the dispatch in the spec, in time with it.
    run = _schedule(FACE + extra, 1).subchains["tracking"]
    book = RunBook(["tracking"], {}, lambda _: None)
    assert book.trigger(run, 1000.0, None) is not None
    assert book.late("tracking", 1000.0 + 87.0, run) is late
