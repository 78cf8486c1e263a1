"""``catanc simulate``: one app, one policy, ``K`` cores, a seeded workload, simulated time.

Policies (issue 7; the paper's section 7 baselines):

- ``catan``: catanc's plan for the spec's compute times, enforced as ``catanc
  run`` does, re-solved from measured p95s (Stage II every
  ``stage2_every_s``, Stage I every ``stage1_every_s``);
- ``catan-nosteal``: the same without priority stealing (the spec's
  ``schedule.stealing`` off: each slot is its owner's), the paper's
  ablation "Catan w/o priority stealing" (its Figure 9);
- ``static-fullrun`` / ``static-20s``: one plan, made before the run from
  the p95 compute times of the whole run / of its first 20 s (drawn from the
  workload model), never re-solved (the paper's Static-FullRun, Static-20s);
- ``baseline``: the hand-tuned rates under fair sharing (CFS);
- ``fifo-static``: the hand-tuned rates under static SCHED_FIFO priorities,
  every subchain its own level by importance, or ``baseline.priorities``
  (:func:`catanc.planning.baseline.static_priorities`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from catanc.control.measure import estimate, mode_times
from catanc.control.schedule import RuntimeSchedule, runtime_schedule
from catanc.errors import UsageError
from catanc.extras import require
from catanc.model.build import build_problem, spec_dag
from catanc.model.graph import all_chains
from catanc.model.problem import Problem
from catanc.model.workload import ComputeSampler, NodeStream
from catanc.planning.baseline import static_priorities
from catanc.planning.planner import plan_problem
from catanc.planning.replan import Replanner
from catanc.planning.types import Plan
from catanc.sim.cpu import Discipline
from catanc.sim.dataflow import Dataflow
from catanc.sim.engine import Engine
from catanc.sim.memory import keep_freed_memory
from catanc.sim.metrics import PolicyResult, chain_result, node_result
from catanc.sim.policies import NO_DELAYS, CatanPolicy, Delays, Reoptimiser, Sampler, TimerPolicy, start_sensors
from catanc.sim.records import Records
from catanc.spec.language import Spec

POLICIES = ("catan", "catan-nosteal", "baseline", "fifo-static", "static-fullrun", "static-20s")
CATAN_POLICIES = frozenset({"catan", "catan-nosteal"})
"""Policies that run catanc's plan and re-solve it."""
DEFAULT_POLICIES = ("catan", "baseline", "fifo-static")
MAX_OTHER_CHAINS = 50
"""Source-to-sink paths reported besides the named chains (an app with thousands lists the first 50)."""
PROFILE_SAMPLES = 2000
"""Draws per node, evenly spread over the profiled interval, for a static plan's tail compute times."""
STATIC_20S = 20.0

SamplerFactory = Callable[[Spec, int], Sampler]
EngineChoice = Literal["auto", "compiled", "python"]


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
    times = profile_times(start_s, end_s)
    return _tails(spec, lambda name: [sampler(name, at) for at in times])


def workload_tail_compute(spec: Spec, seed: int, start_s: float, end_s: float) -> dict[str, float]:
    """:func:`tail_compute` with :func:`workload_sampler`, each node's draws taken in one block."""
    sampler = ComputeSampler(spec, seed)
    times = np.array(profile_times(start_s, end_s))
    return _tails(spec, lambda name: stream_draws(sampler.stream(name), times).tolist())


def profile_times(start_s: float, end_s: float) -> list[float]:
    """When :func:`tail_compute` draws: :data:`PROFILE_SAMPLES` times evenly spread over ``[start_s, end_s]``."""
    return [start_s + (end_s - start_s) * i / (PROFILE_SAMPLES - 1) for i in range(PROFILE_SAMPLES)]


def _tails(spec: Spec, samples_of: Callable[[str], list[float]]) -> dict[str, float]:
    q = spec.runtime.percentile
    return {
        name: estimate(samples_of(name), q, mode_times(node.compute_ms))
        for name, node in sorted(spec.nodes.items())
        if node.scheduled
    }


