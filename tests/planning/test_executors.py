"""Nodes that share one executor thread (docs/explanation/model.md section 6): spec checks, Stage I, Eq. 1.

Stage I's oracle here is written from the spec alone: every set partition of
the subchains into shared groups and dedicated singletons, kept when each
executor's subchains lie in one shared group, scored by the analytic model.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from catanc.errors import ExitCode, InfeasibleError, SpecError
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.model.metrics import capped_dedicated, dedicated_timing
from catanc.model.problem import Problem
from catanc.planning.stage1 import Option, allocate, next_best
from catanc.planning.stage1.estimate import evaluate, option_table
from catanc.planning.stage1.exhaustive import set_partitions
from catanc.sim.simulate import EngineChoice
from catanc.spec.language import Spec
from tests.support.strategies import spec_documents, spec_of

REL = 1e-6


def close(a: float, b: float) -> bool:
    return abs(a - b) <= REL * max(1.0, abs(a), abs(b))


def owners(spec: Spec) -> list[set[str]]:
    """Each executor's subchains, straight from the spec."""
    member = {node: name for name, nodes in spec.subchains.items() for node in nodes}
    return [{member[node] for node in nodes} for nodes in spec.executors.values()]


def keeps_executors_together(spec: Spec, groups: list[list[str]] | tuple[tuple[str, ...], ...]) -> bool:
    for subs in owners(spec):
        if len(subs) < 2:
            continue
        if not any(subs <= set(group) for group in groups):
            return False
    return True


def brute_force(spec: Spec, problem: Problem, cores: int) -> list[tuple[float, float]]:
    """(scale, objective) of every allocation that keeps each executor's subchains in one group."""
    names = list(spec.subchains)
    table = option_table(problem, cores)
    scores = []
    for partition in set_partitions(names, most_blocks=cores):
        singles = [block[0] for block in partition if len(block) == 1]
        groups = [block for block in partition if len(block) > 1]
        # an executor spanning subchains merges with others that share a subchain: check on the merged sets
        if not keeps_executors_together(spec, groups):
            continue
        extra = cores - len(singles) - len(groups)
        if extra < 0:
            continue
        for spread in itertools.product(range(extra + 1), repeat=len(singles)):
            if sum(spread) > extra or (len(names) >= cores and sum(spread) != extra):
                continue
            options = {name: Option(False, 1 + more) for name, more in zip(singles, spread, strict=True)}
            options.update({name: Option(True, len(group)) for group in groups for name in group})
            evaluation = evaluate(problem, table, options)
            scores.append((evaluation.scale, evaluation.objective))
    return scores


def problem_with_executors(document: dict[str, Any]) -> tuple[Spec, Problem]:
    try:
        spec = spec_of(document)
    except SpecError:
        assume(False)  # an executor that cannot keep up with its rate floors: a spec error, tested below
        raise
    return spec, build_problem(spec)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(document=spec_documents(max_subchains=6, with_executors=True), cores=st.integers(1, 4))
def test_stage1_with_executors_matches_brute_force(document: dict[str, Any], cores: int) -> None:
    spec, problem = problem_with_executors(document)
    scores = brute_force(spec, problem, cores)
    if not scores:
        for method in ("exhaustive", "milp"):
            with pytest.raises(InfeasibleError, match="every core must run a subchain"):
                allocate(problem, cores, method=method, time_limit_s=60)
        return
    least = min(scale for scale, _ in scores)
    allowed = least * (1 + 1e-6) if least > 1 else 1.0
    best = min(objective for scale, objective in scores if scale <= allowed)
    for method in ("exhaustive", "milp"):
        found = allocate(problem, cores, method=method, time_limit_s=60)
        assert found.optimal
        assert close(found.constraint_scale, least), (method, found, least)
        assert close(found.objective, best), (method, found, best)
        assert keeps_executors_together(spec, found.allocation.groups), found.allocation
        assert found.allocation.cores_used <= cores


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(document=spec_documents(max_subchains=5, with_executors=True), cores=st.integers(1, 3))
def test_runner_up_keeps_executors_together(document: dict[str, Any], cores: int) -> None:
    spec, problem = problem_with_executors(document)
    scores = brute_force(spec, problem, cores)
    assume(len({(round(s, 9), round(o, 9)) for s, o in scores}) >= 2)
    best = allocate(problem, cores, method="milp", time_limit_s=60)
    runner_up = next_best(problem, cores, [best.allocation], time_limit_s=60)
    assert runner_up.allocation.options() != best.allocation.options()
    assert keeps_executors_together(spec, runner_up.allocation.groups)


