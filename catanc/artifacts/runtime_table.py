"""The plan as plain data: the ``plan`` of the runtime table (interfaces.md, ``runtime.json``).

:func:`plan_payload` is what ``catanc explain --json`` prints and what
``runtime.json`` will carry.  It is deterministic: times are rounded to
:data:`MS_DIGITS` decimals (ms), fractions to :data:`FRACTION_DIGITS`, rates
to :data:`RATE_DIGITS`, and every derived number is recomputed from the
rounded ones, so the table is self-consistent as written:

- each subchain's ``rate_hz`` is ``1000 / period_ms`` and ``slice_ms`` is
  ``fraction * c(S)`` (``c(S)`` from the problem, not printed);
- each chain's metrics are section 2 of catan-model.md over the rounded
  subchain timings and the rounded ``clocks`` (unscheduled nodes' periods);
- ``objective`` is :func:`catanc.core.metrics.objective` over those same numbers.

:func:`plan_json` dumps it with sorted keys, two-space indents and a final
newline: the same plan gives the same bytes.
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from catanc.core.metrics import Timing, evaluate_chain, objective
from catanc.core.problem import Chain, Problem, Stage

if TYPE_CHECKING:
    from catanc.planning.types import ChainPlan, Plan

MS_DIGITS = 6
FRACTION_DIGITS = 9
RATE_DIGITS = 6
SCALE_DIGITS = 9


def ms(value: float) -> float:
    """A time as written in the table (ms)."""
    return round(value, MS_DIGITS)


def plan_payload(plan: Plan, problem: Problem) -> dict[str, Any]:
    """The runtime table's ``plan`` for ``plan`` (the problem it was planned for supplies ``c(S)`` and clocks)."""
    rounded = rounded_problem(problem)
    timings = {name: Timing(ms(sub.period_ms), ms(sub.latency_ms)) for name, sub in plan.subchains.items()}
    subchains: dict[str, Any] = {}
    for name, sub in plan.subchains.items():
        fraction = round(sub.fraction, FRACTION_DIGITS)
        subchains[name] = {
            "nodes": list(sub.nodes),
            "cores": list(sub.cores),
            "shared": sub.shared,
            "threads": sub.threads,
            "period_ms": timings[name].period_ms,
            "latency_ms": timings[name].latency_ms,
            "rate_hz": round(1000.0 / timings[name].period_ms, RATE_DIGITS),
            "fraction": fraction,
            "slice_ms": ms(fraction * problem.subchain(name).compute_ms) if sub.shared else None,
            "priority": sub.priority,
        }
        if sub.every is not None:  # triggered at its slot every k periods: period_ms = k * the core's
            subchains[name]["every"] = sub.every
    cores = [
        {"core": core.core, "period_ms": ms(core.period_ms), "order": list(core.order)}
        for core in sorted(plan.shared_cores, key=lambda c: c.core)
    ]
    chains = []
    for chain_plan in plan.chains:
        chain = _chain_of(chain_plan, rounded, plan)
        metrics = evaluate_chain(rounded, chain, timings)
        chains.append(
            {
                "nodes": list(chain_plan.nodes),
                "subchains": [stage.name for stage in chain.stages],
                "head_period_ms": chain.head_period_ms,
                "latency_ms": ms(metrics.latency_ms),
                "period_ms": ms(metrics.period_ms),
                "response_ms": ms(metrics.response_ms),
            }
        )
    return {
        "objective": ms(objective(rounded, timings)),
        "constraint_scale": round(plan.constraint_scale, SCALE_DIGITS),
        "subchains": subchains,
        "cores": cores,
        "clocks": {name: {"period_ms": period} for name, period in sorted(rounded.fixed_periods_ms.items())},
        "chains": chains,
    }


def plan_json(plan: Plan, problem: Problem, **extra: Any) -> str:
    """``{"plan": plan_payload(...), **extra}`` as deterministic JSON text (sorted keys, final newline)."""
    return json.dumps({**extra, "plan": plan_payload(plan, problem)}, indent=2, sort_keys=True) + "\n"


def rounded_problem(problem: Problem) -> Problem:
    """``problem`` with its clocks and batch-head periods as the table writes them."""
    return replace(
        problem,
        fixed_periods_ms={name: ms(period) for name, period in problem.fixed_periods_ms.items()},
        chains=tuple(_rounded_head(chain) for chain in problem.chains),
    )


def _rounded_head(chain: Chain) -> Chain:
    if chain.head_period_ms is None:
        return chain
    return replace(chain, head_period_ms=ms(chain.head_period_ms))


def _chain_of(chain_plan: ChainPlan, problem: Problem, plan: Plan) -> Chain:
    """The problem's chain over these nodes; else one rebuilt from the plan's stage names."""
    for chain in problem.chains:
        if chain.nodes == chain_plan.nodes:
            return chain
    stages = tuple(Stage(name, fixed=name not in plan.subchains) for name in chain_plan.subchains)
    # A batch head's observed period depends on the head node alone: any chain from it knows it.
    head = next((c.head_period_ms for c in problem.chains if c.nodes[0] == chain_plan.nodes[0]), None)
    return Chain(chain_plan.nodes, stages, head)