def stream_draws(stream: NodeStream, at_s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """What :meth:`NodeStream.draw` returns for each of the non-decreasing times ``at_s``, called in order.

    A run takes the spike when an arrival came at or before it and after the run before it;
    every other run takes the next :meth:`~NodeStream.bases` draw, times the growth factor.
    The same operations on the same values as the run-by-run calls, so the same bits.
    """
    if not len(at_s):
        return np.empty(0)
    arrivals = np.array(stream.spikes_until(float(at_s[-1])))
    taken = np.searchsorted(arrivals, at_s, side="right")  # arrivals at or before each run
    spike = np.diff(taken, prepend=0) > 0
    normal = ~spike
    modes, factors = stream.bases(int(normal.sum()))
    values = modes.copy()
    if stream.growth is not None:
        start, end, over_s = stream.growth
        at = at_s[normal]
        values *= np.where(at >= over_s, end, np.where(at <= 0.0, start, start + (end - start) * (at / over_s)))
    draws = np.full(len(at_s), stream.spike_ms)
    draws[normal] = values * factors
    return draws


def check_policies(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` without repeats, or a usage error naming the unknown one."""
    for name in names:
        if name not in POLICIES:
            raise UsageError(f"--policy: unknown policy {name!r} (expected one of: {', '.join(POLICIES)})")
    return tuple(dict.fromkeys(names))


def policy_spec(spec: Spec, policy: str) -> Spec:
    """The spec ``policy`` plans and enforces: ``catan-nosteal`` turns ``schedule.stealing`` off."""
    if policy != "catan-nosteal":
        return spec
    return spec.model_copy(update={"schedule": spec.schedule.model_copy(update={"stealing": False})})


def workload_sampler(spec: Spec, seed: int) -> Sampler:
    """The spec's workload model (:mod:`catanc.model.workload`), seeded."""
    return ComputeSampler(spec, seed).compute_ms


def simulate_policies(
    setup: Setup, policies: Sequence[str], sampler_for: SamplerFactory = workload_sampler
) -> list[PolicyResult]:
    """Each policy on the same setup and the same seeded workload."""
    return [simulate(setup, policy, sampler_for) for policy in check_policies(policies)]


@dataclass(frozen=True)
class Prepared:
    """A policy ready to run: the chains to report and what the policy enforces."""

    chains: list[tuple[tuple[str, ...], bool]]
    schedule: RuntimeSchedule | None  # catan and static plans
    replanner: Replanner | None  # catan
    plan: Plan | None  # static plans (catan's is the replanner's)
    priorities: dict[str, int] | None  # baselines: each node's static priority
    discipline: Discipline


def static_profile(setup: Setup, policy: str, sampler_for: SamplerFactory = workload_sampler) -> dict[str, float]:
    """The tail compute times a static policy plans with: over the whole run (``static-fullrun``)
    or its first 20 s (``static-20s``). ``catanc bench`` plans its static runs with these too."""
    end = setup.duration_s if policy == "static-fullrun" else min(STATIC_20S, setup.duration_s)
    if sampler_for is workload_sampler:
        return workload_tail_compute(setup.spec, setup.seed, 0.0, end)
    return tail_compute(setup.spec, sampler_for(setup.spec, setup.seed), 0.0, end)


def prepare(setup: Setup, policy: str, sampler_for: SamplerFactory) -> Prepared:
    """Plan what ``policy`` needs (nothing for the baselines, one plan for a static policy)."""
    check_policies([policy])
    spec, cores = setup.spec, setup.cores
    if policy in CATAN_POLICIES:
        replanner = Replanner(spec, cores)
        schedule = runtime_schedule(replanner.plan, replanner.problem, spec.schedule)
        return Prepared(reported_chains(spec, replanner.spec_problem), schedule, replanner, None, None, "fifo")
    problem = build_problem(spec)
    chains = reported_chains(spec, problem)
    if policy in ("baseline", "fifo-static"):  # no plan: the hand-tuned rates
        by_subchain = static_priorities(spec, problem)
        by_node = {node: by_subchain[sub.name] for sub in problem.subchains for node in sub.nodes}
        return Prepared(chains, None, None, None, by_node, "fair" if policy == "baseline" else "fifo")
    # One plan, as the Replanner's Stage I would make it, from the tail compute times.
    profiled = problem.with_compute(static_profile(setup, policy, sampler_for))
    plan = plan_problem(profiled, spec.schedule, cores, backend="conic")
    return Prepared(chains, runtime_schedule(plan, profiled, spec.schedule), None, plan, None, "fifo")


def simulate(
    setup: Setup,
    policy: str,
    sampler_for: SamplerFactory = workload_sampler,
    *,
    engine: EngineChoice = "auto",
    delays: Delays = NO_DELAYS,
) -> PolicyResult:
    """Run ``policy`` on ``setup`` for its duration; the same arguments give the same result.

    ``engine``: ``compiled`` (:mod:`catanc.sim.kernel`, the spec's workload only, no ``delays``),
    ``python`` (the readable engine, any sampler), or ``auto``: compiled for the spec's workload
    without delays.  A compiled run makes the process keep the memory it frees (:mod:`catanc.sim.memory`).
    ``delays``: the real runtime's wake-up and switch delays (:class:`~catanc.sim.policies.Delays`).
    """
    setup = replace(setup, spec=policy_spec(setup.spec, policy))
    prepared = prepare(setup, policy, sampler_for)
    compiled = engine == "compiled" or (engine == "auto" and sampler_for is workload_sampler and delays.none)
    if compiled and sampler_for is not workload_sampler:
        raise UsageError("the compiled simulation draws from the spec's workload model only")
    if compiled and not delays.none:
        raise UsageError("the compiled simulation has no runtime delays: use the python engine")
    records = _run_compiled(setup, prepared) if compiled else _run_python(setup, prepared, sampler_for, delays)
    plan = prepared.replanner.plan if prepared.replanner is not None else prepared.plan
    return policy_result(setup, policy, prepared.chains, records, plan)


def _run_python(setup: Setup, prepared: Prepared, sampler_for: SamplerFactory, delays: Delays) -> Records:
    spec = setup.spec
    engine = Engine()
    flow = Dataflow(spec, [nodes for nodes, _ in prepared.chains])
    sample = sampler_for(spec, setup.seed)
    runner: CatanPolicy | TimerPolicy
    if prepared.schedule is None:
        assert prepared.priorities is not None
        runner = TimerPolicy(
            engine,
            flow,
            spec=spec,
            cores=setup.cores,
            sample=sample,
            discipline=prepared.discipline,
            priorities=prepared.priorities,
            delays=delays,
        )
    else:
        runner = CatanPolicy(
            engine,
            flow,
            spec=spec,
            schedule=prepared.schedule,
            sample=sample,
            replanner=prepared.replanner,
            delays=delays,
        )
    start_sensors(engine, flow, spec)
    runner.start()
    engine.run_until(setup.duration_s * 1000.0)
    return Records(
        done_ms={name: record.done_ms for name, record in flow.records.items()},
        staleness_ms={name: record.staleness_ms for name, record in flow.records.items()},
        arrivals=flow.arrivals,
        busy_by_core=runner.busy_by_core(),
        replans=runner.replans if isinstance(runner, CatanPolicy) else [],
        schedule=runner.schedule if isinstance(runner, CatanPolicy) else None,
    )


def _run_compiled(setup: Setup, prepared: Prepared) -> Records:
    require("numba", "the compiled simulation")
    from catanc.sim import fast, kernel  # noqa: PLC0415 (numba loads only when a compiled run is asked for)

    keep_freed_memory()  # the arrays below fault their pages in once per process, not once per run
    spec, cores = setup.spec, setup.cores
    chains = [nodes for nodes, _ in prepared.chains]
    graph = fast.topology(spec, chains, prepared.schedule, cores, prepared.priorities)
    draws = fast.DrawTable(spec, ComputeSampler(spec, setup.seed), setup.duration_s)
    end_ms = setup.duration_s * 1000.0
    if prepared.schedule is None:  # the baselines: one pool of every core, timers
        kind = kernel.TIMER_FAIR if prepared.discipline == "fair" else kernel.TIMER_FIFO
        state = fast.run_fields(graph, 0, kind)
        sim = fast.new_sim(graph, fast.no_schedules(), draws.arrays, state)
        kernel.start_sensors(sim)
        kernel.start_timers(sim, prepared.discipline == "fair")
        fast.run_compiled(sim, None, draws, end_ms, None)
        records = fast.records_of(sim, spec, chains, [], None)
        records.busy_by_core = dict.fromkeys(range(cores), float(state["pool_busy"][0]) / cores)
        return records
    reoptimiser = Reoptimiser(spec, prepared.replanner) if prepared.replanner is not None else None
    runtime = spec.runtime
    duration = setup.duration_s
    resolves = math.ceil(duration / runtime.stage2_every_s) + math.ceil(duration / runtime.stage1_every_s)
    table = fast.ScheduleTable(spec, prepared.schedule, cores, 2 + (resolves if reoptimiser else 0))
    kind = kernel.CATAN_MEASURED if reoptimiser is not None else kernel.CATAN
    state = fast.run_fields(graph, len(table.names), kind, spec.runtime.window)
    sim = fast.new_sim(graph, table.arrays, draws.arrays, state)
    kernel.start_sensors(sim)
    kernel.install(sim, 0)
    if reoptimiser is not None:
        kernel.schedule_reoptimise(sim, reoptimiser.first_ms)
    fast.run_compiled(sim, table, draws, end_ms, reoptimiser)
    kernel.fold_busy(sim)
    records = fast.records_of(sim, spec, chains, reoptimiser.replans if reoptimiser else [], None)
    records.busy_by_core = {core: float(state["core_busy"][core]) for core in range(cores)}
    records.schedule = table.versions[kernel.clock_of(sim)[1]]
    return records


def promised_rates(plan: Plan) -> dict[str, float]:
    """Each subchain head's rate as ``plan`` promises it run (:attr:`SubchainPlan.rate_as_run_hz`), by node."""
    return {sub.nodes[0]: sub.rate_as_run_hz for sub in plan.subchains.values()}


def policy_result(
    setup: Setup, policy: str, chains: list[tuple[tuple[str, ...], bool]], records: Records, plan: Plan | None
) -> PolicyResult:
    """What a run of ``policy`` shows, from its records (shared by both engines and by ``catanc bench``)."""
    duration_ms = setup.duration_s * 1000.0
    model = {chain.nodes: chain.response_ms for chain in plan.chains} if plan is not None else {}
    promised = promised_rates(plan) if plan is not None else {}
    return PolicyResult(
        policy=policy,
        duration_s=setup.duration_s,
        chains=tuple(
            chain_result(nodes, named, arrivals, model.get(nodes))
            for (nodes, named), arrivals in zip(chains, records.arrivals, strict=True)
        ),
        nodes={
            name: node_result(records.done_ms[name], records.staleness_ms[name], duration_ms, promised.get(name))
            for name in records.done_ms
        },
        utilisation=tuple(records.busy_by_core.get(core, 0.0) / duration_ms for core in range(setup.cores)),
        replans=len(records.replans),
        node_done_ms={name: np.asarray(done, dtype=np.float64) for name, done in records.done_ms.items()},
        schedule=records.schedule,
    )
