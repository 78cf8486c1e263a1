"""Threads and speedups: how many threads a node runs with, and what a plan gives the enforcer."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from catanc.control.schedule import runtime_schedule
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.planning.planner import plan
from catanc.spec.speedup import best_speedup, threads_used

speedup_lists = st.lists(st.floats(0.2, 64, allow_nan=False), max_size=7).map(lambda rest: (1.0, *rest))


def test_threads_used_by_hand() -> None:
    assert threads_used((1.0, 1.8), 2) == 2
    assert threads_used((1.0, 1.8), 1) == 1
    assert threads_used((1.0, 1.8, 1.8), 3) == 2  # the third thread adds nothing: not used
    assert threads_used((1.0, 0.9), 2) == 1  # slower on two: stays on one
    assert threads_used((1.0,), 4) == 1


@given(speedups=speedup_lists, allowed=st.integers(1, 10))
def test_threads_used_is_the_fewest_reaching_the_best_speedup(speedups: tuple[float, ...], allowed: int) -> None:
    q = threads_used(speedups, allowed)
    assert 1 <= q <= min(allowed, len(speedups))
    assert speedups[q - 1] == best_speedup(speedups, allowed)
    assert all(s < speedups[q - 1] for s in speedups[: q - 1])  # by enumeration: no fewer threads reach it


SPEC = """\
catan: 1
app: threads
nodes:
  solve: {compute_ms: 20, threads: {max: 3, speedup: [1.0, 1.8, 1.8]}}
  post: {compute_ms: 2}
  other: {compute_ms: 5, threads: {max: 2, speedup: [1.0, 1.5]}}
edges: [[solve, post]]
subchains: {main: [solve, post], side: [other]}
objective:
  - {node: post, weight: 1.0}
  - {node: other, weight: 0.001}
"""


def test_the_runtime_schedule_gives_each_node_the_threads_its_plan_allows() -> None:
    spec = parse_spec(SPEC)
    for cores in (1, 2, 3):
        result = plan(spec, cores)
        schedule = runtime_schedule(result, build_problem(spec), spec.schedule)
        for name, run in schedule.subchains.items():
            q = result.subchains[name].threads
            for index, node in enumerate(run.nodes):
                speedups = spec.nodes[node].threads.speedups
                threads, speedup = run.threads_of(index)
                assert threads == threads_used(speedups, q)
                assert speedup == speedups[threads - 1]
                if run.shared:
                    assert (threads, speedup) == (1, 1.0)
