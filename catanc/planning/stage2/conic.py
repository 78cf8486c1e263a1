"""Stage II's relaxed GP written directly as an exponential-cone program for Clarabel (the runtime path).

The program is :class:`~catanc.planning.stage2.relaxed.RelaxedStage2`'s, constraint for
constraint, written without cvxpy: a re-solve costs one Clarabel solve and a
few vector operations instead of cvxpy's ~5 ms, and the runtime never
imports cvxpy.  In log variables ``x = log(T, f, p, P)``:

- a constraint with one term, ``C exp(a.x) <= 1``, is the linear row ``a.x <= -log C``;
- a posynomial constraint ``sum_k C_k exp(a_k.x) <= 1`` with ``m > 1`` terms
  gets auxiliaries ``t_2..t_m`` and one exponential cone per term:
  ``(a_k.x + log C_k, 1, t_k)`` for ``k >= 2`` and ``(a_1.x + log C_1, 1, 1 - sum_k t_k)``;
- the objective is the log of its posynomial: an epigraph variable ``z`` with
  the same construction on ``C_k exp(a_k.x - z)`` (the linear ``a.x + log C``
  for a single term).  The objective reported is ``exp`` of it, in ms, so it
  is accurate relatively (Clarabel's tolerances are absolute below 1).

Every number that changes at runtime (compute times, slices, dedicated
constants, the box on ``f``, the bound scale) is a coefficient ``C``, so it
changes only ``b``: ``A``, ``q`` and the cones are built once, and a
re-solve updates ``b`` in place on a persistent Clarabel solver.  Each ``C``
is a weighted sum of parameters (``C = W v``), and equal monomials of a
posynomial are merged first.

The program is kept small without changing its optimum.  A period variable
``p >= T/f`` exists only for a subchain with a rate cap (elsewhere ``p = T/f``
at an optimum: every use of ``p`` is increasing in it).  A chain's longest
period ``P`` is the maximum of its candidates (its stages' periods and a
floor): a floor no larger than another candidate's rate cap is dropped,
chains with the same candidates share one ``P``, a single candidate is ``P``
itself, and a chain whose candidates include another's has that one's
``P`` as a candidate in their place.  Chains that no weighted term and no
bound uses are left out, and a bound with no variable in it (a dedicated
subchain's rate floor) is checked outside the solver.  A subchain's reported
period is ``max(T/f, p_min)``, the least the program allows.

The scale-free twin is a second program with ``log s`` in every bound,
``s >= 1``, and ``log s`` minimised.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import clarabel
import numpy as np
import numpy.typing as npt

from catanc.model.metrics import ChainForm, capped_dedicated, chain_form
from catanc.model.problem import Problem, Subchain
from catanc.planning.stage2.base import Layout, LayoutModel, RelaxedSolution, Stage2Model
from catanc.planning.stage2.sparse import CscMatrix
from catanc.spec.language import Schedule

__all__ = ["SETTINGS", "ConicStage2", "Stage2Model"]

Floats = npt.NDArray[np.float64]

Coefficient = dict[int, float]
"""A monomial's coefficient as weights on the parameters: ``C = sum_j w_j v_j``."""
Key = tuple[tuple[int, float], ...]
"""A monomial's powers of the log variables, ``(column, power)`` sorted by column."""
Posynomial = dict[Key, Coefficient]

ONE = 0
"""The parameter that is always 1 (constant coefficients)."""

SMALLEST_FRACTION = 1e-9
"""The lower end of ``f`` when a box leaves it open (as in the reference model)."""

CONSTANT_TOLERANCE = 1e-9
"""A bound with no variable in it may exceed its scaled limit by this (relatively) and still hold:
the solver's own feasibility tolerance is ~1e-8."""

SETTINGS: dict[str, Any] = {
    "verbose": False,
    "presolve_enable": False,  # keep every row, so that b can be updated in place
    "input_sparse_dropzeros": False,
    # With the default 1e-8, objectives were up to 3e-7 off (as the cvxpy model's are); with 1e-9
    # at most 3e-8 (1,200 random relaxations against 1e-11), for ~14% more iterations.
    "tol_gap_abs": 1e-9,
    "tol_gap_rel": 1e-9,
    "tol_feas": 1e-9,
    # Together ~25% faster on these small programs, as accurate: iterative refinement of the
    # KKT solves costs more than it saves, and a longer backtracking step saves iterations.
    "iterative_refinement_enable": False,
    "linesearch_backtrack_step": 0.95,
}
"""Clarabel's settings for both programs."""

