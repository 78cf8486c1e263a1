"""The results scenarios' arithmetic and spec variants (tests/support/scenario_specs.py; the runs are catanc's)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catanc.model.load import load_spec
from tests.support.scenario_specs import (
    DATASET,
    bucket_medians,
    bucket_periods,
    over_seeds,
    paired_ratio,
    spec_file,
    spec_yaml,
    t_interval,
    with_baseline_rates,
    with_growth_over,
    with_rates,
    with_vsync_display_and_dataset,
)


def test_bucket_periods_average_the_gaps_ending_in_each_bucket() -> None:
    # Outputs at 0, 1, 3 and 12 s: gaps of 1 s and 2 s end in [0, 10) s, 9 s in [10, 20) s.
    assert bucket_periods([0.0, 1000.0, 3000.0, 12000.0], 20.0) == [1.5, 9.0]
    assert bucket_periods([500.0], 20.0) == [None, None]  # one output: no gap


def test_bucket_medians_take_the_middle_of_each_bucket() -> None:
    samples = [(1000.0, 5.0), (2000.0, 1.0), (3000.0, 3.0), (15000.0, 7.0), (19999.0, 9.0)]
    assert bucket_medians(samples, 30.0) == [3.0, 9.0, None]  # upper median of an even bucket


def test_a_rate_variant_changes_that_rate_alone() -> None:
    original = spec_yaml("nav2d")
    with spec_file(with_rates(original, {"LM": 50.0, "LP": 50.0})) as path:
        changed = load_spec(path)
    with spec_file(original) as path:
        same = load_spec(path)
    assert changed.baseline.rates_hz == {**same.baseline.rates_hz, "LM": 50.0, "LP": 50.0}
    assert changed.model_dump(exclude={"baseline"}) == same.model_dump(exclude={"baseline"})
    assert spec_yaml("nav2d") == original  # the variant is a copy


def test_a_growth_variant_compresses_every_growth_and_nothing_else() -> None:
    original = spec_yaml("nav2d_yolo")
    with spec_file(with_growth_over(original, 60.0)) as path:
        changed = load_spec(path)
    with spec_file(original) as path:
        same = load_spec(path)
    growing = {name for name, node in same.nodes.items() if node.workload and node.workload.growth}
    assert growing == {"GM", "GP"}
    for name, node in changed.nodes.items():
        if name in growing:
            assert node.workload is not None
            assert node.workload.growth is not None
            assert node.workload.growth.over_s == pytest.approx(60.0)
        else:
            assert node.model_dump() == same.nodes[name].model_dump()


def test_the_t_interval_of_three_values_by_hand() -> None:
    # mean 2, sample deviation 1, t(0.975, 2 dof) = 4.3027 from the table: 4.3027 / sqrt(3) = 2.4841
    mean, half = t_interval([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert half == pytest.approx(4.3027 / math.sqrt(3), abs=1e-4)
    assert math.isnan(t_interval([7.0])[1])
    assert t_interval([4.0] * 20) == (4.0, 0.0)


def test_the_t_interval_covers_the_true_mean_95_percent_of_the_time() -> None:
    """Simulated: 4000 samples of 20 normal draws; the coverage's own 3-sigma band is +-1.0%."""
    rng = np.random.default_rng(7)
    samples = rng.normal(5.0, 2.0, size=(4000, 20))
    covered = 0
    for sample in samples:
        mean, half = t_interval(sample.tolist())
        covered += abs(mean - 5.0) <= half
    assert 0.94 <= covered / len(samples) <= 0.96


def test_baseline_rates_replace_every_timer() -> None:
    original = spec_yaml("nav2d_yolo")
    with spec_file(with_baseline_rates(original, {"LM": 120.0, "GL": 40.0})) as path:
        changed = load_spec(path)
    assert changed.baseline.rates_hz == {"LM": 120.0, "GL": 40.0}
    assert spec_yaml("nav2d_yolo") == original


def test_the_illixr_variant_adds_vsync_and_a_dataset_and_nothing_else() -> None:
    original = spec_yaml("vr_illixr")
    with spec_file(with_vsync_display_and_dataset(original, 120.0, 20.0)) as path:
        changed = load_spec(path)
    with spec_file(original) as path:
        same = load_spec(path)
    assert changed.nodes["Display"].rate_hz == 120.0
    assert same.nodes["Display"].rate_hz is None
    assert not changed.nodes[DATASET].scheduled
    assert changed.nodes[DATASET].rate_hz == 20.0
    assert set(changed.edge_pairs) - set(same.edge_pairs) == {(DATASET, "Camera")}
    assert set(changed.nodes) - set(same.nodes) == {DATASET}
    for name, node in same.nodes.items():
        if name != "Display":
            assert changed.nodes[name] == node
    assert changed.model_dump(exclude={"nodes", "edges"}) == same.model_dump(exclude={"nodes", "edges"})


def test_measurements_over_seeds_become_means_with_intervals_leaf_by_leaf() -> None:
    measured = [
        {"rate": 1.0, "chain": {"mean_ms": 10.0, "model_ms": None}, "buckets": [2.0, None]},
        {"rate": 3.0, "chain": {"mean_ms": 14.0, "model_ms": None}, "buckets": [4.0, 5.0]},
    ]
    summary = over_seeds(measured)
    # two values: mean, deviation sqrt(2) * |a - b| / 2, t(0.975, 1 dof) = 12.706 from the table
    assert summary["rate"]["mean"] == 2.0
    assert summary["rate"]["ci95"] == pytest.approx(12.706 * 1.0, abs=1e-3)  # s = sqrt(2), / sqrt(2)
    assert summary["rate"]["values"] == [1.0, 3.0]
    assert summary["chain"]["mean_ms"]["mean"] == 12.0
    assert summary["chain"]["model_ms"] is None  # no seed had one
    assert summary["buckets"][0]["mean"] == 3.0
    assert summary["buckets"][1] == {"mean": 5.0, "ci95": None, "n": 1, "values": [5.0]}


def test_paired_ratios_compare_seed_by_seed() -> None:
    mine = over_seeds([8.0, 18.0, 27.0])
    theirs = over_seeds([10.0, 20.0, 30.0])
    ratio = paired_ratio(mine, theirs)
    assert ratio is not None
    assert ratio["values"] == [pytest.approx(-0.2), pytest.approx(-0.1), pytest.approx(-0.1)]
    assert ratio["mean"] == pytest.approx(-0.1333, abs=1e-4)
    assert paired_ratio(mine, None) is None
