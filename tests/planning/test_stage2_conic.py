"""The direct conic model of Stage II against the cvxpy reference, on random apps and the worked examples."""

from __future__ import annotations

import itertools
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import cvxpy as cp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.model.problem import Problem
from catanc.planning.stage1 import allocate
from catanc.planning.stage2.base import Layout, RelaxedSolution, SharedCore, Stage2Model
from catanc.planning.stage2.conic import ConicStage2
from catanc.planning.stage2.integer import most_runs, solve_integer
from catanc.planning.stage2.relaxed import RelaxedStage2
from catanc.spec.language import Spec
from tests.planning.test_stage2_integer import enumerate_best
from tests.support.strategies import spec_documents, spec_of

SPECS = Path(__file__).parents[2] / "specs"
AGREE = 1e-6
"""Both models solve to ~1e-7 or better; the integer search is exact to 5e-7 (its pruning tolerance)."""
AT_INFINITY = 1e-5
"""Where nothing bounds a batch subchain's ``f`` from above, the optimum lies at ``f = T = inf``
and each solver stops somewhere on the way there: the values agree less closely."""
MARGIN = 1e-5
"""Feasibility may differ only this close (relatively) to the boundary: the least scale at the scale."""

Box = dict[str, tuple[int, int]]


@st.composite
def app_documents(
    draw: st.DrawFn, max_subchains: int = 5, longest_runs: int | None = None
) -> tuple[dict[str, Any], Layout]:
    """A random app's document (batch heads, rate caps and floors, chain bounds) and where its subchains run.

    Each subchain is dedicated (1-2 cores) or on one of 1-3 shared cores, at least one shared.
    With ``longest_runs``, the minimum slice keeps every ``n = 1/f`` at most that.  The document is not
    parsed here: a strategy that filters on what the document says rejects an app before paying its parse.
    """
    document: dict[str, Any] = draw(spec_documents(max_subchains=max_subchains, max_threads=2))
    subchains: dict[str, list[str]] = document["subchains"]
    names = list(subchains)
    for name in draw(st.lists(st.sampled_from(names), max_size=2, unique=True)):
        head = subchains[name][0]
        document["nodes"][head]["batch"] = draw(st.sampled_from([True, {"output_rate_hz": 2.5}]))
    if longest_runs is None:
        min_slice = draw(st.sampled_from([0.0, 0.5, 1.0, 4.0]))
    else:
        longest = max(sum(document["nodes"][n]["compute_ms"] for n in members) for members in subchains.values())
        min_slice = round(longest / longest_runs + 0.01, 3)
    document["schedule"] = {
        "min_slice_ms": min_slice,
        "slack": draw(st.sampled_from([0.0, 0.05])),
        "switch_ms": draw(st.sampled_from([0.0, 0.12])),
    }
    places = draw(st.lists(st.integers(0, 3), min_size=len(names), max_size=len(names)))
    if all(place == 0 for place in places):
        places[draw(st.integers(0, len(names) - 1))] = 1
    dedicated = tuple((name, draw(st.integers(1, 2))) for name, place in zip(names, places, strict=True) if not place)
    shared = tuple(
        SharedCore(core, tuple(name for name, place in zip(names, places, strict=True) if place == core))
        for core in sorted(set(places) - {0})
    )
    return document, Layout(dedicated, shared)


@st.composite
def apps(draw: st.DrawFn, max_subchains: int = 5, longest_runs: int | None = None) -> tuple[Spec, Layout]:
    """:func:`app_documents`, parsed: the app's spec and where its subchains run."""
    document, layout = draw(app_documents(max_subchains, longest_runs))
    return spec_of(document), layout


def batch_heads(document: dict[str, Any]) -> set[str]:
    """The subchains of an :func:`app_documents` document whose head is a batch node (``Subchain.batch``)."""
    return {name for name, members in document["subchains"].items() if document["nodes"][members[0]].get("batch")}


def capped(document: dict[str, Any]) -> set[str]:
    """The subchains of an :func:`app_documents` document with a node capped in rate (``min_period_ms > 0``):
    a node constraint with a finite highest rate."""
    member_of = {node: name for name, members in document["subchains"].items() for node in members}
    return {
        member_of[constraint["node"]]
        for constraint in document.get("constraints", [])
        if constraint.get("node") in member_of and ("max_rate_hz" in constraint or "rate_hz" in constraint)
    }


