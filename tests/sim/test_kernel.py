"""The compiled kernel against its oracle, the Python engine: the same runs, record for record.

The Python engine (engine, dataflow, policies) is the readable statement of
the simulation and has its own hand-worked tests (test_simulate.py).  The
kernel must reproduce it exactly: every completion time, every chain
arrival, every re-plan, on the example specs and on random apps with random
workloads, including when its arrays have to grow mid-run.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.errors import CatancError
from catanc.model.load import load_spec
from catanc.sim import fast
from catanc.sim import kernel as k
from catanc.sim.comparison import comparison_payload
from catanc.sim.metrics import PolicyResult
from catanc.sim.simulate import POLICIES, Setup, simulate
from catanc.spec.language import Spec
from tests.support.strategies import spec_documents, spec_of

untimed = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=40)


def assert_same_run(compiled: PolicyResult, python: PolicyResult) -> None:
    assert json.dumps(comparison_payload([compiled]), sort_keys=True) == json.dumps(
        comparison_payload([python]), sort_keys=True
    )
    assert compiled.node_done_ms.keys() == python.node_done_ms.keys()
    for node, done in compiled.node_done_ms.items():  # every completion, to the last bit
        assert np.array_equal(done, python.node_done_ms[node])
    for mine, theirs in zip(compiled.chains, python.chains, strict=True):
        assert np.array_equal(mine.samples, theirs.samples)
    assert compiled.utilisation == pytest.approx(python.utilisation, rel=1e-9, abs=1e-12)
    assert compiled.replans == python.replans
    assert compiled.schedule == python.schedule


def both(setup: Setup, policy: str) -> tuple[PolicyResult, PolicyResult]:
    return simulate(setup, policy, engine="compiled"), simulate(setup, policy, engine="python")


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("app", ["face_tracking", "nav2d", "nav2d_yolo", "vr_illixr"])
def test_the_example_specs_run_the_same_in_both_engines(app: str, cores: int) -> None:
    """12 s: past the first re-solves (2 s, then every 5 s) and the workloads' growth and spikes."""
    spec = load_spec(f"specs/{app}.yaml")
    for policy in POLICIES:
        compiled, python = both(Setup(spec, cores, 12.0, 3), policy)
        assert_same_run(compiled, python)
        assert sum(len(done) for done in compiled.node_done_ms.values()) > 0


def test_arrays_grown_mid_run_change_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tiny first arrays: the draws, records and rings all grow during the run, results unchanged."""
    spec = load_spec("specs/nav2d.yaml")
    expected = {policy: simulate(Setup(spec, 2, 8.0, 1), policy, engine="python") for policy in POLICIES}
    monkeypatch.setattr(fast, "FIRST_DRAWS", 4)
    monkeypatch.setattr(fast, "FIRST_RECORDS", 2)
    monkeypatch.setattr(fast, "FIRST_RING", 4)
    for policy, python in expected.items():
        assert_same_run(simulate(Setup(spec, 2, 8.0, 1), policy, engine="compiled"), python)


def test_chain_arrivals_follow_what_each_run_read_back_to_the_head() -> None:
    """Worked by hand: nodes a, b, c and x; c reads b and x; chains (a, b, c), (b, c), (x, c) and (a,)."""
    a, b, c, x = 0, 1, 2, 3
    chains = [("a", "b", "c"), ("b", "c"), ("x", "c"), ("a",)]
    # record: (node, read at, done at, what it read of each feed (c: b then x): a record, -1 for none yet)
    table = [
        (b, 0.0, 0.5, [-1]),  # 0: b before a's first output
        (c, 0.6, 1.0, [0, -1]),  # 1: (b, c) from 0.0; nothing from a or x
        (a, 1.0, 2.0, []),  # 2: (a,) from 1.0
        (x, 2.2, 2.2, []),  # 3: a tick
        (b, 2.5, 3.0, [2]),  # 4
        (c, 3.5, 4.0, [4, 3]),  # 5: (a, b, c) from 1.0, (b, c) from 2.5, (x, c) from 2.2
        (c, 4.5, 5.0, [4, 3]),  # 6: the same origins again: no arrival
        (c, 5.5, 6.0, [0, 3]),  # 7: an older b (as a batch reads): older origins, no arrival
        (a, 6.0, 7.0, []),  # 8: (a,) from 6.0
    ]
    by_chain, origin, done = k.chain_arrivals(
        np.array([row[0] for row in table], np.int64),
        np.array([row[2] for row in table]),
        np.array([row[1] for row in table]),
        np.array([f for row in table for f in row[3]], np.int64),
        *fast.chain_tables(["a", "b", "c", "x"], chains),
    )
    arrivals: dict[int, list[tuple[float, float]]] = {}
    for chain, pair in zip(by_chain.tolist(), zip(origin.tolist(), done.tolist(), strict=True), strict=True):
        arrivals.setdefault(chain, []).append(pair)  # each chain's in order (chains interleave in any order)
    assert arrivals == {0: [(1.0, 4.0)], 1: [(0.0, 1.0), (2.5, 4.0)], 2: [(2.2, 4.0)], 3: [(1.0, 2.0), (6.0, 7.0)]}


@pytest.mark.parametrize("ring", [4, 8, 64])
def test_draws_taken_from_small_rings_change_nothing(monkeypatch: pytest.MonkeyPatch, ring: int) -> None:
    """Rings of a few draws per node: the local chain's nodes wrap theirs thousands of times."""
    spec = load_spec("specs/nav2d.yaml")
    monkeypatch.setattr(fast, "FIRST_DRAWS", 4)
    monkeypatch.setattr(fast, "RING_DRAWS", ring)
    for policy in ("catan", "baseline"):
        setup = Setup(spec, 2, 8.0, 2)
        assert_same_run(simulate(setup, policy, engine="compiled"), simulate(setup, policy, engine="python"))


