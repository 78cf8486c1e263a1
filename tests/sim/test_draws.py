"""A static plan's profiled tail times, drawn a block at a time (catanc.sim.simulate.stream_draws).

Oracle: the run-by-run sampler (ComputeSampler.compute_ms, what the Python engine
calls), whose draws test_workload.py checks on their own.  The block draws must
give the same bits, so the static plans are planned from the same numbers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.model.load import load_spec
from catanc.model.workload import ComputeSampler
from catanc.sim.simulate import (
    STATIC_20S,
    profile_times,
    stream_draws,
    tail_compute,
    workload_sampler,
    workload_tail_compute,
)
from catanc.spec.language import Spec
from tests.sim.test_kernel import apps_with_workloads, untimed
from tests.support.strategies import spec_of

APPS = ["face_tracking", "nav2d", "nav2d_yolo", "vr_illixr"]


def one_by_one(spec: Spec, seed: int, node: str, times: list[float]) -> list[float]:
    sample = ComputeSampler(spec, seed).compute_ms
    return [sample(node, at) for at in times]


def at_once(spec: Spec, seed: int, node: str, times: list[float]) -> list[float]:
    drawn: list[float] = stream_draws(ComputeSampler(spec, seed).stream(node), np.array(times)).tolist()
    return drawn


def same_bits(a: list[float], b: list[float]) -> bool:
    return np.array(a).tobytes() == np.array(b).tobytes()


@pytest.mark.parametrize("app", APPS)
def test_block_draws_are_the_run_by_run_draws(app: str) -> None:
    """Over 250 s: past nav2d's growth (over 250 s) and through its spikes (every 30 s)."""
    spec = load_spec(f"specs/{app}.yaml")
    runs = 0
    for seed in range(3):
        for times in (profile_times(0.0, 250.0), profile_times(0.0, STATIC_20S), [0.0, 0.0, 3.5, 3.5, 40.0, 400.0]):
            for name, node in spec.nodes.items():
                if node.scheduled:
                    assert same_bits(at_once(spec, seed, name, times), one_by_one(spec, seed, name, times))
                    runs += len(times)
    assert runs > 0


def test_nav2d_block_draws_take_spikes() -> None:
    """The oracle is not trivially met: GL's spikes (250 ms) are among the draws."""
    spec = load_spec("specs/nav2d.yaml")
    draws = at_once(spec, 0, "GL", profile_times(0.0, 250.0))
    assert 250.0 in draws
    assert len(set(draws)) > 1000


@pytest.mark.parametrize("app", APPS)
@pytest.mark.parametrize("end_s", [STATIC_20S, 60.0])
def test_workload_tail_compute_is_tail_compute(app: str, end_s: float) -> None:
    spec = load_spec(f"specs/{app}.yaml")
    for seed in range(2):
        assert workload_tail_compute(spec, seed, 0.0, end_s) == tail_compute(
            spec, workload_sampler(spec, seed), 0.0, end_s
        )


sorted_times = st.lists(st.floats(-1.0, 30.0), max_size=300).map(sorted)


@untimed
@given(apps_with_workloads(), sorted_times, st.integers(0, 5))
def test_random_workloads_draw_the_same_in_blocks(document: dict[str, Any], times: list[float], seed: int) -> None:
    spec = spec_of(document)
    for name, node in spec.nodes.items():
        if node.scheduled:
            assert same_bits(at_once(spec, seed, name, times), one_by_one(spec, seed, name, times))