_ACCEPTED = (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved)


def _monomial(powers: Mapping[int, float], coefficient: Coefficient) -> Posynomial:
    return {tuple(sorted((column, power) for column, power in powers.items() if power)): dict(coefficient)}


def _add(total: Posynomial, part: Posynomial, factor: float = 1.0) -> None:
    """``total += factor * part``, merging equal monomials."""
    for key, coefficient in part.items():
        into = total.setdefault(key, {})
        for param, weight in coefficient.items():
            into[param] = into.get(param, 0.0) + factor * weight


def _times(part: Posynomial, factor: float) -> Posynomial:
    total: Posynomial = {}
    _add(total, part, factor)
    return total


def _over(part: Posynomial, column: int) -> Posynomial:
    """``part / exp(x[column])``: the constraint ``part <= exp(x[column])`` as ``... <= 1``."""
    total: Posynomial = {}
    for key, coefficient in part.items():
        powers = dict(key)
        powers[column] = powers.get(column, 0.0) - 1.0
        _add(total, _monomial(powers, coefficient))
    return total


@dataclass
class _Rows:
    """A conic program under construction: ``A`` as coordinates, and where each term's ``log C`` goes in ``b``.

    Rows are in two blocks, linear (the nonnegative cone) then exponential
    cones of three rows each; ``row`` numbers count within a block.
    """

    linear: int = 0
    cones: int = 0
    columns: int = 0
    entries: list[tuple[bool, int, int, float]] = field(default_factory=list)  # (in a cone, row, column, value)
    fixed_b: list[tuple[bool, int, float]] = field(default_factory=list)
    terms: list[tuple[bool, int, float, Coefficient]] = field(default_factory=list)  # (.., .., sign, C)

    def copy(self) -> _Rows:
        return _Rows(self.linear, self.cones, self.columns, list(self.entries), list(self.fixed_b), list(self.terms))

    def column(self) -> int:
        self.columns += 1
        return self.columns - 1

    def bound(self, column: int, value: float) -> int:
        """The linear row ``value * x[column] <= b``, its ``b`` set directly."""
        self.entries.append((False, self.linear, column, value))
        self.linear += 1
        return self.linear - 1

    def constraint(self, posynomial: Posynomial, shift: int | None = None) -> None:
        """``posynomial * exp(-x[shift]) <= 1`` (no shift: ``x[shift]`` = 0), a posynomial with variables."""
        terms = list(posynomial.items())
        if len(terms) == 1 and shift is None:  # C exp(a.x) <= 1: the row a.x <= -log C
            key, coefficient = terms[0]
            self.entries += [(False, self.linear, column, power) for column, power in key]
            self.terms.append((False, self.linear, -1.0, coefficient))
            self.linear += 1
            return
        auxiliary = [self.column() for _ in terms[1:]]
        for index, (key, coefficient) in enumerate(terms):
            first = 3 * self.cones
            self.cones += 1
            # (y, 1, w) in K_exp, i.e. exp(y) <= w, with y = a.x - x[shift] + log C = b - A x.
            self.entries += [(True, first, column, -power) for column, power in key]
            if shift is not None:
                self.entries.append((True, first, shift, 1.0))
            self.terms.append((True, first, 1.0, coefficient))
            self.fixed_b.append((True, first + 1, 1.0))
            if index == 0:  # w = 1 - sum_k t_k
                self.entries += [(True, first + 2, t, 1.0) for t in auxiliary]
                self.fixed_b.append((True, first + 2, 1.0))
            else:  # w = t_k
                self.entries.append((True, first + 2, auxiliary[index - 1], -1.0))


def _weights(coefficients: list[Coefficient], params: int) -> Floats:
    """The matrix ``W`` with ``C = W v``."""
    weights = np.zeros((len(coefficients), params))
    for index, coefficient in enumerate(coefficients):
        for param, weight in coefficient.items():
            weights[index, param] += weight
    return weights


