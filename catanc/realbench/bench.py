"""``catanc bench``: one real run per policy, measured from the workers' timestamps.

Per policy, in a temporary folder: one synthetic worker process per scheduled node
(:func:`catanc.runtime.worker.command.workload_worker_command`: it burns what the spec's workload
model draws, with ``at_s`` counted from the moment the workers are started, shared by all
of them, and records every run); then

- ``catan``: the real enforcer, as ``catanc run`` runs it (:class:`~catanc.runtime.enforcer.run.Enforcer`
  with SCHED_FIFO, its watchdog, and re-solving), starting from the spec's plan as the
  simulator's ``catan`` does;
- ``catan-nosteal`` (not run by default): the same with the spec's ``schedule.stealing`` off, so the
  enforcer never gives a slot to a late subchain of higher priority (the paper's ablation, Figure 9);
- ``baseline``: :class:`~catanc.realbench.driver.Driver` triggers the nodes as
  ``baseline.rates_hz`` says, every node thread under SCHED_OTHER (CFS) on the first ``K``
  CPUs this process may use;
- ``fifo-static``: the same triggers, each node thread at a static SCHED_FIFO level by its
  subchain's importance or ``baseline.priorities`` (:func:`fifo_levels`), the driver one level above
  them (it stands for the timers, which the simulator fires on time).
- ``static-fullrun`` / ``static-20s`` (not run by default): the real enforcer with one plan made
  before the run from the workload model's p95 compute times over the whole run / its first 20 s,
  as the simulator's policies of those names make it, and never re-solved (the paper's
  Static-FullRun and Static-20s).

The measured window starts once every node has registered and lasts ``duration_s``; the
runs inside it are replayed (:mod:`catanc.realbench.replay`).  Whatever ends a run (its end, an
error, Ctrl-C), the workers are stopped (SIGTERM, then SIGKILL to their process groups), and
every thread this process changed, its own included, gets its scheduling back.
"""

from __future__ import annotations

import gc
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from catanc.control.schedule import RuntimeSchedule
from catanc.control.timers import trigger_rules
from catanc.errors import PrivilegeError, UsageError
from catanc.files import write_files
from catanc.model.build import build_problem
from catanc.model.priorities import ENFORCER_FIFO
from catanc.model.problem import Problem
from catanc.planning.baseline import static_priorities
from catanc.planning.types import Plan
from catanc.realbench.driver import BenchError, Driver, DriverSocket
from catanc.realbench.replay import measured_result, replay, utilisation
from catanc.runtime.compiled import ready as compiled_ready
from catanc.runtime.compiled.ready import LoopChoice, LoopState
from catanc.runtime.enforcer.processes import Children
from catanc.runtime.linux.sched import (
    Restorer,
    allowed_cpus,
    apply_policy,
    check_fifo_allowed,
    read_policy,
    set_affinity,
    set_fifo,
)
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.worker.command import worker_groups, workload_worker_command
from catanc.runtime.worker.records import RunRecord, read_records, records_text
from catanc.sim.metrics import PolicyResult
from catanc.sim.simulate import CATAN_POLICIES, Setup, policy_spec, promised_rates, reported_chains, static_profile
from catanc.spec.executors import executor_nodes
from catanc.spec.language import Spec

POLICIES = ("catan", "catan-nosteal", "baseline", "fifo-static", "static-fullrun", "static-20s")
DEFAULT_POLICIES = ("catan", "baseline", "fifo-static")
ENFORCER_LOG = "enforcer.jsonl"
"""The enforcer's run log in a policy's working folder (``--log`` keeps a copy)."""
ENFORCED_POLICIES = frozenset({"catan", "catan-nosteal", "static-fullrun", "static-20s"})  # under the real enforcer
FIFO_POLICIES = frozenset({*ENFORCED_POLICIES, "fifo-static"})
REGISTER_TIMEOUT_S = 30.0
"""How long the workers may take to start and register (they import catanc's spec loader: ~0.6 s each)."""
EXIT_TIMEOUT_S = 5.0
"""How long stopped workers may take to finish their last run and write their records."""
WAIT_STEP_S = 0.01
NO_RESOLVE_MARGIN_S = 3600.0
"""A static plan's first re-solve is due this long after the run ends: never."""

