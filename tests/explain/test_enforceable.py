"""explain's warning for shared cores whose switching outweighs their slack (catanc.explain.enforceable)."""

from __future__ import annotations

import pytest

from catanc.explain.analysis import explain_plan
from catanc.explain.enforceable import short_slots
from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.planning.planner import plan
from catanc.spec.machine import MachineFile, MachineProfile, apply_machine

TWO = """catan: 1
app: two
nodes: {a: {compute_ms: 1}, b: {compute_ms: 1}}
subchains: {A: [a], B: [b]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}]
schedule: {switch_ms: SWITCH}
"""


@pytest.mark.parametrize(("switch", "flagged"), [(0.12, True), (0.05, False)])
def test_two_slots_by_hand(switch: float, flagged: bool) -> None:
    # One core, two 1 ms subchains, each a whole run per period: T = (1 + 1 + 2 s) / 0.95.
    # s = 0.12: T = 2.358 ms, switching 0.24 ms > slack 0.118 ms: flagged.
    # s = 0.05: T = 2.211 ms, switching 0.10 ms < slack 0.111 ms: not.
    spec = parse_spec(TWO.replace("SWITCH", str(switch)))
    result = plan(spec, 1)
    period = (2 + 2 * switch) / 0.95
    assert result.shared_cores[0].period_ms == pytest.approx(period, rel=1e-6)
    found = short_slots(result, spec.schedule)
    assert bool(found) == flagged
    if flagged:
        assert found[0].switching_ms == pytest.approx(0.24)
        assert found[0].slack_ms == pytest.approx(0.05 * period)


def test_two_slots_are_flagged_and_a_profile_silences_them() -> None:
    spec = parse_spec(TWO.replace("SWITCH", "0.12"))
    problem = build_problem(spec)
    warnings = explain_plan(spec, problem, plan(spec, 1)).warnings
    assert any(w.startswith("slices too short to enforce") and "on 2 switches" in w for w in warnings)
    profile = MachineProfile.model_validate(
        {
            "format": "catanc-machine/1",
            "machine": {"host": "h"},
            "switch_ms": 0.1,
            "hop_ms": 0.05,
            "overhead": [0.01],
            "rt": {"runtime_us": 950000, "period_us": 1000000},
        }
    )
    measured, use = apply_machine(spec, MachineFile(profile, "h.yaml", "0" * 64))
    warnings = explain_plan(measured, problem, plan(measured, 1), use).warnings
    assert not any(w.startswith("slices too short") for w in warnings)


def test_vr_on_one_core_is_not_flagged() -> None:
    # With aligned triggers VR's schedule is locked to vsync: T = 8.333 ms, three switches of
    # 0.12 ms (0.36 ms) within its 5% slack (0.417 ms).
    spec = load_spec("specs/vr_illixr.yaml")
    assert short_slots(plan(spec, 1), spec.schedule) == []


def test_nav2d_two_cores_is_not_flagged() -> None:
    # Core 1 holds 4 slots in a 22 ms period: 0.48 ms of switching against 1.1 ms of slack.
    spec = load_spec("specs/nav2d.yaml")
    assert short_slots(plan(spec, 2), spec.schedule) == []