def load(text: str) -> Problem:
    return build_problem(parse_spec("catan: 1\napp: t\n" + text, "t.yaml"))


THREE = """nodes: {a: {compute_ms: 1}, b: {compute_ms: 2}, c: {compute_ms: 3}}
subchains: {A: [a], B: [b], C: [c]}
objective: [{node: a, weight: 1}, {node: b, weight: 1}, {node: c, weight: 1}]
schedule: {slack: 0}
"""


@pytest.mark.parametrize("method", ["exhaustive", "milp"])
def test_worked_example_executor_forces_sharing(method: str) -> None:
    # Without the executor each subchain gets a core of its own on 3 cores (periods 1, 2, 3: objective 6;
    # no slack, so dedicated periods are Eq. 1's).
    # With b and c in one thread, B and C must share a core: {A on 2 cores | B, C shared}; A's period is
    # still 1 (one node), B and C get fair shares 2*2 and 3*2: objective 1 + 4 + 6 = 11.
    free = allocate(load(THREE), 3, method=method)
    assert close(free.objective, 6.0)
    bound = allocate(load(THREE + "executors: {worker: [b, c]}\n"), 3, method=method)
    assert bound.allocation.groups == (("B", "C"),)
    assert bound.allocation.dedicated == (("A", 2),)
    assert close(bound.objective, 11.0)


def test_every_core_used_but_the_executor_forbids_it_is_infeasible() -> None:
    text = "nodes: {b: {compute_ms: 2}, c: {compute_ms: 3}}\nsubchains: {B: [b], C: [c]}\n" + (
        "objective: [{node: b, weight: 1}]\nexecutors:\n  worker: [b, c]\n"
    )
    problem = load(text)
    assert allocate(problem, 1).allocation.groups == (("B", "C"),)
    with pytest.raises(InfeasibleError) as caught:
        allocate(problem, 2)
    message = str(caught.value)
    assert message.startswith("t.yaml:7:3: executors.worker: on 2 cores")  # where the executor is declared
    assert "executor 'worker' runs b, c in one thread" in message
    assert "at most 1 core," in message


def test_cli_infeasible_executor_exit_code(tmp_path: Any) -> None:
    from catanc.cli import app

    spec_file = tmp_path / "two.yaml"
    spec_file.write_text(
        "catan: 1\napp: two\nnodes: {b: {compute_ms: 2}, c: {compute_ms: 3}}\nsubchains: {B: [b], C: [c]}\n"
        "objective: [{node: b, weight: 1}]\nexecutors:\n  worker: [b, c]\n"
    )
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["compile", str(spec_file), "--cores", "2", "--out", str(out)])
    assert result.exit_code == ExitCode.INFEASIBLE, result.output
    assert "two.yaml:7:3" in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_eq1_adds_up_an_executors_nodes_by_hand() -> None:
    # One subchain a -> b -> c (2, 3, 4 ms, one thread each) on 3 cores: 3 runs in flight, so Eq. 1 gives
    # p = max(4, 9 / 3) = 4. With b and c in one thread they form one stage of 3 + 4 = 7 ms: p = 7.
    times = [[2.0, 3.0, 4.0]] * 3
    assert dedicated_timing(times, 3).period_ms == 4.0
    assert dedicated_timing(times, 3, [(1, 2)]).period_ms == 7.0
    assert dedicated_timing(times, 3, [(1, 2)]).latency_ms == 9.0
    text = (
        "nodes: {a: {compute_ms: 2}, b: {compute_ms: 3}, c: {compute_ms: 4}}\nedges: [[a, b], [b, c]]\n"
        "subchains: {S: [a, b, c]}\nobjective: [{node: a, weight: 1}]\n"
    )
    assert capped_dedicated(load(text).subchain("S"), 3, 0.0).period_ms == 4.0
    bound = load(text + "executors: {worker: [b, c]}\n").subchain("S")
    assert bound.serial == ((1, 2),)
    assert capped_dedicated(bound, 3, 0.0).period_ms == 7.0
    # On one core nothing overlaps anyway: 9 ms either way; the slack stretches the period alone.
    assert capped_dedicated(bound, 1, 0.0).period_ms == 9.0
    assert capped_dedicated(bound, 3, 0.3).period_ms == 10.0
    assert capped_dedicated(bound, 3, 0.3).latency_ms == 9.0


