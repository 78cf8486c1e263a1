"""The results scenarios' arithmetic and spec variants (tests/support/scenario_specs.py; the runs are catanc's)."""

from __future__ import annotations

import pytest

from catanc.core.load import load_spec
from tests.support.scenario_specs import (
    bucket_medians,
    bucket_periods,
    spec_file,
    spec_yaml,
    with_growth_over,
    with_rates,
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
