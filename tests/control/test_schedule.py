"""The enforcer's schedule: triggers, slots and stealing, checked without threads or a kernel."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from catanc.control.schedule import (
    CoreSchedule,
    Slot,
    SubchainRun,
    is_late,
    node_priority,
    runtime_schedule,
    slot_owner,
    triggers_at_slot,
)
from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.planning.planner import plan

ROOT = Path(__file__).parents[2]
CASES = [(path, cores) for path in sorted((ROOT / "specs").glob("*.yaml")) for cores in (1, 2)]


@pytest.mark.parametrize(("path", "cores"), CASES, ids=lambda case: str(getattr(case, "stem", case)))
def test_slots_fit_the_period_and_match_the_committed_table(path: Path, cores: int) -> None:
    spec = load_spec(path)
    problem = build_problem(spec)
    result = plan(spec, cores)
    schedule = runtime_schedule(result, problem, spec.schedule)
    table = json.loads((ROOT / "out" / spec.app / f"cores-{cores}" / "runtime.json").read_text())["plan"]
    for core in schedule.shared:
        assert core.busy_ms <= (1 - spec.schedule.slack) * core.period_ms * (1 + 1e-6)
        starts = [slot.start_ms for slot in core.slots]
        assert starts == sorted(starts)
        for slot in core.slots:
            assert math.isclose(slot.length_ms, table["subchains"][slot.subchain]["slice_ms"], abs_tol=2e-6)
    for name, run in schedule.subchains.items():
        written = table["subchains"][name]
        assert run.cores == tuple(written["cores"])
        assert math.isclose(run.period_ms, written["period_ms"], abs_tol=2e-6)
        assert node_priority(run) == (1 if written["shared"] else 2)


@pytest.mark.parametrize(("path", "cores"), CASES, ids=lambda case: str(getattr(case, "stem", case)))
def test_slot_triggers_give_the_planned_rates(path: Path, cores: int) -> None:
    """Run each core's period loop for many periods: slot-triggered subchains run at 1000 / period_ms."""
    spec = load_spec(path)
    result = plan(spec, cores)
    schedule = runtime_schedule(result, build_problem(spec), spec.schedule)
    for core in schedule.shared:
        periods = 5000
        counts = dict.fromkeys((slot.subchain for slot in core.slots), 0)
        for index in range(periods):
            for slot in core.slots:
                counts[slot.subchain] += triggers_at_slot(schedule.subchains[slot.subchain], index)
        elapsed_s = periods * core.period_ms / 1000
        for name, count in counts.items():
            run = schedule.subchains[name]
            if run.on_clock:
                assert count == 0
                continue
            assert abs(count - elapsed_s * 1000 / run.period_ms) <= 1, name  # a partial cycle at the end


def test_only_batch_subchains_run_on_their_own_clock() -> None:
    # Every shared non-batch subchain is triggered at its slot every k periods, a rate cap's too
    # (docs/explanation/model.md section 4): GP at 1 Hz on nav2d's one core, timewarp at vsync on VR's.
    spec = load_spec(ROOT / "specs" / "nav2d.yaml")
    result = plan(spec, 1)
    schedule = runtime_schedule(result, build_problem(spec), spec.schedule)
    length = schedule.shared[0].period_ms
    assert [run.name for run in schedule.clocked] == ["GL"]  # batch: a continuous fraction
    for run in schedule.subchains.values():
        if run.name != "GL":
            assert run.runs == result.every[run.name]
            assert math.isclose(run.period_ms, run.runs * length, rel_tol=1e-9)
    assert result.every["GP"] > result.runs["GP"]  # held back by its cap: every k > n periods
    assert schedule.subchains["GP"].period_ms >= 1000.0 * (1 - 1e-9)
    vr = load_spec(ROOT / "specs" / "vr_illixr.yaml")
    vr_plan = plan(vr, 1)
    vr_schedule = runtime_schedule(vr_plan, build_problem(vr), vr.schedule)
    assert vr_schedule.clocked == ()
    timewarp = vr_schedule.subchains["timewarp"]
    assert math.isclose(vr_plan.every["timewarp"] * vr_schedule.shared[0].period_ms, 1000 / 120, rel_tol=1e-9)
    assert timewarp.runs == vr_plan.every["timewarp"]  # vsync


def run(name: str, priority: int, latency_ms: float = 10.0) -> SubchainRun:
    return SubchainRun(name, (name,), (0,), True, 20.0, latency_ms, 1, priority)


def test_stealing_goes_to_the_highest_late_subchain_above_the_owner() -> None:
    runs = {"a": run("a", 3), "b": run("b", 2), "c": run("c", 1)}
    core = CoreSchedule(0, 20.0, 0.1, (Slot("a", 0.1, 2.0), Slot("b", 2.2, 2.0), Slot("c", 4.3, 2.0)))
    c_slot, b_slot, a_slot = core.slots[2], core.slots[1], core.slots[0]
    assert slot_owner(c_slot, core, runs, set()) == "c"
    assert slot_owner(c_slot, core, runs, {"b"}) == "b"
    assert slot_owner(c_slot, core, runs, {"a", "b"}) == "a"
    assert slot_owner(b_slot, core, runs, {"c"}) == "b"  # a lower one never steals
    assert slot_owner(a_slot, core, runs, {"a", "b"}) == "a"
    without = CoreSchedule(0, 20.0, 0.1, core.slots, stealing=False)  # the paper's ablation
    assert [slot_owner(slot, without, runs, {"a", "b", "c"}) for slot in core.slots] == ["a", "b", "c"]


def test_lateness() -> None:
    late = run("a", 1, latency_ms=10.0)
    assert not is_late(None, 100.0, late)
    assert not is_late(95.0, 100.0, late)
    assert is_late(89.0, 100.0, late)
