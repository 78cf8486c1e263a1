"""A process whose nodes share one thread is planned as one executor (catanc.spec.executors).

The oracle is the executors' own: the brute-force Stage I of tests/planning/test_executors.py, told
which nodes share a thread by an ``executors:`` entry written from the random app, while the
planner under test reads the same nodes as a process of the deploy section.  Whole plans are
checked for what the issue asks (no process of one thread on two core sets), and nav2d's Navigator
(GP blocking NC in one thread) against the simulator, which serialises the process's nodes.
"""

from __future__ import annotations

import copy
from typing import Any, Literal

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.errors import InfeasibleError
from catanc.model.build import build_problem
from catanc.planning.planner import plan_problem
from catanc.planning.stage1 import allocate
from catanc.sim.simulate import Setup, simulate
from catanc.spec.language import Spec
from tests.planning.test_executors import brute_force, close, keeps_executors_together, problem_with_executors
from tests.support.scenario_specs import SPECS
from tests.support.strategies import spec_documents, spec_of

Kind = Literal["python", "plain", "isolated"]


def as_processes(document: dict[str, Any], kind: Kind) -> dict[str, Any]:
    """The app with each ``executors:`` entry made a process of its own instead: a Python one (``python``),
    a ROS one naming no callback group (``plain``), or a ROS one whose nodes each name one (``isolated``)."""
    data = copy.deepcopy(document)
    deploy: dict[str, Any] = {}
    for name, nodes in data.pop("executors", {}).items():
        for index, node in enumerate(nodes):
            entry: dict[str, Any] = {"process": f"proc_{name}"}
            if index == 0:
                entry["command"] = "python3 app.py" if kind == "python" else "ros2 run demo app"
            if kind == "isolated":
                entry |= {"ros_node": f"/{node}", "callback_group": f"/{node}@Timer(1000000)"}
            deploy[node] = entry
    if deploy:
        data["deploy"] = deploy
    return data


def without_executors(document: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(document)
    data.pop("executors", None)
    return data


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(
    document=spec_documents(max_subchains=6, with_executors=True),
    cores=st.integers(1, 4),
    kind=st.sampled_from(["python", "plain", "isolated"]),
)
def test_stage1_reads_processes_as_the_executors_they_are(document: dict[str, Any], cores: int, kind: Kind) -> None:
    # The oracle's app: the executors as entries (a process of one thread), or none (threads of their own).
    told = document if kind != "isolated" else without_executors(document)
    spec, _ = problem_with_executors(told)
    problem = build_problem(spec_of(as_processes(document, kind)))
    scores = brute_force(spec, problem, cores)
    if not scores:
        return  # no allocation keeps them together: test_executors checks the error
    least = min(scale for scale, _ in scores)
    allowed = least * (1 + 1e-6) if least > 1 else 1.0
    best = min(objective for scale, objective in scores if scale <= allowed)
    found = allocate(problem, cores, method="exhaustive", time_limit_s=60)
    assert close(found.constraint_scale, least), (found, least)
    assert close(found.objective, best), (found, best)
    assert keeps_executors_together(spec, found.allocation.groups), found.allocation


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(document=spec_documents(max_subchains=4, with_executors=True, max_threads=2), cores=st.integers(1, 3))
def test_a_python_process_never_runs_on_two_core_sets(document: dict[str, Any], cores: int) -> None:
    told, _ = problem_with_executors(document)  # skips apps whose threads cannot keep up with their floors
    spec = spec_of(as_processes(document, "python"))
    problem = build_problem(spec)
    if not brute_force(told, problem, cores):
        with pytest.raises(InfeasibleError, match="every core must run a subchain"):
            plan_problem(problem, spec.schedule, cores)
        return
    plan = plan_problem(problem, spec.schedule, cores)
    for nodes in told.executors.values():
        placed = {plan.placement(node)[0] for node in nodes}
        assert len(placed) == 1, (nodes, placed)
        subchains = {problem.subchain_of(node).name for node in nodes}
        if len(subchains) > 1:  # taking turns across subchains: on one shared core
            assert all(plan.subchains[name].shared for name in subchains)
            assert len(next(iter(placed))) == 1


def nav2d_fixed() -> Spec:
    """nav2d, its deploy section's processes included, with every compute time at its planned mean."""
    data = yaml.safe_load((SPECS / "nav2d.yaml").read_text())
    for node in data["nodes"].values():
        node.pop("workload", None)
    data["nodes"]["GL"]["compute_ms"] = 3.2  # its modes' mean
    return spec_of(data)


def test_nav2d_plans_its_processes_as_executors() -> None:
    problem = build_problem(nav2d_fixed())
    assert [(e.name, e.nodes, e.process) for e in problem.executors] == [
        ("mapper", ("GL", "GM"), "/Mapper"),  # the spec's entry, which the Mapper process makes anyway
        ("/Operator", ("LM", "LP"), "/Operator"),
        ("/Navigator", ("GP", "NC"), "/Navigator"),
    ]
    assert problem.together == (("GL", "GM"), ("GP", "NC"))
    assert problem.subchain("local").serial == ((1, 2),)


@pytest.mark.slow
@pytest.mark.parametrize("cores", [2, 3])
def test_nav2d_navigators_nc_runs_at_about_its_predicted_rate(cores: int) -> None:
    # GP's 100 ms runs hold the Navigator's thread, and NC's triggers meanwhile are lost.  Simulated 60 s:
    # NC 35.5 and 113.6 Hz against 36.5 and 109.4 predicted on 2 and 3 cores (before the Navigator was an
    # executor the plan promised 41.0 and 120.0).
    spec = nav2d_fixed()
    problem = build_problem(spec)
    plan = plan_problem(problem, spec.schedule, cores)
    predicted = plan.subchains["NC"].rate_as_run_hz
    assert predicted < 0.95 * 1000.0 / plan.subchains["NC"].period_ms  # the thread costs NC triggers
    result = simulate(Setup(spec, cores, 30.0, 0), "catan")
    assert result.nodes["NC"].rate_hz == pytest.approx(predicted, rel=0.08)
    assert result.nodes["GL"].rate_hz == pytest.approx(plan.subchains["GL"].rate_as_run_hz, rel=0.08)