@st.composite
def apps_with_workloads(draw: st.DrawFn, executors: bool = False) -> dict[str, Any]:
    """A random app with random jitter, growth and spikes, a hand-tuned baseline and quick re-solves
    (and, if ``executors``, nodes that share executor threads)."""
    document = draw(spec_documents(max_subchains=4, with_executors=executors))
    for name, node in document["nodes"].items():
        if "compute_ms" not in node:
            continue
        workload: dict[str, Any] = {}
        if draw(st.booleans()):
            workload["jitter"] = {
                "cv": draw(st.sampled_from([0.05, 0.2, 0.3])),
                "dist": draw(st.sampled_from(["lognormal", "uniform", "normal"])),
            }
        if draw(st.booleans()):
            workload["growth"] = {"start": 0.5, "end": draw(st.sampled_from([1.0, 2.5])), "over_s": 3}
        if draw(st.integers(0, 3)) == 0:
            workload["spikes"] = {"every_s": draw(st.sampled_from([0.3, 2.0])), "ms": 40}
        if workload:
            document["nodes"][name]["workload"] = workload
    heads = [members[0] for members in document["subchains"].values()]
    document["baseline"] = {"rates_hz": {head: draw(st.sampled_from([5, 20, 60])) for head in heads}}
    document["runtime"] = {"first_solve_after_s": 0.5, "stage2_every_s": 0.7, "stage1_every_s": 2.0}
    return document


@untimed
@given(apps_with_workloads(), st.integers(1, 3), st.sampled_from(POLICIES), st.integers(0, 5))
def test_random_apps_run_the_same_in_both_engines(document: dict[str, Any], cores: int, policy: str, seed: int) -> None:
    spec: Spec = spec_of(document)
    setup = Setup(spec, cores, 4.0, seed)
    try:
        python = simulate(setup, policy, engine="python")
    except CatancError:  # an app the planner finds infeasible: the planner's tests cover those
        return
    assert_same_run(simulate(setup, policy, engine="compiled"), python)


@untimed
@given(apps_with_workloads(executors=True), st.integers(1, 3), st.sampled_from(POLICIES), st.integers(0, 5))
def test_random_apps_with_executors_run_the_same_in_both_engines(
    document: dict[str, Any], cores: int, policy: str, seed: int
) -> None:
    try:
        spec: Spec = spec_of(document)
        python = simulate(Setup(spec, cores, 4.0, seed), policy, engine="python")
    except CatancError:  # an executor that cannot keep up, or a core count it forbids: tested elsewhere
        return
    assert_same_run(simulate(Setup(spec, cores, 4.0, seed), policy, engine="compiled"), python)


@settings(deadline=None, max_examples=60)
@given(keys=st.lists(st.integers(0, 5), max_size=200), width=st.sampled_from([1, 2]))
def test_grouping_records_keeps_each_keys_rows_in_order(keys: list[int], width: int) -> None:
    # The oracle: a stable argsort, then each key's rows picked out one key at a time.
    values = np.arange(len(keys) * width, dtype=np.float64).reshape(len(keys), width)
    groups = fast._grouped(values if width == 2 else values[:, 0], np.array(keys, np.int64), 7)
    assert len(groups) == 7
    for key, group in enumerate(groups):
        expected = values[[i for i, other in enumerate(keys) if other == key]]
        assert np.array_equal(group, expected if width == 2 else expected[:, 0])