def models(spec: Spec, problem: Problem, layout: Layout) -> tuple[ConicStage2, RelaxedStage2]:
    conic = ConicStage2(problem, layout, spec.schedule)
    relaxed = RelaxedStage2(problem, layout, spec.schedule)
    relaxed.set_numbers(problem)
    return conic, relaxed


def draw_box(data: st.DataObject, problem: Problem, spec: Spec, model: Stage2Model) -> Box:
    """A box on some of the non-batch ``n``: whole ranges, narrow ranges, single values."""
    box: Box = {}
    for name in model.integral:
        most = most_runs(problem.subchain(name).compute_ms, spec.schedule)
        if data.draw(st.booleans(), label=f"box {name}"):
            low = data.draw(st.integers(1, min(most, 200)), label=f"low {name}")
            high = data.draw(st.integers(low, min(most, low + data.draw(st.sampled_from([0, 1, 5, 200])))))
            box[name] = (low, high)
    return box


def tolerance(*solutions: RelaxedSolution | None) -> float:
    fractions = [f for solution in solutions if solution is not None for f in solution.fraction.values()]
    return AT_INFINITY if max(fractions, default=0.0) > 1e3 else AGREE


def tight(relaxed: RelaxedStage2, scale: float | None) -> float | None:
    """The reference's optimum solved to 1e-10 (None: infeasible), the scale-free twin's for ``scale=None``.

    The arbiter where the two models differ by more than :data:`AGREE`: at its default tolerances
    the reference is itself up to ~2e-6 off on degenerate relaxations (no switch cost and no minimum
    slice, so ``T`` and ``f`` may shrink together), where the conic model is not.
    """
    problem = relaxed.problem_scale if scale is None else relaxed.problem_gp
    relaxed.scale.value = 1.0 if scale is None else scale
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
        try:
            problem.solve(gp=True, solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
        except cp.SolverError:  # pragma: no cover - Clarabel gave up
            return None
    return float(problem.value) if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) else None


def assert_same_value(
    found: RelaxedSolution, expected: RelaxedSolution, relaxed: RelaxedStage2, scale: float | None
) -> None:
    rel = tolerance(found, expected)
    if found.objective != pytest.approx(expected.objective, rel=rel):
        truth = tight(relaxed, scale)
        assert truth is not None
        assert found.objective == pytest.approx(truth, rel=rel)


def assert_agree(
    conic: ConicStage2,
    relaxed: RelaxedStage2,
    found: RelaxedSolution | None,
    expected: RelaxedSolution | None,
    scale: float,
) -> None:
    """The same optimum, or both infeasible; or a feasibility verdict that differs on the boundary only."""
    if found is not None and expected is not None:
        assert_same_value(found, expected, relaxed, scale)
        return
    if found is None and expected is None:
        return
    least = conic.solve_least_scale()
    assert least is not None, "one model found a plan where the box allows none"
    assert least.objective == pytest.approx(scale, rel=MARGIN), "the models disagree on feasibility"


def changed(problem: Problem, factors: list[float]) -> Problem:
    """The same problem with every node's compute time multiplied by a factor."""
    cycle = itertools.cycle(factors)
    subchains = tuple(
        replace(sub, node_compute_ms=tuple(round(c * next(cycle), 3) for c in sub.node_compute_ms))
        for sub in problem.subchains
    )
    return replace(problem, subchains=subchains)


