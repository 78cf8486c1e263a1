"""Priority stealing and the paper's ablation without it (its Figure 9), worked by hand.

One core, period 10 ms, 0.5 ms switches: subchain ``a`` (priority 2, planned latency 2 ms)
has its slot at 0.5-2.5 ms, ``b`` (priority 1) at 3.0-6.0 ms. ``a``'s run takes 5 ms (a
spike), ``b``'s 3 ms; both heads are triggered at their slots.

- **With stealing** (``catan``): ``a`` runs from 0; at b's switch (2.5 ms) ``a`` is late
  (2.5 > 2) and takes the slot, so it runs on to 5.0 ms; ``b``, triggered at 2.5 ms but
  resting at FIFO 1, runs 5.0-8.0 ms.
- **Without** (``catan-nosteal``): at 2.5 ms ``b`` is raised and runs 2.5-5.5 ms; ``a``,
  lowered with 2.5 ms left, runs 5.5-8.0 ms.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun
from catanc.model.load import load_spec
from catanc.realbench.bench import BenchSetup, planned_spec
from catanc.sim.dataflow import Dataflow
from catanc.sim.engine import Engine
from catanc.sim.policies import CatanPolicy
from catanc.sim.simulate import Setup, policy_spec, simulate
from tests.support.strategies import spec_of

TWO_NODES = {
    "catan": 1,
    "app": "two",
    "nodes": {"a": {"compute_ms": 2.0}, "b": {"compute_ms": 3.0}},
    "edges": [],
    "subchains": {"a": ["a"], "b": ["b"]},
    "objective": [{"node": "a", "weight": 1.0}, {"node": "b", "weight": 0.5}],
}
COMPUTE_MS = {"a": 5.0, "b": 3.0}


def completions(*, stealing: bool) -> dict[str, list[float]]:
    spec = spec_of(TWO_NODES)
    runs = {
        "a": SubchainRun("a", ("a",), (0,), True, 10.0, 2.0, 1, 2),
        "b": SubchainRun("b", ("b",), (0,), True, 10.0, 10.0, 1, 1),
    }
    core = CoreSchedule(0, 10.0, 0.5, (Slot("a", 0.5, 2.0), Slot("b", 3.0, 3.0)), stealing=stealing)
    engine = Engine()
    flow = Dataflow(spec, [("a",), ("b",)])
    policy = CatanPolicy(
        engine,
        flow,
        spec=spec,
        schedule=RuntimeSchedule(1, runs, (core,)),
        sample=lambda node, _at_s: COMPUTE_MS[node],
    )
    policy.start()
    engine.run_until(9.0)  # the first period only (the next triggers come at 10 ms)
    return {name: record.done_ms for name, record in sorted(flow.records.items())}


def test_a_late_subchain_of_higher_priority_takes_the_next_slot() -> None:
    assert completions(stealing=True) == {"a": [pytest.approx(5.0)], "b": [pytest.approx(8.0)]}


def test_without_stealing_the_slot_stays_its_owners() -> None:
    assert completions(stealing=False) == {"a": [pytest.approx(8.0)], "b": [pytest.approx(5.5)]}


def test_catan_nosteal_plans_as_catan_and_turns_stealing_off_in_both_engines_and_the_bench() -> None:
    spec = load_spec("specs/vr_illixr.yaml")
    assert spec.schedule.stealing
    assert not policy_spec(spec, "catan-nosteal").schedule.stealing
    assert policy_spec(spec, "catan") is spec
    for engine in ("compiled", "python"):
        with_stealing = simulate(Setup(spec, 1, 3.0, 0), "catan", engine=engine)
        without = simulate(Setup(spec, 1, 3.0, 0), "catan-nosteal", engine=engine)
        assert with_stealing.schedule is not None
        assert without.schedule is not None
        assert [core.stealing for core in with_stealing.schedule.shared] == [True]
        assert [core.stealing for core in without.schedule.shared] == [False]
        assert [core.slots for core in without.schedule.shared] == [
            core.slots for core in with_stealing.schedule.shared
        ]
    bench = BenchSetup(Path("specs/vr_illixr.yaml"), spec, 1, 3.0, 0)
    assert not planned_spec(bench, "catan-nosteal").schedule.stealing
    assert planned_spec(bench, "catan").schedule.stealing


def test_a_spec_can_turn_stealing_off_and_only_then_is_it_written_out() -> None:
    on = spec_of(TWO_NODES)
    off = spec_of({**TWO_NODES, "schedule": {"stealing": False}})
    assert on.schedule.stealing
    assert not off.schedule.stealing
    assert "stealing" not in on.model_dump()["schedule"]  # runtime tables of existing specs stay as they were
    assert off.model_dump()["schedule"]["stealing"] is False
    assert not type(off).model_validate(off.model_dump()).schedule.stealing
