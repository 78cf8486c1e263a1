"""Adding many compute times at once (ComputeWindow.extend, Measurements.record_many).

Oracle: adding the same values one by one with ComputeWindow.add / Measurements.record,
which test_measure.py checks on its own.  The windows must end bit for bit the same
(-0.0 stays -0.0), with the same counts of accepted and rejected samples.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from catanc.control.measure import ComputeWindow, Measurements
from catanc.errors import UsageError
from catanc.model.load import load_spec

untimed = settings(deadline=None)  # tests never time things

NAV2D = Path(__file__).resolve().parents[2] / "specs" / "nav2d.yaml"

any_floats = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)
edge_floats = st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf, -1e-300, 5e-324, 1.0, 12.0])
values = st.lists(st.one_of(any_floats, edge_floats), max_size=300)
chunkings = st.lists(st.integers(0, 120), max_size=8)
window_sizes = st.integers(1, 120)


def bits(samples: tuple[float, ...]) -> tuple[bytes, ...]:
    return tuple(struct.pack("<d", x) for x in samples)


def state(window: ComputeWindow) -> tuple[tuple[bytes, ...], int, int]:
    return bits(window.samples), window.total, window.rejected


def split(items: list[float], sizes: list[int]) -> list[list[float]]:
    """``items`` in consecutive chunks of ``sizes`` (then the rest as one chunk)."""
    parts, at = [], 0
    for size in sizes:
        parts.append(items[at : at + size])
        at += size
    parts.append(items[at:])
    return parts


@untimed
@given(values, chunkings, window_sizes)
@example([1.0, -0.0, math.nan, 2.0], [2], 1)
@example([math.inf] * 5 + [3.0] * 5, [3, 3], 2)
def test_extend_is_adding_one_by_one(items: list[float], sizes: list[int], size: int) -> None:
    one_by_one, at_once = ComputeWindow(window=size), ComputeWindow(window=size)
    for part in split(items, sizes):
        kept = [one_by_one.add(x) for x in part]
        assert at_once.extend(np.array(part, dtype=np.float64)) == sum(kept)
        assert state(at_once) == state(one_by_one)
    assert at_once.estimate() == one_by_one.estimate() or (
        math.isnan(at_once.estimate()) and math.isnan(one_by_one.estimate())
    )


@untimed
@given(st.lists(st.one_of(any_floats, st.integers(-5, 5), st.booleans(), st.none(), st.just("3")), max_size=40),
       window_sizes)  # fmt: skip
def test_extend_with_anything_but_a_float_array_adds_one_by_one(items: list[object], size: int) -> None:
    one_by_one, at_once = ComputeWindow(window=size), ComputeWindow(window=size)
    kept = [one_by_one.add(x) for x in items]  # type: ignore[arg-type]  # bad samples on purpose
    assert at_once.extend(items) == sum(kept)  # type: ignore[arg-type]
    assert state(at_once) == state(one_by_one)


def test_extend_checks_numpy_scalars_as_add_does() -> None:
    """A float32 or bool array is not float64: added one by one, where add rejects its numpy scalars."""
    for dtype in (np.float32, np.bool_, np.int64):
        one_by_one, at_once = ComputeWindow(window=4), ComputeWindow(window=4)
        array = np.array([1, 0, 2], dtype=dtype)
        kept = [one_by_one.add(x) for x in array]
        assert at_once.extend(array) == sum(kept)
        assert state(at_once) == state(one_by_one)


def test_extend_hand_worked() -> None:
    window = ComputeWindow(window=3)
    assert window.extend(np.array([5.0, math.nan, -1.0, 1.0, 2.0, math.inf, 3.0, 4.0])) == 5
    assert window.samples == (2.0, 3.0, 4.0)
    assert (window.total, window.rejected) == (5, 3)
    assert window.extend(np.array([], dtype=np.float64)) == 0
    assert window.samples == (2.0, 3.0, 4.0)


@untimed
@given(st.lists(st.tuples(st.sampled_from(["GL", "GP", "LM", "scan"]), st.one_of(any_floats, edge_floats)),
                max_size=200))  # fmt: skip
def test_record_many_is_recording_one_by_one(runs: list[tuple[str, float]]) -> None:
    spec = load_spec(NAV2D)
    one_by_one, at_once = Measurements.for_spec(spec), Measurements.for_spec(spec)
    for node, ms in runs:
        one_by_one.record(node, ms)
    for node in at_once.nodes:
        at_once.record_many(node, np.array([ms for name, ms in runs if name == node], dtype=np.float64))
    assert at_once.snapshot().keys() == one_by_one.snapshot().keys()
    for node, snap in at_once.snapshot().items():
        theirs = one_by_one.snapshot()[node]
        assert (snap.count, snap.total, snap.rejected) == (theirs.count, theirs.total, theirs.rejected)
    assert at_once.estimates() == one_by_one.estimates()
    assert at_once.estimates(measured_only=True) == one_by_one.estimates(measured_only=True)


def test_record_many_for_an_unmeasured_node_is_an_error() -> None:
    measurements = Measurements.for_spec(load_spec(NAV2D))
    with pytest.raises(UsageError, match=r"'odom': not a scheduled node"):
        measurements.record_many("odom", np.array([1.0]))


@untimed
@given(
    earlier=st.lists(st.floats(0.0, 1e6), min_size=1, max_size=50),
    later=st.lists(st.one_of(any_floats, edge_floats), max_size=120),
    size=st.integers(1, 40),
    as_array=st.booleans(),
)
def test_earlier_samples_count_as_if_added_first(
    earlier: list[float], later: list[float], size: int, as_array: bool
) -> None:
    # The oracle adds the earlier (valid) samples too; the window cannot tell them apart from nothing,
    # so long as at least a window's worth of valid samples follow them.
    oracle, told = ComputeWindow(window=size), ComputeWindow(window=size)
    accepted = sum(oracle.add(x) for x in [*earlier, *later])
    given_later = np.array(later, dtype=np.float64) if as_array else later
    if sum(math.isfinite(x) and x >= 0 for x in later) < size:
        with pytest.raises(ValueError, match="would have kept some"):
            told.extend(given_later, earlier=len(earlier))
        assert state(told) == state(ComputeWindow(window=size))  # nothing taken in
        return
    assert told.extend(given_later, earlier=len(earlier)) == accepted
    assert state(told) == state(oracle)


def test_a_negative_earlier_count_is_an_error() -> None:
    with pytest.raises(ValueError, match="a count >= 0"):
        ComputeWindow(window=1).extend(np.array([1.0]), earlier=-1)