Progress = Callable[[str], None]


@dataclass(frozen=True)
class BenchSetup:
    spec_path: Path
    spec: Spec
    cores: int
    duration_s: float
    seed: int
    # --log: each enforced policy's run log, as <policy>.jsonl (catanc report reads it), and every
    # policy's worker records, as <policy>.runs.jsonl
    log_dir: Path | None = None
    loop: LoopChoice = "python"  # --loop: the enforcer's loop (catanc run --loop)


@dataclass
class Measured:
    """What one policy's run left: its window, every run, and the plan's side (catan)."""

    start_ns: int = 0
    end_ns: int = 0
    runs: list[RunRecord] = field(default_factory=list)
    cores_of: dict[str, tuple[int, ...]] = field(default_factory=dict)  # node -> the plan cores it may use
    replans: int = 0
    model: dict[tuple[str, ...], float] = field(default_factory=dict)
    promised: dict[str, float] = field(default_factory=dict)  # heads' rates as the last plan promises them run
    schedule: RuntimeSchedule | None = None


def bench_loop(choice: LoopChoice) -> LoopChoice:
    """The enforcer's loop for a bench's ``--loop``: ``auto`` is the compiled one wherever numba is, built before
    the first run if it must be (a build beside the runs would disturb what they measure)."""
    if choice == "auto":
        return "python" if compiled_ready.state() is LoopState.NO_NUMBA else "compiled"
    return choice