class _Program:
    """One compiled conic program, its ``b``, and the persistent Clarabel solver that solves it."""

    def __init__(self, rows: _Rows, q: Floats, params: int) -> None:
        self.linear = rows.linear
        size = rows.linear + 3 * rows.cones
        places = [self.place(cone, row) for cone, row, _, _ in rows.entries]
        columns = [column for _, _, column, _ in rows.entries]
        values = [value for _, _, _, value in rows.entries]
        self.A = CscMatrix.from_entries((size, rows.columns), places, columns, values)
        self.P = CscMatrix.zeros((rows.columns, rows.columns))
        self.q = q
        self.cones = [clarabel.NonnegativeConeT(rows.linear)] if rows.linear else []
        self.cones += [clarabel.ExponentialConeT() for _ in range(rows.cones)]
        self.b = np.zeros(size)
        for cone, row, value in rows.fixed_b:
            self.b[self.place(cone, row)] = value
        self.term_rows = np.array([self.place(cone, row) for cone, row, _, _ in rows.terms], dtype=np.intp)
        self.term_signs = np.array([sign for _, _, sign, _ in rows.terms])
        self.weights = _weights([coefficient for _, _, _, coefficient in rows.terms], params)
        self.solver: clarabel.DefaultSolver | None = None
        self.updates = 0  # solves that only updated b on the persistent solver

    def place(self, cone: bool, row: int) -> int:
        return self.linear + row if cone else row

    def load(self, values: Floats) -> None:
        """Put every term's ``+-log C`` into ``b`` for the parameter values ``v``."""
        self.b[self.term_rows] = self.term_signs * np.log(self.weights @ values)

    def run(self, b: Floats) -> list[float] | None:
        """Solve with this ``b``: the primal solution, or None unless solved (or almost)."""
        if self.solver is not None and self.solver.is_data_update_allowed():
            self.solver.update(b=b)
            self.updates += 1
        else:
            settings = clarabel.DefaultSettings()
            for name, value in SETTINGS.items():
                setattr(settings, name, value)
            self.solver = clarabel.DefaultSolver(self.P, self.q, self.A, b, self.cones, settings)
        solution = self.solver.solve()
        if solution.status not in _ACCEPTED:
            return None
        x: list[float] = solution.x
        return x