def test_executor_overload_is_a_spec_error() -> None:
    text = (
        "nodes: {b: {compute_ms: 8}, c: {compute_ms: 10}}\nsubchains: {B: [b], C: [c]}\n"
        "objective: [{node: b, weight: 1}]\n"
        "constraints: [{node: b, min_rate_hz: 80}, {node: c, min_rate_hz: 50}]\n"
        "executors:\n  worker: [b, c]\n"
    )
    with pytest.raises(SpecError) as caught:
        load(text)
    message = str(caught.value)
    assert message.startswith("t.yaml:8:3: executors.worker:")
    assert "b at >= 80 Hz needs 64%, c at >= 50 Hz needs 50%" in message
    assert "114%" in message
    # Apart, each fits a core of its own.
    load(text.replace("executors:\n  worker: [b, c]\n", ""))


def test_nav2d_mapper_shares_a_core() -> None:
    from catanc.model.load import load_spec
    from catanc.planning.planner import plan

    spec = load_spec("specs/nav2d.yaml")
    problem = build_problem(spec)
    # The spec's mapper, and its deploy section's Navigator process (GP and NC in one thread).
    assert problem.together == (("GL", "GM"), ("GP", "NC"))
    for cores in (1, 2, 3):
        result = plan(spec, cores)
        for a, b in problem.together:
            assert result.subchains[a].cores == result.subchains[b].cores
            assert result.subchains[a].shared
            assert result.stage1.allocation.options()[a] == result.stage1.allocation.options()[b]
        assert math.isfinite(result.objective)


TWO_TIMERS = {
    "catan": 1,
    "app": "two",
    "nodes": {"a": {"compute_ms": 10}, "b": {"compute_ms": 10}, "c": {"compute_ms": 1}},
    "subchains": {"A": ["a"], "B": ["b"], "C": ["c"]},
    "objective": [{"node": "a", "weight": 1}],
    "baseline": {"rates_hz": {"a": 10, "b": 10, "c": 10}},
}


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["python", "compiled"])
def test_the_simulator_runs_an_executors_nodes_one_after_the_other(engine: EngineChoice) -> None:
    # Baseline on 3 cores, a and b (10 ms each) on 10 Hz timers from t = 0. Apart, each takes a core:
    # both done at 10 ms. In one executor, b waits for a: done at 20 ms, every period; c is unaffected.
    # No workload: every run takes its compute_ms.
    from catanc.sim.simulate import Setup, simulate

    apart = simulate(Setup(spec_of(TWO_TIMERS), 3, 0.35, 0), "baseline", engine=engine)
    assert list(apart.node_done_ms["a"]) == pytest.approx([10, 110, 210, 310])
    assert list(apart.node_done_ms["b"]) == pytest.approx([10, 110, 210, 310])
    together = simulate(
        Setup(spec_of({**TWO_TIMERS, "executors": {"worker": ["a", "b"]}}), 3, 0.35, 0),
        "baseline",
        engine=engine,
    )
    assert list(together.node_done_ms["a"]) == pytest.approx([10, 110, 210, 310])
    assert list(together.node_done_ms["b"]) == pytest.approx([20, 120, 220, 320])
    assert list(together.node_done_ms["c"]) == list(apart.node_done_ms["c"])


def test_explain_says_how_long_a_run_can_wait_for_its_executor() -> None:
    # One core, b (2 ms) and c (3 ms) in one executor and nothing else: while c runs, the thread has all the
    # app gets of the core (its slots and b's slot, whose owner is the same thread), 1 - 0.05 of slack, so
    # b waits for c's 3 ms of compute, 3 / 0.95 = 3.16 ms.
    from catanc.explain.analysis import explain_plan
    from catanc.planning.planner import plan

    spec = parse_spec(
        "catan: 1\napp: t\nnodes: {b: {compute_ms: 2}, c: {compute_ms: 3}}\nsubchains: {B: [b], C: [c]}\n"
        "objective: [{node: b, weight: 1}, {node: c, weight: 1}]\nexecutors: {worker: [b, c]}\n"
    )
    result = plan(spec, 1)
    (note,) = explain_plan(spec, build_problem(spec), result).executors
    assert note.startswith("Executor worker runs b, c in one thread (never at once): subchains B, C share core 0")
    assert "up to about 3.2 ms for b behind c (3 ms of compute, at what the slack and the other subchains" in note
    assert "objective as run" not in note  # each hold is shorter than two of the waiter's periods: nothing is lost
