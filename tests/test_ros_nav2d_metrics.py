"""The nav2d benchmark's own figures (benchmarks/ros_nav2d.py), on hand-made run records: no ROS 2 needed."""

from __future__ import annotations

from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from benchmarks.ros_nav2d import stale_runs


def run(node: str, start: int, end: int, origin: int | None) -> dict[str, Any]:
    return {"node": node, "start_ns": start, "end_ns": end, "origin_ns": origin}


# scan A (stamp 1) ends at 10, scan B (stamp 2) at 20; LM reads A at 15 (fresh), A again at 25 (stale: B ended at
# 20), B at 30 (fresh).
ROWS = [
    run("scan", 1, 10, 1),
    run("scan", 2, 20, 2),
    run("LM", 15, 16, 1),
    run("LM", 25, 26, 1),
    run("LM", 30, 31, 2),
]


def test_a_run_that_reads_an_older_scan_than_one_ended_before_it_is_stale() -> None:
    assert stale_runs(ROWS, "scan", "LM", 0, 100) == (1, 3)


def test_only_the_windows_runs_count_compared_with_head_runs_from_before_it() -> None:
    assert stale_runs(ROWS, "scan", "LM", 22, 100) == (1, 2)  # B ended before the window: LM at 25 is stale
    assert stale_runs(ROWS, "scan", "LM", 26, 100) == (0, 1)  # the stale run started before the window
    assert stale_runs(ROWS, "scan", "LM", 0, 25) == (0, 1)  # [start, end): the one at 25 is after it


def test_a_run_before_any_head_run_ended_or_without_an_origin_is_not_counted() -> None:
    rows = [run("scan", 1, 10, 1), run("LM", 5, 6, 1), run("LM", 12, 13, None), run("LM", 14, 15, 1)]
    assert stale_runs(rows, "scan", "LM", 0, 100) == (0, 1)


@st.composite
def records(draw: st.DrawFn) -> list[dict[str, Any]]:
    heads = draw(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 5)), max_size=8))
    later = draw(st.lists(st.tuples(st.integers(0, 60), st.integers(0, 50)), max_size=8))
    return [run("scan", s, s + d, s) for s, d in heads] + [run("LM", s, s + 1, o) for s, o in later]


@given(records(), st.integers(0, 70))
def test_two_windows_side_by_side_count_what_their_union_counts(rows: list[dict[str, Any]], middle: int) -> None:
    first, second = stale_runs(rows, "scan", "LM", 0, middle), stale_runs(rows, "scan", "LM", middle, 100)
    assert stale_runs(rows, "scan", "LM", 0, 100) == (first[0] + second[0], first[1] + second[1])


@given(records())
def test_a_run_is_stale_exactly_when_a_newer_scan_ended_before_it_started(rows: list[dict[str, Any]]) -> None:
    heads = [row for row in rows if row["node"] == "scan"]
    counted = [row for row in rows if row["node"] == "LM" and any(head["end_ns"] <= row["start_ns"] for head in heads)]
    stale = sum(
        1
        for row in counted
        if any(head["end_ns"] <= row["start_ns"] and head["origin_ns"] > row["origin_ns"] for head in heads)
    )
    assert stale_runs(rows, "scan", "LM", 0, 100) == (stale, len(counted))