@pytest.mark.slow
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    app=apps(),
    scale=st.sampled_from([0.7, 1.0, 2.0, 1e6]),
    factors=st.lists(st.sampled_from([0.25, 0.5, 0.9, 1.1, 2.0, 3.0]), min_size=1, max_size=4),
    data=st.data(),
)
def test_conic_model_agrees_with_the_reference(
    app: tuple[Spec, Layout], scale: float, factors: list[float], data: st.DataObject
) -> None:
    spec, layout = app
    problem = build_problem(spec)
    conic, relaxed = models(spec, problem, layout)
    assert conic.integral == relaxed.integral
    assert conic.shared_names == relaxed.shared_names
    assert conic.dedicated_names == relaxed.dedicated_names
    for numbers in (problem, changed(problem, factors)):  # the second: the same objects re-solved
        conic.set_numbers(numbers)
        relaxed.set_numbers(numbers)
        for box in ({}, draw_box(data, numbers, spec, conic)):
            conic.set_box(box)
            relaxed.set_box(box)
            found, expected = conic.solve(scale), relaxed.solve(scale)
            assert_agree(conic, relaxed, found, expected, scale)
            if found is not None:
                assert set(found.fraction) == set(conic.shared_names)
                assert set(found.core_period_ms) == {core.core for core in layout.shared}
            least, expected_least = conic.solve_least_scale(), relaxed.solve_least_scale()
            assert (least is None) == (expected_least is None)
            if least is not None and expected_least is not None:
                assert_same_value(least, expected_least, relaxed, None)
                assert least.objective >= 1.0 - 1e-7


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(app=apps(max_subchains=4, longest_runs=6), scale=st.sampled_from([1.0, 1e6]))
def test_integer_search_agrees_with_either_model(app: tuple[Spec, Layout], scale: float) -> None:
    spec, layout = app
    problem = build_problem(spec)
    conic, relaxed = models(spec, problem, layout)
    found, expected = (
        solve_integer(conic, problem, scale, enumerate_up_to=0),
        solve_integer(relaxed, problem, scale, enumerate_up_to=0),
    )
    if found is not None and expected is not None:
        rel = tolerance(found.solution, expected.solution)
        if found.objective != pytest.approx(expected.objective, rel=rel):
            # Arbitrate with the reference solved tightly at both searches' answers: equally good,
            # and the conic model's value right.
            relaxed.set_box({name: (n, n) for name, n in found.runs.items()})
            mine = tight(relaxed, scale)
            relaxed.set_box({name: (n, n) for name, n in expected.runs.items()})
            theirs = tight(relaxed, scale)
            assert mine is not None
            assert theirs is not None
            assert mine == pytest.approx(theirs, rel=rel)
            assert found.objective == pytest.approx(mine, rel=rel)
        return
    if found is None and expected is None:
        return
    least = solve_integer(conic, problem, least_scale=True)  # the verdicts may differ on the boundary only
    assert least is not None
    assert least.objective == pytest.approx(scale, rel=MARGIN)


@pytest.mark.parametrize(("name", "cores"), [("nav2d", 2), ("vr_illixr", 1)])
def test_worked_examples(name: str, cores: int) -> None:
    spec = load_spec(SPECS / f"{name}.yaml")
    problem = build_problem(spec)
    layout = Layout.from_allocation(allocate(problem, cores).allocation)
    conic, relaxed = models(spec, problem, layout)
    found = solve_integer(conic, problem, enumerate_up_to=0)
    expected = solve_integer(relaxed, problem, enumerate_up_to=0)
    assert found is not None
    assert expected is not None
    assert found.objective == pytest.approx(expected.objective, rel=AGREE)
    assert found.runs == expected.runs
    assert found.root_bound == pytest.approx(expected.root_bound, rel=AGREE)
    if name == "vr_illixr":  # no batch subchain: every integer vector in closed form is the oracle
        oracle = enumerate_best(problem, layout, spec.schedule, 1.0)
        assert oracle is not None
        assert found.objective == pytest.approx(oracle, rel=1e-6)


def test_a_re_solve_only_updates_b() -> None:
    spec = load_spec(SPECS / "vr_illixr.yaml")
    problem = build_problem(spec)
    layout = Layout.from_allocation(allocate(problem, 1).allocation)
    model = ConicStage2(problem, layout, spec.schedule)
    assert model.solve() is not None
    solver = model.solver
    assert solver is not None
    assert solver.is_data_update_allowed()
    slower = changed(problem, [1.2])
    model.set_numbers(slower)
    model.set_box({"vio": (6, 6)})
    again = model.solve()
    assert model.solver is solver  # the same Clarabel solver: A and its factorisation kept
    assert model.updates == 1
    # ... and the update took: the answer is a fresh model's for the new numbers.
    fresh = ConicStage2(slower, layout, spec.schedule)
    fresh.set_box({"vio": (6, 6)})
    expected = fresh.solve()
    assert again is not None
    assert expected is not None
    assert again.objective == pytest.approx(expected.objective, rel=1e-9)
    assert again.fraction["vio"] == pytest.approx(1 / 6)


def test_runtime_path_imports_neither_cvxpy_nor_scipy() -> None:
    """The re-optimiser's first plans (nav2d on 1 and 2 cores) load neither: each costs every run
    start-up time (scipy.sparse ~0.15 s of CPU)."""
    code = (
        "import sys; from catanc.model.load import load_spec; from catanc.planning.replan import Replanner; "
        f"spec = load_spec({str(SPECS / 'nav2d.yaml')!r}); Replanner(spec, 1); Replanner(spec, 2); "
        "print(sorted(name for name in ('cvxpy', 'scipy') if name in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