class ConicStage2(LayoutModel):
    """The relaxed Stage II GP for one layout as an exponential-cone program for Clarabel, built once.

    The same interface and the same program as
    :class:`~catanc.planning.stage2.relaxed.RelaxedStage2` (see :class:`Stage2Model`).
    The constructor also loads ``problem``'s numbers, as :meth:`set_numbers`
    would, so the model can be solved at once.
    """

    def __init__(self, problem: Problem, layout: Layout, schedule: Schedule) -> None:
        super().__init__(problem, layout, schedule)
        by_name = {sub.name: sub for sub in problem.subchains}

        # Parameters v: v[ONE] = 1, each shared subchain's compute time, each dedicated period and latency.
        shared_count = len(self.shared_names)
        compute = {name: 1 + i for i, name in enumerate(self.shared_names)}
        fixed_period = {name: 1 + shared_count + 2 * i for i, name in enumerate(self.dedicated_names)}
        fixed_latency = {name: 2 + shared_count + 2 * i for i, name in enumerate(self.dedicated_names)}
        self._params = 1 + shared_count + 2 * len(self.dedicated_names)

        rows = _Rows()
        core_var = {core.core: rows.column() for core in layout.shared}  # log T
        fraction_var = {name: rows.column() for name in self.shared_names}  # log f
        core_of = {name: core.core for core in layout.shared for name in core.subchains}

        # Bounds on log f, first (b[:2k] is the box): per non-batch subchain one lower row (the
        # box's f >= 1/high and slice <= f c together) and one upper row (f <= 1/low); per batch
        # subchain a lower row for the slice.
        self._box = len(self.integral)
        for sign in (-1.0, 1.0):
            for name in self.integral:
                rows.bound(fraction_var[name], sign)
        sliced = [name for name in self.shared_names if name not in self.integral and schedule.min_slice_ms > 0]
        self._sliced_rows = np.array([rows.bound(fraction_var[name], -1.0) for name in sliced], dtype=np.intp)
        self._sliced_of = np.array([self.shared_names.index(name) for name in sliced], dtype=np.intp)
        self._integral_of = [self.shared_names.index(name) for name in self.integral]

        # The load on each core.
        usable = 1.0 - schedule.slack
        for core in layout.shared:
            T = core_var[core.core]
            load: Posynomial = {}
            for name in core.subchains:
                _add(load, _monomial({fraction_var[name]: 1, T: -1}, {compute[name]: 1 / usable}))
            overhead = len(core.subchains) * schedule.switch_ms
            if overhead > 0:
                _add(load, _monomial({T: -1}, {ONE: overhead / usable}))
            rows.constraint(load)

        # Latencies and periods as monomials; a period variable where a rate cap needs one.
        latencies: dict[str, Posynomial] = {}
        periods: dict[str, Posynomial] = {}
        for name in self.shared_names:
            latencies[name] = _monomial({core_var[core_of[name]]: 1, fraction_var[name]: -1}, {ONE: 1})
        for name in self.dedicated_names:
            latencies[name] = _monomial({}, {fixed_latency[name]: 1})
            periods[name] = _monomial({}, {fixed_period[name]: 1})

        def period(name: str) -> Posynomial:
            if name not in periods:
                if by_name[name].min_period_ms > 0:  # p >= T/f and p >= p_min
                    p = rows.column()
                    rows.constraint(_over(latencies[name], p))
                    rows.constraint(_monomial({p: -1}, {ONE: by_name[name].min_period_ms}))
                    periods[name] = _monomial({p: 1}, {ONE: 1})
                else:  # no rate cap: p = T/f at an optimum
                    periods[name] = latencies[name]
            return periods[name]

        bounds: list[tuple[Posynomial, float]] = []  # posynomial <= scale * limit
        for name in self.shared_names + self.dedicated_names:
            if by_name[name].max_period_ms < math.inf:  # rate floors, a dedicated subchain's too
                bounds.append((period(name), by_name[name].max_period_ms))

        # Chain responses L + P, for the chains a weighted term or a bound uses.
        used = {term.chain for term in problem.response_terms if term.weight > 0}
        used |= {bound.chain for bound in problem.response_bounds}
        forms = {index: chain_form(problem, problem.chains[index]) for index in used if problem.chains[index].stages}
        longest = _longest(forms, by_name, period, rows)
        responses: dict[int, Posynomial] = {}
        for index, form in sorted(forms.items()):
            response: Posynomial = {}
            for name in form.latency_of:
                _add(response, latencies[name])
            for name in form.period_of:
                _add(response, period(name))
            if form.constant > 0:
                _add(response, _monomial({}, {ONE: form.constant}))
            if index in longest:
                _add(response, longest[index])
            responses[index] = response
        bounds += [
            (responses[bound.chain], bound.max_response_ms)
            for bound in problem.response_bounds
            if bound.chain in responses
        ]

        goal: Posynomial = {}
        weighted = False
        for term in problem.response_terms:
            if term.weight > 0 and term.chain in responses:
                _add(goal, responses[term.chain], term.weight)
                weighted = True
        for period_term in problem.period_terms:
            if period_term.weight > 0:
                _add(goal, period(period_term.subchain), period_term.weight)
                weighted = True
        if not weighted:  # every feasible plan is optimal; shortest schedules then
            for T in core_var.values():
                _add(goal, _monomial({T: 1}, {ONE: 1}))

        # The bounds, last in each block, so that the scale is added to two slices of b. One
        # without variables is checked outside the solver.
        constant = [_times(bound, 1 / limit)[()] for bound, limit in bounds if list(bound) == [()]]
        first_linear, first_cone = rows.linear, rows.cones
        scaled_terms = len(rows.terms)
        for bound, limit in bounds:
            if list(bound) != [()]:
                rows.constraint(_times(bound, 1 / limit))
        scaled = rows.terms[scaled_terms:]
        self._scaled_linear = slice(first_linear, rows.linear)
        self._scaled_cones = slice(3 * first_cone, 3 * rows.cones, 3)  # the y rows; shifted by the linear block
        self._constant_weights = _weights(constant, self._params)
        self._constant_log = -math.inf  # log of the least scale the bounds without variables allow
        self._variables = rows.columns

        # The scale-free twin: log s in every scaled term, log s >= 0 and >= those without variables.
        twin = rows.copy()
        self._scale_column = twin.column()
        twin.entries += [(cone, row, self._scale_column, sign) for cone, row, sign, _ in scaled]
        self._least_row = twin.bound(self._scale_column, -1.0)
        q_twin = np.zeros(twin.columns)
        q_twin[self._scale_column] = 1.0

        # The objective: the log of its posynomial (linear for a single term).
        self._objective_weights = np.zeros(self._params)  # a single term's C
        self._objective_log = 0.0
        if len(goal) == 1:
            key, coefficient = next(iter(goal.items()))
            q = np.zeros(rows.columns)
            for column, power in key:
                q[column] = power
            self._objective_weights = _weights([coefficient], self._params)[0]
        else:
            z = rows.column()
            rows.constraint(goal, shift=z)
            q = np.zeros(rows.columns)
            q[z] = 1.0
        self._objective_terms = [(column, float(value)) for column, value in enumerate(q) if value]

        self._program = _Program(rows, q, self._params)
        self._twin = _Program(twin, q_twin, self._params)

        # Where the answer is in x: log T and log f; periods are max(T/f, p_min).
        self._core_columns = list(core_var.items())
        self._shared_columns = [
            (name, fraction_var[name], core_var[core_of[name]], by_name[name].min_period_ms)
            for name in self.shared_names
        ]
        self._box_lower = [-math.log(SMALLEST_FRACTION)] * len(self.integral)  # -log f_min
        self._box_upper = [0.0] * len(self.integral)  # log f_max
        self._slice_lower = [math.inf] * shared_count  # -log(min(slice, c) / c)
        self._numbers: Problem | None = None  # compute times set, not loaded into ``b`` yet
        self.set_numbers(problem)

    def set_numbers(self, problem: Problem) -> None:
        """Load compute times (and the dedicated constants they imply) into ``b``, when a solve first needs them:
        a re-solve that the closed form and a solver-free bound settle solves nothing (~60 us saved, nav2d)."""
        self._numbers = problem

    def _load_numbers(self) -> None:
        """Load the numbers set last, if not loaded yet: the same ``b`` as loading them when set, as the
        box is loaded after them either way."""
        if self._numbers is None:
            return
        problem, self._numbers = self._numbers, None
        by_name = {sub.name: sub for sub in problem.subchains}
        values = np.ones(self._params)
        shared = np.array([by_name[name].compute_ms for name in self.shared_names])
        values[1 : 1 + len(shared)] = shared
        for index, (name, cores) in enumerate(self.layout.dedicated):
            timing = capped_dedicated(by_name[name], cores, problem.slack)
            values[1 + len(shared) + 2 * index] = timing.period_ms
            values[2 + len(shared) + 2 * index] = timing.latency_ms
        if self.schedule.min_slice_ms > 0:
            self._slice_lower = (-np.log(np.minimum(self.schedule.min_slice_ms, shared) / shared)).tolist()
        for program in (self._program, self._twin):
            program.load(values)
            program.b[self._sliced_rows] = np.array(self._slice_lower)[self._sliced_of]
        if self._objective_weights.any():
            self._objective_log = math.log(float(self._objective_weights @ values))
        if len(self._constant_weights):
            self._constant_log = float(np.max(np.log(self._constant_weights @ values)))
        self._twin.b[self._least_row] = -max(0.0, self._constant_log)
        self._load_box()

    def set_box(self, box: Mapping[str, tuple[int, int]]) -> None:
        """Confine each non-batch subchain's ``n = 1/f`` to ``[low, high]`` (the rest: ``n >= 1``)."""
        for index, name in enumerate(self.integral):
            low, high = box.get(name, (1, 0))
            self._box_upper[index] = -math.log(low)
            self._box_lower[index] = math.log(high) if high >= low else -math.log(SMALLEST_FRACTION)
        self._load_box()

    def _load_box(self) -> None:
        slices = self._slice_lower
        values = [min(slices[i], bound) for i, bound in zip(self._integral_of, self._box_lower, strict=True)]
        values += self._box_upper
        self._program.b[: 2 * self._box] = values
        self._twin.b[: 2 * self._box] = values

    def solve(self, scale: float = 1.0) -> RelaxedSolution | None:
        """The relaxed optimum with every bound scaled by ``scale``; None when infeasible."""
        self._load_numbers()
        log_scale = math.log(scale)
        if self._constant_log > log_scale + CONSTANT_TOLERANCE:
            return None
        program = self._program
        b = program.b
        if log_scale:  # scaled terms hold log C - log s: +log s in a linear row, -log s in a cone
            b = b.copy()
            b[self._scaled_linear] += log_scale
            shift = program.linear
            cones = self._scaled_cones
            b[cones.start + shift : cones.stop + shift : 3] -= log_scale
        x = program.run(b)
        if x is None:
            return None
        log_objective = math.fsum(x[column] * value for column, value in self._objective_terms)
        return self._answer(x, log_objective + self._objective_log)

    def solve_least_scale(self) -> RelaxedSolution | None:
        """The relaxed plan needing the smallest scale on the bounds (its ``objective`` is that scale)."""
        self._load_numbers()
        x = self._twin.run(self._twin.b)
        return None if x is None else self._answer(x, x[self._scale_column])

    def _answer(self, x: list[float], log_objective: float) -> RelaxedSolution | None:
        if not math.isfinite(log_objective):  # pragma: no cover - a diverged iterate that the solver accepted
            return None
        cores = {core: _exp(x[column]) for core, column in self._core_columns}
        fraction = {name: _exp(x[f]) for name, f, _, _ in self._shared_columns}
        period = {name: max(_exp(x[T] - x[f]), least) for name, f, T, least in self._shared_columns}
        return RelaxedSolution(core_period_ms=cores, fraction=fraction, period_ms=period, objective=_exp(log_objective))

    @property
    def solver(self) -> clarabel.DefaultSolver | None:
        """The persistent Clarabel solver of :meth:`solve` (None before the first solve)."""
        return self._program.solver

    @property
    def updates(self) -> int:
        """Solves that only updated ``b`` on a persistent solver (both programs)."""
        return self._program.updates + self._twin.updates