def check_policies(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` without repeats, or a usage error naming the unknown one."""
    for name in names:
        if name not in POLICIES:
            raise UsageError(f"--policy: unknown policy {name!r} (expected one of: {', '.join(POLICIES)})")
    return tuple(dict.fromkeys(names))


def check_setup(setup: BenchSetup, policies: Sequence[str]) -> None:
    """Everything that can be checked before a worker starts: cores, the baseline, privileges."""
    cpus = allowed_cpus()
    if setup.cores > len(cpus):
        raise UsageError(f"--cores {setup.cores}: this process may use only {len(cpus)} CPU(s) ({sorted(cpus)})")
    if any(policy in ("baseline", "fifo-static") for policy in policies):
        trigger_rules(setup.spec)
    needed = [ENFORCER_FIFO] if ENFORCED_POLICIES.intersection(policies) else []
    if "fifo-static" in policies:
        needed.append(driver_level(fifo_levels(build_problem(setup.spec), setup.spec)))
    if needed:
        try:
            check_fifo_allowed(max(needed))
        except PrivilegeError as exc:
            chosen = " and ".join(p for p in policies if p in FIFO_POLICIES)
            raise PrivilegeError(
                f"catanc bench: {chosen} run(s) the app under SCHED_FIFO: {exc}\n"
                "The baseline alone (SCHED_OTHER) needs no privilege: catanc bench SPEC --policy baseline"
            ) from None


MAX_APP_FIFO = 97
"""The highest SCHED_FIFO level a node gets under fifo-static: the driver runs one above, the watchdog at 10+."""


def fifo_levels(problem: Problem, spec: Spec) -> dict[str, int]:
    """fifo-static: each scheduled node's SCHED_FIFO level, its subchain's static priority, as 1, 2, ...

    :func:`catanc.planning.baseline.static_priorities` ranks subchains (the spec's ``baseline.priorities``,
    else by importance; the simulator's fifo-static uses the same); equal ranks share a level, and the
    levels keep their order.
    """
    ranks = static_priorities(spec, problem)
    levels = {rank: level for level, rank in enumerate(sorted(set(ranks.values())), start=1)}
    if len(levels) > MAX_APP_FIFO:
        raise UsageError(f"{spec.app}: {len(levels)} distinct subchain priorities; SCHED_FIFO has {MAX_APP_FIFO}")
    return {node: levels[ranks[sub.name]] for sub in problem.subchains for node in sub.nodes}


def driver_level(levels: Mapping[str, int]) -> int:
    """fifo-static: the driver's SCHED_FIFO level, above every node's."""
    return max(levels.values(), default=0) + 1


def bench_policies(setup: BenchSetup, policies: Sequence[str], progress: Progress | None = None) -> list[PolicyResult]:
    """Check the setup, then run each policy in turn."""
    chosen = check_policies(policies)
    check_setup(setup, chosen)
    results = []
    for policy in chosen:
        if progress is not None:
            progress(f"{policy}: {setup.duration_s:g} s on {setup.cores} core(s)")
        results.append(bench_policy(setup, policy))
    return results


def bench_policy(setup: BenchSetup, policy: str) -> PolicyResult:
    """One run of ``policy`` (call :func:`check_setup` first), replayed into the simulator's result."""
    check_policies([policy])
    spec = setup.spec
    chains = reported_chains(spec, build_problem(spec))
    with tempfile.TemporaryDirectory(prefix="catanc-bench-") as tmp:
        folder = Path(tmp)
        workers = Workers(setup, folder)
        try:
            if policy in ENFORCED_POLICIES:
                measured = run_enforced(setup, planned_spec(setup, policy), folder, workers)
                if setup.log_dir is not None:
                    log = (folder / ENFORCER_LOG).read_bytes()
                    write_files(setup.log_dir, {f"{policy}.jsonl": log}, kind="run log")
            else:
                measured = run_timers(setup, policy, folder, workers)
            measured.runs = workers.finish()
            if setup.log_dir is not None:
                runs = records_text(sorted(measured.runs)).encode()
                write_files(setup.log_dir, {f"{policy}.runs.jsonl": runs}, kind="worker records")
        finally:
            workers.children.stop()
    window = {"start_ns": measured.start_ns, "end_ns": measured.end_ns}
    flow = replay(spec, [nodes for nodes, _ in chains], measured.runs, **window)
    busy = utilisation(measured.runs, measured.cores_of, setup.cores, **window)
    return measured_result(
        policy,
        flow,
        chains,
        duration_s=setup.duration_s,
        utilisation=busy,
        replans=measured.replans,
        model=measured.model,
        promised=measured.promised,
        schedule=measured.schedule,
    )


class Workers:
    """The run's worker processes, each with its record file: one per scheduled node, one per executor."""

    def __init__(self, setup: BenchSetup, folder: Path) -> None:
        self.setup = setup
        self.children = Children()
        self.records: dict[str, Path] = {}  # by the worker's nodes, joined by ", "
        self.nodes = [name for name, node in setup.spec.nodes.items() if node.scheduled]
        self.groups = worker_groups(self.nodes, executor_nodes(setup.spec))
        for index, group in enumerate(self.groups):
            self.records[", ".join(group)] = folder / f"worker-{index}.runs"  # node names need not be file names

    def start(self, socket_path: Path) -> None:
        """Start every worker; the workload model's time counts from now."""
        clock_start_ns = time.monotonic_ns()
        spec = self.setup.spec
        for group in self.groups:
            key = ", ".join(group)
            argv = workload_worker_command(
                list(group),
                self.setup.spec_path.absolute(),
                seed=self.setup.seed,
                clock_start_ns=clock_start_ns,
                record=self.records[key],
                socket_path=socket_path,
                speedups={name: spec.nodes[name].threads.speedups for name in group},
                executors=[group] if len(group) > 1 else [],
            )
            self.children.start(key, argv, str(socket_path))

    def check_alive(self) -> None:
        """Raise :class:`BenchError` if a worker has exited (before the run is over, none should)."""
        for name, code in self.children.exited():
            raise BenchError(f"the worker of node {name!r} exited with status {code} (its error is above)")

    def finish(self) -> list[RunRecord]:
        """Wait for the stopped workers to exit, then read their records."""
        deadline = time.monotonic() + EXIT_TIMEOUT_S
        while len(self.children.exited()) < len(self.children.processes) and time.monotonic() < deadline:
            time.sleep(WAIT_STEP_S)
        codes = dict(self.children.exited())
        runs: list[RunRecord] = []
        for name, path in self.records.items():
            code = codes.get(name)
            if code is None:
                raise BenchError(f"the worker of node {name!r} did not exit within {EXIT_TIMEOUT_S:g} s of the stop")
            if code != 0:
                raise BenchError(f"the worker of node {name!r} exited with status {code} (its error is above)")
            try:
                runs += read_records(path)
            except (OSError, ValueError) as exc:
                raise BenchError(f"cannot read the runs of node {name!r}: {exc}") from None
        return runs


# --------------------------------------------------------------------------- catan: the enforcer


def planned_spec(setup: BenchSetup, policy: str) -> Spec:
    """The spec the enforcer plans with: the app's for ``catan``; for a static policy, the app with
    the profiled tail compute times (:func:`~catanc.sim.simulate.static_profile`) and no re-solve
    before the run ends; for ``catan-nosteal``, the app without priority stealing
    (:func:`~catanc.sim.simulate.policy_spec`). The workers still burn what the app's own workload model draws."""
    spec = setup.spec
    if policy in CATAN_POLICIES:
        return policy_spec(spec, policy)
    tails = static_profile(Setup(spec, setup.cores, setup.duration_s, setup.seed), policy)
    nodes = {name: node.model_copy(update={"compute_ms": tails[name]}) if name in tails else node
             for name, node in spec.nodes.items()}  # fmt: skip
    never = setup.duration_s + NO_RESOLVE_MARGIN_S
    runtime = spec.runtime.model_copy(
        update={"first_solve_after_s": never, "stage2_every_s": never, "stage1_every_s": never}
    )
    return spec.model_copy(update={"nodes": nodes, "runtime": runtime})


def run_enforced(setup: BenchSetup, spec: Spec, folder: Path, workers: Workers) -> Measured:
    """The workers under the real enforcer planning with ``spec``, as ``catanc run`` runs them."""
    from catanc.artifacts.runtime_table import RuntimeTable  # noqa: PLC0415
    from catanc.runtime.enforcer.run import Enforcer  # noqa: PLC0415 - the baselines need none of it
    from catanc.runtime.linux.watchdog import Watchdog  # noqa: PLC0415
    from catanc.runtime.logs.writer import read_log  # noqa: PLC0415

    table = RuntimeTable(path=setup.spec_path, app=spec.app, cores=setup.cores, spec=spec, plan=None, processes=())
    socket_path = folder / "enforcer.sock"
    log_path = folder / ENFORCER_LOG
    measured = Measured()

    def begin(enforcer: Enforcer) -> None:
        workers.start(socket_path)
        deadline = time.monotonic() + REGISTER_TIMEOUT_S
        while True:
            missing = [node for node in workers.nodes if not enforcer.registry.of(node)]
            if not missing:
                break
            workers.check_alive()
            if time.monotonic() > deadline:
                raise BenchError(f"node(s) {', '.join(missing)} did not register within {REGISTER_TIMEOUT_S:g} s")
            time.sleep(WAIT_STEP_S)
        measured.start_ns = time.monotonic_ns()

    # The enforcer raises the calling thread to SCHED_FIFO and shortens the interpreter's switch
    # interval for its run; this process goes on afterwards, so both are put back here.
    main_tid = threading.get_native_id()
    original = read_policy(main_tid)
    interval = sys.getswitchinterval()
    restorer = Restorer(Watchdog().start())
    try:
        enforcer = Enforcer(
            table,
            socket_path=str(socket_path),
            rt=True,
            start="spec",
            log_path=log_path,
            cores=setup.cores,
            restorer=restorer,
            loop=setup.loop,
        )
    except BaseException:
        restorer.close()
        raise
    try:
        enforcer.run(setup.duration_s, on_start=begin)
    finally:
        apply_policy(main_tid, original)
        sys.setswitchinterval(interval)
        gc.unfreeze()
    measured.end_ns = measured.start_ns + round(setup.duration_s * 1e9)
    schedule = enforcer.schedule
    measured.schedule = schedule
    measured.cores_of = {node: run.cores for run in schedule.subchains.values() for node in run.nodes}
    resolves = [event for event in read_log(log_path) if event.get("event") == "resolve"]
    measured.replans = len(resolves)
    plan = last_plan(spec, setup.cores, resolves)
    measured.model = {tuple(chain.nodes): chain.response_ms for chain in plan.chains}
    measured.promised = promised_rates(plan)
    return measured


def last_plan(spec: Spec, cores: int, resolves: Sequence[Mapping[str, Any]]) -> Plan:
    """The enforcer's last plan, made again: what the run is compared with (chains' ``R``, heads' rates).

    The enforcer's planner process is deterministic: its plan is the spec's, then one re-solve
    per ``resolve`` line of its log, with the compute times the line lists
    (:mod:`catanc.runtime.enforcer.reoptimiser`).  This does the same.
    """
    from catanc.planning.replan import Replanner  # noqa: PLC0415 - solvers: only for catan

    replanner = Replanner(spec, cores)
    for event in resolves:
        compute = {str(k): float(v) for k, v in dict(event.get("compute_ms") or {}).items()}
        plan = dict(event.get("plan") or {})
        try:
            if event.get("reason") == "costs" and event.get("error") is None:  # re-planned with measured costs
                costs = {"switch_ms": float(plan["switch_ms"]), "slack": float(plan["slack"])}
                spec = spec.model_copy(update={"schedule": spec.schedule.model_copy(update=costs)})
                replanner = Replanner(spec, cores)
                replanner.reallocate(compute or None)
            elif event.get("stage1"):
                replanner.reallocate(compute or None)
            else:
                replanner.resolve(compute)
        except Exception:  # the enforcer kept its last plan after a failed re-solve too
            continue
    return replanner.plan


# --------------------------------------------------------------------------- baselines: the driver


def run_timers(setup: BenchSetup, policy: str, folder: Path, workers: Workers) -> Measured:
    """The workers under the baseline's triggers: CFS (``baseline``) or static SCHED_FIFO (``fifo-static``)."""
    spec = setup.spec
    rules = trigger_rules(spec)
    cpus = frozenset(sorted(allowed_cpus())[: setup.cores])
    fifo = policy == "fifo-static"
    levels = fifo_levels(build_problem(spec), spec) if fifo else {}
    if fifo:
        from catanc.runtime.linux.watchdog import Watchdog  # noqa: PLC0415

        restorer = Restorer(Watchdog().start())
    else:
        restorer = Restorer()
    measured = Measured(cores_of=dict.fromkeys(workers.nodes, tuple(range(setup.cores))))

    def place(hello: protocol.Hello) -> None:
        if fifo:
            restorer.remember(hello.tid)
        set_affinity(hello.tid, cpus)
        if fifo:
            set_fifo(hello.tid, levels[hello.node])

    with restorer, DriverSocket(folder / "driver.sock") as sock:
        driver = Driver(sock, spec, rules, place=place)
        try:
            workers.start(sock.path)
            driver.register(workers.nodes, REGISTER_TIMEOUT_S, workers.check_alive)
            if fifo:  # the timers' thread above the app's, as the simulator's timers are never late
                main_tid = threading.get_native_id()
                restorer.remember(main_tid)
                set_fifo(main_tid, driver_level(levels))
            measured.start_ns = time.monotonic_ns()
            measured.end_ns = measured.start_ns + round(setup.duration_s * 1e9)
            driver.run(measured.start_ns / 1e6, measured.end_ns / 1e6)
        finally:
            driver.stop()
    return measured
