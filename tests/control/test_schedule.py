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


def test_a_run_is_judged_late_past_its_latency_and_its_planned_wait_for_an_executors_thread() -> None:
    """nav2d on 2 cores (the committed plan), worked by hand (docs/explanation/executor-planning.md, "The model").

    Core 1 runs GL, GP, NC, GM (priorities 4, 3, 2, 1 as GL > NC > GP > GM) with 5% slack; the Mapper's thread
    runs GL and GM, the Navigator's GP and NC.  GL waiting for GM's 150 ms run: the thread gets what GP
    and NC leave, s0 = 0.95 - 100 / p_GP - 1 / p_NC; GL steals from d = p_GL / 2 + l_GL on, and outranks
    everything else there: s1 = 0.95.  NC waiting for GP's 100 ms: s0 = 0.95 - 3.2 / p_GL - 150 / p_GM; it
    steals from GP and GM but not GL: s1 = 0.95 - 3.2 / p_GL.
    """
    spec = load_spec(ROOT / "specs" / "nav2d.yaml")
    table = json.loads((ROOT / "out" / "nav2d" / "cores-2" / "runtime.json").read_text())["plan"]["subchains"]
    period = {name: row["period_ms"] for name, row in table.items()}
    latency = {name: row["latency_ms"] for name, row in table.items()}
    schedule = runtime_schedule(plan(spec, 2), build_problem(spec), spec.schedule)

    def hold(compute: float, s0: float, s1: float, delay: float) -> float:
        return delay + (compute - s0 * delay) / s1 if compute > s0 * delay else compute / s0

    gl_behind_gm = hold(150.0, 0.95 - 100.0 / period["GP"] - 1.0 / period["NC"], 0.95, 10.0 + latency["GL"])
    nc_delay = period["NC"] / 2 + latency["NC"]
    nc_behind_gp = hold(100.0, 0.95 - 3.2 / period["GL"] - 150.0 / period["GM"], 0.95 - 3.2 / period["GL"], nc_delay)
    assert gl_behind_gm == pytest.approx(162.56, abs=0.01)  # PLAN.md: "up to about 162.6 ms for GL behind GM"
    assert nc_behind_gp == pytest.approx(136.08, abs=0.01)  # "up to about 136.1 ms for NC behind GP"
    runs = schedule.subchains
    assert runs["GL"].wait_ms == pytest.approx(gl_behind_gm, rel=1e-6)
    assert runs["NC"].wait_ms == pytest.approx(nc_behind_gp, rel=1e-6)
    assert runs["GL"].late_after_ms == pytest.approx(latency["GL"] + gl_behind_gm, rel=1e-6)
    assert runs["local"].wait_ms == 0.0  # LM and LP share a thread, but in one subchain: its latency has them
    assert runs["local"].late_after_ms == runs["local"].latency_ms
    assert is_late(0.0, latency["GL"] + 1.0, runs["GL"])  # stealing still starts at the planned latency