def _longest(
    forms: Mapping[int, ChainForm],
    by_name: Mapping[str, Subchain],
    period: Callable[[str], Posynomial],
    rows: _Rows,
) -> dict[int, Posynomial]:
    """Each chain's longest period ``P``: the maximum of its stages' periods and its floor.

    A floor no larger than another candidate's rate cap never decides.  Chains with the same
    candidates share one ``P``; a single candidate is ``P`` itself.  Otherwise ``P`` is a variable
    above each candidate, where a chain whose candidates include all of another's has that one's
    ``P`` as a candidate in their place: the other's ``P`` can always take its least value, so
    this allows the same plans with fewer rows.
    """
    candidates: dict[int, frozenset[tuple[str, float]]] = {}
    for index, form in forms.items():
        stages = {(name, 0.0) for name in form.longest_of}
        capped = max((by_name[name].min_period_ms for name in form.longest_of), default=0.0)
        floor = {("", form.floor)} if form.floor > capped else set()
        candidates[index] = frozenset(stages | floor)
    built: dict[frozenset[tuple[str, float]], Posynomial] = {}
    for keys in sorted(set(candidates.values()), key=lambda keys: (len(keys), sorted(keys))):
        if not keys:
            continue
        inner = max((other for other in built if other < keys), key=len, default=frozenset())
        parts = [period(name) if name else _monomial({}, {ONE: floor}) for name, floor in sorted(keys - inner)]
        if inner:
            parts.append(built[inner])
        if len(parts) == 1:
            built[keys] = parts[0]
        else:
            column = rows.column()
            for part in parts:
                rows.constraint(_over(part, column))
            built[keys] = _monomial({column: 1}, {ONE: 1})
    return {index: built[keys] for index, keys in candidates.items() if keys}


def _exp(value: float) -> float:
    """``exp``, infinite where it overflows: where nothing bounds a batch subchain's ``f``, ``T`` and
    ``f`` may grow together towards an optimum at infinity."""
    return math.exp(value) if value < 709.0 else math.inf
