"""``catanc simulate``: one app, one policy, ``K`` cores, a seeded workload, simulated time.

Policies (issue 7; the paper's section 7 baselines):

- ``catan``: catanc's plan for the spec's compute times, enforced as ``catanc
  run`` does, re-solved from measured p95s (Stage II every
  ``stage2_every_s``, Stage I every ``stage1_every_s``);
- ``static-fullrun`` / ``static-20s``: one plan, made before the run from
  the p95 compute times of the whole run / of its first 20 s (drawn from the
  workload model), never re-solved (the paper's Static-FullRun, Static-20s);
- ``baseline``: the hand-tuned rates under fair sharing (CFS);
- ``fifo-static``: the hand-tuned rates under static SCHED_FIFO priorities
  by weight.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from catanc.errors import UsageError
from catanc.graph import all_chains
from catanc.planner import Plan, plan_problem, priorities
from catanc.problem import Problem, build_problem, spec_dag
from catanc.replan import Replanner
from catanc.runtime.measure import estimate, mode_times
from catanc.runtime.schedule import runtime_schedule
from catanc.simulate.cpu import Discipline
from catanc.simulate.dataflow import Dataflow
from catanc.simulate.engine import Engine
from catanc.simulate.metrics import ChainResult, PolicyResult, Summary, node_result, timed_responses
from catanc.simulate.policies import CatanPolicy, Sampler, TimerPolicy, start_sensors
from catanc.spec import Spec
from catanc.workload import ComputeSampler

POLICIES = ("catan", "baseline", "fifo-static", "static-fullrun", "static-20s")
DEFAULT_POLICIES = ("catan", "baseline", "fifo-static")
MAX_OTHER_CHAINS = 50
"""Source-to-sink paths reported besides the named chains (an app with thousands lists the first 50)."""
PROFILE_SAMPLES = 2000
"""Draws per node, evenly spread over the profiled interval, for a static plan's tail compute times."""
STATIC_20S = 20.0

SamplerFactory = Callable[[Spec, int], Sampler]


@dataclass(frozen=True)
class Setup:
    spec: Spec
    cores: int
    duration_s: float
    seed: int


def reported_chains(spec: Spec, problem: Problem) -> list[tuple[tuple[str, ...], bool]]:
    """The chains the objective and constraints name (as the spec expands them), then every other path."""
    seen: dict[tuple[str, ...], bool] = {}
    for chain in problem.chains:
        seen.setdefault(tuple(chain.nodes), True)
    others, _ = all_chains(spec_dag(spec), MAX_OTHER_CHAINS)
    for path in others:
        seen.setdefault(tuple(path), False)
    return list(seen.items())


def tail_compute(spec: Spec, sampler: Sampler, start_s: float, end_s: float) -> dict[str, float]:
    """Each scheduled node's planning compute time (the runtime's p95 estimate) over ``[start_s, end_s]``."""
    q = spec.runtime.percentile
    times = [start_s + (end_s - start_s) * i / (PROFILE_SAMPLES - 1) for i in range(PROFILE_SAMPLES)]
    tails = {}
    for name, node in sorted(spec.nodes.items()):
        if node.scheduled:
            samples = [sampler(name, at) for at in times]
            tails[name] = estimate(samples, q, mode_times(node.compute_ms))
    return tails


def check_policies(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` without repeats, or a usage error naming the unknown one."""
    for name in names:
        if name not in POLICIES:
            raise UsageError(f"--policy: unknown policy {name!r} (expected one of: {', '.join(POLICIES)})")
    return tuple(dict.fromkeys(names))


def workload_sampler(spec: Spec, seed: int) -> Sampler:
    """The spec's workload model (:mod:`catanc.workload`), seeded."""
    return ComputeSampler(spec, seed).compute_ms


def simulate_policies(
    setup: Setup, policies: Sequence[str], sampler_for: SamplerFactory = workload_sampler
) -> list[PolicyResult]:
    """Each policy on the same setup and the same seeded workload."""
    return [simulate(setup, policy, sampler_for) for policy in check_policies(policies)]


def simulate(setup: Setup, policy: str, sampler_for: SamplerFactory = workload_sampler) -> PolicyResult:
    """Run ``policy`` on ``setup`` for its duration; the same arguments give the same result."""
    check_policies([policy])
    spec, cores = setup.spec, setup.cores
    problem = build_problem(spec)
    chains = reported_chains(spec, problem)
    engine = Engine()
    flow = Dataflow(spec, [nodes for nodes, _ in chains])
    sample = sampler_for(spec, setup.seed)
    plan: Plan | None = None
    runner: CatanPolicy | TimerPolicy
    if policy in ("baseline", "fifo-static"):  # no plan: the hand-tuned rates
        by_subchain = priorities(problem, spec.schedule, problem.importance())
        by_node = {node: by_subchain[sub.name] for sub in problem.subchains for node in sub.nodes}
        discipline: Discipline = "fair" if policy == "baseline" else "fifo"
        runner = TimerPolicy(
            engine, flow, spec=spec, cores=cores, sample=sample, discipline=discipline, priorities=by_node
        )
    elif policy == "catan":
        replanner = Replanner(spec, cores)
        schedule = runtime_schedule(replanner.plan, replanner.problem, spec.schedule)
        runner = CatanPolicy(engine, flow, spec=spec, schedule=schedule, sample=sample, replanner=replanner)
    else:  # one plan, as the Replanner's Stage I would make it, from the tail compute times
        end = setup.duration_s if policy == "static-fullrun" else min(STATIC_20S, setup.duration_s)
        profiled = problem.with_compute(tail_compute(spec, sampler_for(spec, setup.seed), 0.0, end))
        plan = plan_problem(profiled, spec.schedule, cores, backend="conic")
        schedule = runtime_schedule(plan, profiled, spec.schedule)
        runner = CatanPolicy(engine, flow, spec=spec, schedule=schedule, sample=sample)
    start_sensors(engine, flow, spec)
    runner.start()
    duration_ms = setup.duration_s * 1000.0
    engine.run_until(duration_ms)
    if isinstance(runner, CatanPolicy):
        plan = runner.replanner.plan if runner.replanner is not None else plan
    model = {chain.nodes: chain.response_ms for chain in plan.chains} if plan is not None else {}
    busy = runner.busy_by_core()
    timed = [timed_responses(arrivals) for arrivals in flow.arrivals]
    return PolicyResult(
        policy=policy,
        duration_s=setup.duration_s,
        chains=tuple(
            ChainResult(
                nodes, named, Summary.of([r for _, r in timed[i]]), model.get(nodes), samples=tuple(timed[i])
            )
            for i, (nodes, named) in enumerate(chains)
        ),
        nodes={
            name: node_result(record.done_ms, record.staleness_ms, duration_ms) for name, record in flow.records.items()
        },
        utilisation=tuple(busy.get(core, 0.0) / duration_ms for core in range(cores)),
        replans=len(runner.replans) if isinstance(runner, CatanPolicy) else 0,
        node_done_ms={name: tuple(record.done_ms) for name, record in flow.records.items()},
        schedule=runner.schedule if isinstance(runner, CatanPolicy) else None,
    )
