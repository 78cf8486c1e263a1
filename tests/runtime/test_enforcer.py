"""``catanc run`` on the real kernel: real node processes on this machine's CPUs 0 and 1.

Each test compiles a small spec of its own into its folder and starts the enforcer as ``python -m
catanc run`` would (with ``--socket`` and ``--log`` in the test's folders), then starts node
processes that talk to it through :mod:`catanc.client`: :func:`catanc.runtime.worker.command.worker_command`
workers, or :data:`LINGERING_NODE` where a thread must outlive the run so that the test can see what
the enforcer left it with.  The specs whose rates are checked have runs of 8-36 ms and rates of
18-50 Hz, so the ~0.1-0.3 ms a trigger and a done message cost stay a few percent of a period.

What each thread runs at is read from ``/proc/<pid>/task/<tid>`` (``stat`` fields 40 and 41,
``status``'s Cpus_allowed_list), never through catanc; what the enforcer planned and measured comes
from its JSON-lines log (:mod:`catanc.runtime.logs.writer`, flushed once a second).  The plan a check compares
with is the one in force at the time (the latest ``start`` or ``resolve`` event).  Rates are
measured from the ``run`` events' timestamps over the last seconds of a run.  Bounds are generous:
this checks that the mechanism works; it is not a benchmark.

Everything skips with the reason when SCHED_FIFO is not permitted or CPUs 0 and 1 are not both
allowed.  Every wait has a timeout; every process started here (each in its own session) and the
enforcer's watchdog are SIGKILLed at teardown, the nodes first (so none is left at SCHED_FIFO
without its enforcer).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from catanc.errors import ExitCode
from catanc.model.priorities import ENFORCER_FIFO, RUNNING_FIFO, SHARED_FIFO, UNSCHEDULED_FIFO
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
from catanc.runtime.logs.writer import read_log
from catanc.runtime.worker.command import worker_command
from catanc.runtime.worker.draws import Profile
from tests.support.enforcer_runs import (
    ENFORCER_MAIN,
    EnforcerRun,
    Event,
    cmdline,
    compile_table,
    kill_groups,
    of_kind,
    process_name,
)
from tests.support.linux import (
    WAIT_S,
    Sched,
    alive,
    as_user,
    missing_tools,
    poll,
    sched_of,
    threads_of,
)

PLANNER = "catanc-planner"  # the re-optimiser's process name, as `ps -o comm` and `top` show it
KILL_BOUND_S = 1.0  # the issue: after the enforcer's SIGKILL, every app thread is back within this
RATE_TOLERANCE = 0.10  # the issue: measured rates within 10% of planned
BOTH = frozenset({0, 1})
MINE = frozenset(os.sched_getaffinity(0))  # what the node processes started here may run on

# A node whose thread lives on after its run ends (the enforcer stopped it, or went away), as an
# app's would: the test reads the policy and affinity it was left with.
LINGERING_NODE = """\
import sys, time
from catanc.client import ClientError, Node
from catanc.runtime.worker.burn import burn

name, compute_ms, socket_path = sys.argv[1], float(sys.argv[2]), sys.argv[3]
try:
    with Node(name, socket_path=socket_path) as node:
        for _trigger in node:
            burn(compute_ms)
            node.done()
except ClientError as exc:
    print(exc, file=sys.stderr, flush=True)
time.sleep(60)
"""

# Two cores: one dedicated subchain, two sharing the other core, one unscheduled node that registers.
# Stage I puts `front` (cam + track, 18 ms, capped at 25 Hz) alone on core 0: its period is the cap,
# 40 ms; `map` (12 ms, f = 1) and `plan` (15 ms, f = 1/2) share core 1 with T ~ 23.2 ms, i.e. ~43
# and ~22 Hz.  Every period is >= 20 ms and every run >= 8 ms, so the trigger/done hops (~0.1-0.3 ms
# each) and the 0.12 ms switches are ~1-3% of a period: a 10% rate check is honest for this spec.
# The slack is 15%, not the default 5%: on a shared VM the host's steal and the kernel's own claims
# (Linux >= 6.12 keeps 50 ms a second of each CPU for SCHED_OTHER tasks) can take 5% of core 1, and
# `plan`, whose run spans two of its slices, then misses triggers (CI once measured it 12% slow).
# The only re-solve (Stage II with the measured times, at 2.5 s, once every node has run) keeps the
# allocation.
MIXED_SPEC = """\
catan: 1
app: mixed
nodes:
  imu: {scheduled: false, rate_hz: 100}
  cam: {compute_ms: 10}
  track: {compute_ms: 8}
  map: {compute_ms: 12}
  plan: {compute_ms: 15}
edges:
  - [imu, track]
  - [cam, track]
  - [track, map]
  - [map, plan]
subchains:
  front: [cam, track]
  map: [map]
  plan: [plan]
objective:
  - {chain: [cam, track], weight: 1.0}
  - {node: map, weight: 0.3}
  - {node: plan, weight: 0.1}
constraints:
  - {node: cam, max_rate_hz: 25}
schedule: {slack: 0.15}
runtime: {first_solve_after_s: 2.5, stage2_every_s: 100, stage1_every_s: 100}
"""
MIXED_COMPUTE: dict[str, float] = {"cam": 10, "track": 8, "map": 12, "plan": 15, "imu": 0}

# The same app, re-solving Stage II every second with a short window, for the slow-down test.
SLOWING_SPEC = MIXED_SPEC.replace(
    "runtime: {first_solve_after_s: 2.5, stage2_every_s: 100, stage1_every_s: 100}",
    "runtime: {window: 20, first_solve_after_s: 2, stage2_every_s: 1, stage1_every_s: 100}",
)

# One core, two subchains.  `hi` (weight 1) outranks `lo` (weight 0.1) for stealing.  It is planned
# with its mean, 0.8 * 5 + 0.2 * 30 = 10 ms: a 10 ms slice every T ~ 14 ms.  One run in five takes
# 30 ms, two periods and more: it is late at `lo`'s slot and takes it.  No re-solve, so the plan
# stays the mean's.
STEALING_SPEC = """\
catan: 1
app: stealing
nodes:
  hi: {compute_ms: {modes: [{share: 0.8, ms: 5}, {share: 0.2, ms: 30}]}}
  lo: {compute_ms: 10}
subchains: {hi: [hi], lo: [lo]}
objective:
  - {node: hi, weight: 1.0}
  - {node: lo, weight: 0.1}
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""


# --------------------------------------------------------------------------- reading /proc


OTHER = Sched(os.SCHED_OTHER, 0, MINE)  # every node thread started here, before and after a run


def children_of(pid: int) -> list[int]:
    found: list[int] = []
    for tid in threads_of(pid):
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):
            found += [int(word) for word in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
    return found


# --------------------------------------------------------------------------- reading the log


def plans(events: Sequence[Event]) -> list[tuple[float, dict[str, Any]]]:
    """Every plan the enforcer put in force, with when: the first one, then each re-solve's."""
    return [(event["t"], event["plan"]) for event in events if event["event"] in ("start", "resolve")]


def plans_during(events: Sequence[Event], since: float, until: float) -> list[dict[str, Any]]:
    """The plans in force at some time in ``[since, until]``."""
    timed = plans(events)
    first = max((i for i, (t, _) in enumerate(timed) if t <= since), default=0)
    return [plan for t, plan in timed[first:] if t <= until]


def runs_of(events: Sequence[Event], subchain: str, since: float, until: float) -> list[float]:
    return [e["t"] for e in of_kind(events, "run") if e["subchain"] == subchain and since <= e["t"] <= until]


def measured_hz(events: Sequence[Event], subchain: str, since: float, until: float) -> float:
    """Completed runs per second of ``subchain`` in ``[since, until]`` (first to last completion)."""
    times = runs_of(events, subchain, since, until)
    assert len(times) >= 10, f"{subchain}: only {len(times)} runs between {since:.1f} s and {until:.1f} s"
    return (len(times) - 1) / (times[-1] - times[0])


def planned_hz(plan_list: Sequence[dict[str, Any]], subchain: str) -> float:
    """The planned rate of ``subchain``, after checking every plan in ``plan_list`` agrees on it within 3%."""
    periods: list[float] = [plan["subchains"][subchain]["period_ms"] for plan in plan_list]
    assert max(periods) <= 1.03 * min(periods), f"{subchain}: the plan changed meanwhile: {periods}"
    return 1000.0 * len(periods) / sum(periods)


# --------------------------------------------------------------------------- the processes


def table_subchains(table: Path) -> dict[str, dict[str, Any]]:
    subchains: dict[str, dict[str, Any]] = json.loads(table.read_text())["plan"]["subchains"]
    return subchains


@dataclass
class Harness(EnforcerRun):
    """One test's enforcer and node processes; :meth:`close` kills what is left of them."""

    workers: list[subprocess.Popen[bytes]] = field(default_factory=list)
    helpers: list[int] = field(default_factory=list)  # the enforcer's watchdog and planner
    began: float = 0.0

    def start(
        self, table: Path, *options: str, duration: float, stdout: int | None = None, prefix: Sequence[str] = ()
    ) -> None:
        """Start the enforcer and wait until it is up: its socket bound (its log is flushed once a second)."""
        argv = [*prefix, sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet"]
        argv += ["--socket", str(self.socket), "--log", str(self.log), "--duration", str(duration), *options]
        with (self.folder / "enforcer.out").open("wb") as out, (self.folder / "enforcer.err").open("wb") as err:
            output = out.fileno() if stdout is None else stdout
            self.enforcer = subprocess.Popen(argv, stdout=output, stderr=err, start_new_session=True)
        enforcer = self.enforcer
        poll(lambda: enforcer.poll() is not None or self.socket.exists(), "the enforcer's socket")
        assert enforcer.poll() is None, self.stderr()
        self.began = time.monotonic()
        self.helpers = children_of(self.pid)  # the planner and the watchdog start before the socket is bound

    def node(self, argv: Sequence[str]) -> subprocess.Popen[bytes]:
        index = len(self.workers)
        with (self.folder / f"node-{index}.err").open("wb") as err:
            proc = subprocess.Popen(list(argv), stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        self.workers.append(proc)
        return proc

    def worker(self, nodes: dict[str, Profile], **options: Any) -> subprocess.Popen[bytes]:
        """A :mod:`catanc.runtime.worker` process serving ``nodes``."""
        return self.node(worker_command(nodes, socket_path=self.socket, **options))

    def lingering(self, name: str, compute_ms: float) -> subprocess.Popen[bytes]:
        """A :data:`LINGERING_NODE` process."""
        return self.node([sys.executable, "-c", LINGERING_NODE, name, repr(compute_ms), str(self.socket)])

    def close(self) -> None:
        kill_groups([*self.workers, *([self.enforcer] if self.enforcer else [])])  # nodes first
        registered = [e["pid"] for e in of_kind(self.events(), "register")]  # --demo's workers have their sessions
        self.end_helpers({*self.helpers, *registered})  # and so has the watchdog


@contextlib.contextmanager
def harness_in(folder: Path) -> Iterator[Harness]:
    harness = Harness(folder, Path(tempfile.mkdtemp(prefix="catanc-test-")))
    try:
        yield harness
    finally:
        harness.close()


@pytest.fixture
def harness(tmp_path: Path) -> Iterator[Harness]:
    with harness_in(tmp_path) as made:
        yield made


def expected_sched(
    node: str, plan: dict[str, Any], table: dict[str, dict[str, Any]]
) -> tuple[set[int], frozenset[int]]:
    """The SCHED_FIFO priorities ``node``'s thread may show under ``plan``, and its CPUs."""
    for name, sub in table.items():
        if node in sub["nodes"]:
            planned = plan["subchains"][name]
            cpus = frozenset(planned["cores"])
            return ({SHARED_FIFO, RUNNING_FIFO} if planned["shared"] else {RUNNING_FIFO}), cpus
    return {UNSCHEDULED_FIFO}, frozenset(range(plan["cores"]))


def sample(threads: dict[str, tuple[int, int]]) -> dict[str, Sched | None]:
    return {node: sched_of(pid, tid) for node, (pid, tid) in threads.items()}


def wait_all_pinned_to(threads: dict[str, tuple[int, int]], cpu: int) -> None:
    """Wait (3 s at most) until every one of ``threads`` may run on ``cpu`` alone."""

    def pinned() -> bool | None:
        now = [sched_of(pid, tid) for pid, tid in threads.values()]
        return all(sched is not None and sched.cpus == frozenset({cpu}) for sched in now) or None

    poll(pinned, f"every node thread pinned to CPU {cpu}", timeout=3.0)


def restored(threads: dict[str, tuple[int, int]]) -> bool:
    return all(found == OTHER for found in sample(threads).values())


# --------------------------------------------------------------------------- what the machine allows


REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: every test here needs SCHED_FIFO up to it
pytestmark = pytest.mark.usefixtures("real_kernel")


# --------------------------------------------------------------------------- a plain run, watched throughout

MIXED_DURATION_S = 7.0


@dataclass
class MixedRun:
    """What one 7 s run of :data:`MIXED_SPEC` on two cores showed."""

    table: dict[str, dict[str, Any]]
    events: list[Event]
    threads: dict[str, tuple[int, int]]  # node -> (pid, tid), from the register events
    samples: list[tuple[float, dict[str, Sched | None]]]  # (seconds since the start, each node's thread)
    enforcer_threads: dict[int, Sched | None]  # mid-run
    helpers: dict[str, Sched | None]  # "planner", "watchdog": their main threads, mid-run
    returncode: int
    after: dict[str, Sched | None]  # each node's thread once the enforcer has exited


@pytest.fixture(scope="module", params=["python", "compiled"])
def mixed(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[MixedRun]:
    """The run, with the enforcer's Python loop and with its compiled one (``--loop``)."""
    if request.param == "compiled":
        request.getfixturevalue("compiled_loop")  # skips without numba
    loop = ["--loop", request.param]
    folder = tmp_path_factory.mktemp("mixed")
    table = compile_table(MIXED_SPEC, folder, 2)
    with harness_in(folder) as run:
        run.start(table, "--start", "spec", *loop, duration=MIXED_DURATION_S)
        for node, compute in MIXED_COMPUTE.items():
            run.lingering(node, compute)
        threads = run.registered(list(MIXED_COMPUTE))
        samples = []
        enforcer_threads: dict[int, Sched | None] = {}
        helpers: dict[str, Sched | None] = {}
        time.sleep(0.5)  # the first runs
        while time.monotonic() < run.began + MIXED_DURATION_S - 0.7:
            samples.append((time.monotonic() - run.began, sample(threads)))
            if not enforcer_threads and time.monotonic() > run.began + 3.0:
                enforcer_threads = {tid: sched_of(run.pid, tid) for tid in threads_of(run.pid)}
                for pid in run.helpers:
                    planner = process_name(pid) == PLANNER
                    kind = "watchdog" if "watchdog" in cmdline(pid) else "planner" if planner else ""
                    helpers[kind or str(pid)] = sched_of(pid, pid)
            time.sleep(0.03)
        returncode = run.wait()
        after = sample(threads)
        yield MixedRun(
            table_subchains(table), run.events(), threads, samples, enforcer_threads, helpers, returncode, after
        )


def test_the_run_ends_cleanly_after_its_duration(mixed: MixedRun) -> None:
    assert mixed.returncode == 0
    kinds = [event["event"] for event in mixed.events]
    assert kinds[0] == "start"
    assert kinds[-1] == "stop"
    assert mixed.events[-1]["t"] == pytest.approx(MIXED_DURATION_S, abs=1.0)
    assert not of_kind(mixed.events, "lost")
    resolves = of_kind(mixed.events, "resolve")
    assert [(r["reason"], r["allocation_changed"], r["error"]) for r in resolves] == [("stage2", False, None)]


def test_node_threads_get_the_planned_policy_priority_and_cpus(mixed: MixedRun) -> None:
    allocations = {
        json.dumps({n: (s["cores"], s["shared"]) for n, s in plan["subchains"].items()})
        for _, plan in plans(mixed.events)
    }
    assert len(allocations) == 1, "Stage I never ran: every plan keeps the allocation"
    plan = plans(mixed.events)[-1][1]
    assert len(mixed.samples) >= 50
    seen: dict[str, set[int]] = {node: set() for node in mixed.threads}
    for when, found in mixed.samples:
        for node, sched in found.items():
            priorities, cpus = expected_sched(node, plan, mixed.table)
            assert sched is not None, f"{node}'s thread exited during the run"
            assert sched.policy == os.SCHED_FIFO, f"{node} at {when:.2f} s: {sched}"
            assert sched.priority in priorities, f"{node} at {when:.2f} s: {sched}, expected one of {priorities}"
            assert sched.cpus == cpus, f"{node} at {when:.2f} s: {sched}, expected CPUs {sorted(cpus)}"
            seen[node].add(sched.priority)
    # The layout this spec is about: front dedicated on core 0, map and plan sharing core 1.
    assert {n: (s["cores"], s["shared"]) for n, s in plan["subchains"].items()} == {
        "front": ([0], False),
        "map": ([1], True),
        "plan": ([1], True),
    }
    assert seen == {
        "cam": {RUNNING_FIFO},
        "track": {RUNNING_FIFO},
        "map": {SHARED_FIFO, RUNNING_FIFO},  # raised for its slice, back between slices
        "plan": {SHARED_FIFO, RUNNING_FIFO},
        "imu": {UNSCHEDULED_FIFO},
    }


def test_the_enforcer_is_one_loop_at_fifo_4_pinned_to_the_shared_core(mixed: MixedRun) -> None:
    """The main thread only waits (its CPUs are the process's); one loop thread does everything, pinned to the
    shared core whose switches it makes; the solvers run in a process of their own at SCHED_OTHER."""
    found = {tid: sched for tid, sched in mixed.enforcer_threads.items() if sched is not None}
    main = next(iter(found))
    assert found[main] == Sched(os.SCHED_FIFO, ENFORCER_FIFO, MINE)  # the main thread (lowest tid)
    assert sorted(found.values(), key=str) == sorted(
        [Sched(os.SCHED_FIFO, ENFORCER_FIFO, MINE), Sched(os.SCHED_FIFO, ENFORCER_FIFO, frozenset({1}))], key=str
    ), [str(s) for s in found.values()]
    assert mixed.helpers["planner"] == OTHER  # the solvers never run at a real-time priority
    assert mixed.helpers["watchdog"] == Sched(os.SCHED_FIFO, WATCHDOG_PRIORITY, MINE)


def test_measured_rates_are_within_10_percent_of_the_plan_in_force(mixed: MixedRun) -> None:
    end = of_kind(mixed.events, "stop")[0]["t"]
    resolve = of_kind(mixed.events, "resolve")[0]
    for node in ("cam", "track", "map", "plan"):  # so it planned with measured times (unmeasured nodes keep the plan's)
        assert resolve["compute_ms"][node] == pytest.approx(MIXED_COMPUTE[node], rel=0.1), resolve["compute_ms"]
    since, until = resolve["t"] + 1.0, end - 0.1  # the plan it made, settled
    in_force = plans_during(mixed.events, since, until)
    report = {}
    for name in ("front", "map", "plan"):
        planned = planned_hz(in_force, name)
        measured = measured_hz(mixed.events, name, since, until)
        report[name] = (round(planned, 2), round(measured, 2))
        assert measured == pytest.approx(planned, rel=RATE_TOLERANCE), (
            f"{name}: planned {planned:.2f} Hz, measured {measured:.2f} Hz"
        )
    print("planned vs measured Hz:", report)
    assert not of_kind(mixed.events, "lost")


def test_a_normal_end_puts_every_node_thread_back(mixed: MixedRun) -> None:
    assert mixed.after == dict.fromkeys(mixed.threads, OTHER)


def test_a_re_solve_before_the_nodes_ran_keeps_the_spec_times(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(MIXED_SPEC.replace("first_solve_after_s: 2.5", "first_solve_after_s: 0.5"), tmp_path, 2)
    harness.start(table, "--start", "spec", duration=2.0)
    resolve = poll(lambda: of_kind(harness.events(), "resolve"), "the first re-solve")[0]
    start = of_kind(harness.events(), "start")[0]
    harness.wait()
    assert resolve["error"] is None
    for name, planned in start["plan"]["subchains"].items():
        assert resolve["plan"]["subchains"][name]["period_ms"] == pytest.approx(planned["period_ms"], rel=0.01), (
            f"{name}: re-solved with {resolve['compute_ms']} before any node ran"
        )


def test_a_subchain_starts_only_once_every_node_of_it_has_registered(harness: Harness, tmp_path: Path) -> None:
    """`front` is cam -> track. With cam up alone for 1.5 s (longer than the 1 s lost limit), a run
    started then would stall at track and be given up as lost; none is started until track is up."""
    table = compile_table(MIXED_SPEC, tmp_path, 2)
    harness.start(table, "--start", "spec", duration=4.0)
    harness.lingering("cam", MIXED_COMPUTE["cam"])
    harness.registered(["cam"])
    time.sleep(1.5)
    harness.lingering("track", MIXED_COMPUTE["track"])
    harness.registered(["track"])
    harness.wait()
    events = harness.events()
    assert not of_kind(events, "lost")
    track_up = next(e["t"] for e in of_kind(events, "register") if e["node"] == "track")
    front = [e for e in of_kind(events, "run") if e["subchain"] == "front"]
    assert front, "front never ran once both its nodes were up"
    assert all(e["t"] >= track_up for e in front)


# A node that takes its first trigger and never answers (it sleeps: no CPU is burnt at SCHED_FIFO).
SILENT_NODE = """\
import sys, time
from catanc.client import Node

with Node(sys.argv[1], socket_path=sys.argv[2]) as node:
    for _trigger in node:
        time.sleep(60)
"""


def test_a_run_stuck_at_a_node_is_given_up_while_other_traffic_flows(harness: Harness, tmp_path: Path) -> None:
    """track never answers while cam, map and plan keep the socket busy (datagrams every few ms, so
    the receiver never waits out its timeout): front's stuck run is still reported lost after ~1 s."""
    table = compile_table(MIXED_SPEC, tmp_path, 2)
    harness.start(table, "--start", "spec", duration=3.5)
    for node in ("cam", "map", "plan"):
        harness.lingering(node, MIXED_COMPUTE[node])
    harness.node([sys.executable, "-c", SILENT_NODE, "track", str(harness.socket)])
    harness.registered(["cam", "track", "map", "plan"])
    harness.wait()
    lost = [e for e in of_kind(harness.events(), "lost") if e["subchain"] == "front"]
    assert lost
    assert lost[0]["node"] == "track"
    assert of_kind(harness.events(), "run"), "the other subchains kept running"


# One node busy all the time (1.2 s runs back to back on its own core): when the run ends, it is
# in the middle of one, which ends after the enforcer's own shutdown (~0.2 s) is done.
BUSY_SPEC = """\
catan: 1
app: busy
nodes:
  work: {compute_ms: 1200}
subchains: {work: [work]}
objective:
  - {node: work, weight: 1.0}
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""


def test_a_node_in_the_middle_of_a_run_at_the_end_reports_it_and_ends_cleanly(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(BUSY_SPEC, tmp_path, 1)
    harness.start(table, "--start", "spec", duration=2.0)
    harness.lingering("work", 1200.0)
    harness.registered(["work"])
    assert harness.wait() == 0
    time.sleep(1.5)  # its last run (<= 1.2 s) is over: LINGERING_NODE has printed any error by now
    assert (tmp_path / "node-0.err").read_text() == "", "the node lost the enforcer in its last run"


# --------------------------------------------------------------------------- re-solving


def test_a_node_that_slows_down_3x_gets_a_re_solve_that_lowers_its_rate(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(SLOWING_SPEC, tmp_path, 2)
    duration = 9.0
    harness.start(table, "--start", "spec", duration=duration)
    for node, compute in MIXED_COMPUTE.items():
        slowing = {"scale_after": (2.5, 3.0)} if node == "map" else {}
        harness.worker({node: compute}, **slowing)
    harness.registered(list(MIXED_COMPUTE))
    assert harness.wait(duration + WAIT_S) == 0
    events = harness.events()

    # When map slowed down: its first slow run of five in a row (a lone slow run at start-up, seen
    # once in CI at 0.85 s, is not the slow-down).
    runs = [(e["t"], e["ms"] > 2 * MIXED_COMPUTE["map"]) for e in of_kind(events, "compute") if e["node"] == "map"]
    slow = [t for i, (t, _) in enumerate(runs) if all(is_slow for _, is_slow in runs[i : i + 5])]
    assert slow, "map never slowed down"
    slowed_at = slow[0]
    resolves = of_kind(events, "resolve")
    before = [r for r in resolves if r["t"] < slowed_at]
    after = [r for r in resolves if r["t"] > slowed_at + 1.0]  # its window holds slow runs by then
    assert before, f"no re-solve before the slow-down at {slowed_at:.2f} s"
    assert len(after) >= 3, f"re-solves: {[round(r['t'], 2) for r in resolves]}, slow-down at {slowed_at:.2f} s"
    assert all(r["error"] is None for r in resolves)
    # Only a re-plan for the runtime's measured costs (switch_ms, slack) may take a new allocation.
    assert all(not r["allocation_changed"] for r in resolves if r["reason"] != "costs")
    last_fast, first_slow = before[-1], after[0]
    assert last_fast["compute_ms"]["map"] == pytest.approx(MIXED_COMPUTE["map"], rel=0.1)
    assert first_slow["compute_ms"]["map"] / last_fast["compute_ms"]["map"] == pytest.approx(3.0, rel=0.1)
    fast_period = last_fast["plan"]["subchains"]["map"]["period_ms"]
    slow_period = first_slow["plan"]["subchains"]["map"]["period_ms"]
    assert slow_period > 1.5 * fast_period, f"map's period: {fast_period:.2f} ms, then {slow_period:.2f} ms"

    # The measured rate follows: over the last seconds, against the plans in force then.
    end = of_kind(events, "stop")[0]["t"]
    since, until = max(first_slow["t"] + 1.0, end - 3.0), end - 0.1
    planned = planned_hz(plans_during(events, since, until), "map")
    measured = measured_hz(events, "map", since, until)
    # Before: from the first re-solve (every plan since is a fast one) to the slow-down, so that a
    # re-solve just before the slow-down does not leave too short a window.
    fast = measured_hz(events, "map", before[0]["t"] + 0.2, slowed_at)
    print(f"map: {fast:.2f} Hz before (planned {1000 / fast_period:.2f}); after {measured:.2f} (planned {planned:.2f})")
    assert measured == pytest.approx(planned, rel=RATE_TOLERANCE)
    assert measured < 0.7 * fast


# --------------------------------------------------------------------------- priority stealing


def test_a_late_high_priority_subchain_steals_the_lower_ones_slot(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(STEALING_SPEC, tmp_path, 1)
    subchains = table_subchains(table)
    assert subchains["hi"]["priority"] > subchains["lo"]["priority"]
    assert subchains["hi"]["cores"] == subchains["lo"]["cores"] == [0]
    assert subchains["hi"]["slice_ms"] == pytest.approx(10.0)  # planned with the mean: the 30 ms runs overrun
    duration = 4.0
    harness.start(table, "--start", "spec", duration=duration)
    harness.worker({"hi": [(0.8, 5.0), (0.2, 30.0)]}, seed=1)
    harness.worker({"lo": 10.0})
    harness.registered(["hi", "lo"])
    assert harness.wait(duration + WAIT_S) == 0
    events = harness.events()
    assert not of_kind(events, "resolve")
    final = of_kind(events, "stop")[0]["summary"]["subchains"]
    print(
        {
            name: {key: row[key] for key in ("planned_hz", "measured_hz", "late", "steals", "skipped")}
            for name, row in final.items()
        }
    )
    assert final["hi"]["late"] > 0
    assert final["hi"]["steals"] > 0
    assert final["lo"]["steals"] == 0  # never from a subchain that outranks it
    statuses = [e["subchains"]["hi"]["steals"] for e in of_kind(events, "status")]
    assert statuses == sorted(statuses)


# --------------------------------------------------------------------------- ending: signals


def running_app(harness: Harness, tmp_path: Path) -> dict[str, tuple[int, int]]:
    """The mixed app on two cores, lingering nodes, running for a second: ``{node: (pid, tid)}``."""
    harness.start(compile_table(MIXED_SPEC, tmp_path, 2), "--start", "spec", duration=60.0)
    for node, compute in MIXED_COMPUTE.items():
        harness.lingering(node, compute)
    threads = harness.registered(list(MIXED_COMPUTE))
    time.sleep(1.0)
    before = sample(threads)
    assert all(sched is not None and sched.policy == os.SCHED_FIFO for sched in before.values()), before
    assert of_kind(harness.events(), "run")
    return threads


def time_to_restore(threads: dict[str, tuple[int, int]], since: float) -> float:
    """Seconds from ``since`` until every thread in ``threads`` is back to :data:`OTHER` (polled every 2 ms)."""
    poll(lambda: restored(threads), "every node thread back to SCHED_OTHER on its original CPUs", step=0.002)
    return time.monotonic() - since


def assert_helpers_exit(harness: Harness, timeout: float = 5.0) -> None:
    """The enforcer's planner and watchdog exit within ``timeout``."""
    poll(lambda: not [pid for pid in harness.helpers if alive(pid)], "the planner and the watchdog to exit", timeout)


def test_sigint_stops_the_run_and_puts_every_thread_back(harness: Harness, tmp_path: Path) -> None:
    threads = running_app(harness, tmp_path)
    sent = time.monotonic()
    os.kill(harness.pid, signal.SIGINT)
    took = time_to_restore(threads, sent)
    returncode = harness.wait()
    print(f"SIGINT: every thread back after {1000 * took:.1f} ms; exit status {returncode}")
    assert returncode == ExitCode.OK  # Ctrl-C is how a run without --duration ends: a normal end, summary printed
    assert "Traceback" not in harness.stderr()
    assert "log:" in (harness.folder / "enforcer.out").read_text()
    events = harness.events()
    assert events[-1]["event"] == "stop"
    assert sample(threads) == dict.fromkeys(threads, OTHER)
    assert_helpers_exit(harness)  # the planner and the watchdog are gone with it


def test_the_planner_is_a_fork_holding_only_its_socket(harness: Harness, tmp_path: Path) -> None:
    """Forked from the enforcer (it inherits the spec's imports: ~0.2 s of CPU a run), it holds none
    of the enforcer's descriptors (the log, the sockets, the watchdog's pipe), or the watchdog
    would not see the enforcer go: only stdio and its end of the socket pair."""
    running_app(harness, tmp_path)
    named = {pid: process_name(pid) for pid in harness.helpers}
    planners = [pid for pid, name in named.items() if name == PLANNER]
    assert len(planners) == 1, named
    held = {int(fd.name): str(fd.readlink()) for fd in Path(f"/proc/{planners[0]}/fd").iterdir()}
    beyond_stdio = [target for fd, target in held.items() if fd > 2]
    assert len(beyond_stdio) == 1, held
    assert beyond_stdio[0].startswith("socket:"), held
    os.kill(harness.pid, signal.SIGINT)
    assert harness.wait() == ExitCode.OK
    assert_helpers_exit(harness)


def test_sigkill_puts_every_thread_back_within_a_second(harness: Harness, tmp_path: Path) -> None:
    threads = running_app(harness, tmp_path)
    sent = time.monotonic()
    os.kill(harness.pid, signal.SIGKILL)
    took = time_to_restore(threads, sent)
    print(f"SIGKILL: every thread back after {1000 * took:.1f} ms (the watchdog)")
    assert took < KILL_BOUND_S
    assert harness.wait() == -signal.SIGKILL
    assert "stop" not in [event["event"] for event in harness.events()]
    time.sleep(0.3)  # nothing puts them back to FIFO afterwards
    assert sample(threads) == dict.fromkeys(threads, OTHER)
    assert_helpers_exit(harness)  # no orphans: the planner sees its pipe close, the watchdog ends after restoring


@dataclass
class Ended:
    """How a run of the mixed app ended on a signal."""

    threads: dict[str, tuple[int, int]]
    restore_s: float  # from the signal until every node thread was back
    returncode: int
    events: list[Event]
    stdout: str
    after: dict[str, Sched | None]


@pytest.fixture(scope="module")
def sigterm(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Ended]:
    """SIGTERM, as systemd, docker or a supervisor stop a service."""
    folder = tmp_path_factory.mktemp("sigterm")
    with harness_in(folder) as harness:
        threads = running_app(harness, folder)
        sent = time.monotonic()
        os.kill(harness.pid, signal.SIGTERM)
        took = time_to_restore(threads, sent)
        returncode = harness.wait()
        stdout = (folder / "enforcer.out").read_text()
        yield Ended(threads, took, returncode, harness.events(), stdout, sample(threads))


def test_sigterm_puts_every_thread_back(sigterm: Ended) -> None:
    print(f"SIGTERM: every thread back after {1000 * sigterm.restore_s:.1f} ms; exit status {sigterm.returncode}")
    assert sigterm.restore_s < KILL_BOUND_S
    assert sigterm.after == dict.fromkeys(sigterm.threads, OTHER)


def test_sigterm_ends_the_run_like_sigint(sigterm: Ended) -> None:
    assert sigterm.events[-1]["event"] == "stop", sigterm.events[-1]
    assert "log:" in sigterm.stdout


# --------------------------------------------------------------------------- without real-time priorities


def test_no_rt_pins_node_threads_but_leaves_them_at_sched_other(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(MIXED_SPEC, tmp_path, 2)
    duration = 4.0
    harness.start(table, "--no-rt", "--demo", "--start", "spec", duration=duration)
    scheduled = [node for node in MIXED_COMPUTE if node != "imu"]  # --demo starts the scheduled nodes
    threads = harness.registered(scheduled)
    assert harness.helpers, "the planner"
    assert not [pid for pid in harness.helpers if "watchdog" in cmdline(pid)]  # nothing to put back after a SIGKILL
    own = [sched_of(harness.pid, tid) for tid in threads_of(harness.pid)]
    assert all(sched is not None and sched.policy == os.SCHED_OTHER for sched in own), own  # nor its own threads
    plan = of_kind(harness.events(), "start")[0]["plan"]
    subchains = table_subchains(table)
    time.sleep(0.5)
    for _ in range(20):
        for node, sched in sample(threads).items():
            _, cpus = expected_sched(node, plan, subchains)
            assert sched == Sched(os.SCHED_OTHER, 0, cpus), f"{node}: {sched}"
        time.sleep(0.05)
    assert harness.wait(duration + WAIT_S) == 0
    events = harness.events()
    end = of_kind(events, "stop")[0]["t"]
    for name in subchains:  # rates are still enforced (no bound: CFS gives no guarantee)
        assert len(runs_of(events, name, 0.0, end)) >= 10, name


def nobody_run(
    nobody: tuple[int, int], folder: Path, tmp_path: Path, *options: str
) -> subprocess.CompletedProcess[str]:
    """``catanc run`` of the mixed app as ``nobody``, without privileges, its files in ``folder``."""
    table = folder / "runtime.json"
    if not table.exists():
        shutil.copyfile(compile_table(MIXED_SPEC, tmp_path, 2), table)
        table.chmod(0o644)
    argv = [*as_user(*nobody, rtprio=0), sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet"]
    argv += ["--socket", str(folder / "s.sock"), "--log", str(folder / "log.jsonl"), *options]
    return subprocess.run(
        argv,
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
        cwd="/",
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        start_new_session=True,
    )


def test_without_privilege_catanc_run_exits_4_and_says_why(
    nobody: tuple[int, int], shared_folder: Path, tmp_path: Path
) -> None:
    refused = nobody_run(nobody, shared_folder, tmp_path, "--duration", "1")
    assert refused.returncode == ExitCode.NO_PRIVILEGE, refused.stderr
    assert int(ExitCode.NO_PRIVILEGE) == 4  # as docs/reference/spec.md documents
    assert f"cannot use SCHED_FIFO priority {ENFORCER_FIFO}" in refused.stderr
    assert "catanc run --no-rt" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert not (shared_folder / "log.jsonl").exists()  # refused before it started anything


def test_without_privilege_no_rt_runs(nobody: tuple[int, int], shared_folder: Path, tmp_path: Path) -> None:
    probe = subprocess.run(
        [
            *as_user(*nobody, rtprio=0),
            sys.executable,
            "-c",
            "import subprocess, sys; subprocess.run([sys.executable, '-c', ''])",
        ],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
        cwd="/",
    )
    if probe.returncode != 0:  # e.g. a Python under /root: setpriv's own exec may still reach it, nobody's cannot
        pytest.skip(f"nobody cannot start {sys.executable}: {(probe.stderr.strip().splitlines() or ['?'])[-1]}")
    allowed = nobody_run(nobody, shared_folder, tmp_path, "--no-rt", "--demo", "--start", "spec", "--duration", "2")
    assert allowed.returncode == 0, allowed.stderr
    events = read_log(shared_folder / "log.jsonl")
    assert {e["node"] for e in of_kind(events, "register")} == {"cam", "track", "map", "plan"}
    assert of_kind(events, "run")


# One core, six subchains of 100 ms each at f = 1: T ~ 630 ms, a slot boundary every ~100 ms.
LONG_PERIOD_SPEC = """\
catan: 1
app: long
nodes:
  n1: {compute_ms: 100}
  n2: {compute_ms: 100}
  n3: {compute_ms: 100}
  n4: {compute_ms: 100}
  n5: {compute_ms: 100}
  n6: {compute_ms: 100}
subchains: {s1: [n1], s2: [n2], s3: [n3], s4: [n4], s5: [n5], s6: [n6]}
objective:
  - {chains: {}, weight: 1}
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""


def full_pipe() -> tuple[int, int]:
    """A pipe whose buffer is full: the first write to its write end blocks until the read end is read."""
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    with contextlib.suppress(BlockingIOError):
        while True:
            os.write(write_end, b"x" * 4096)
    os.set_blocking(write_end, True)
    return read_end, write_end


def drain(fd: int, timeout: float = WAIT_S) -> None:
    """Read ``fd`` until end of file (its writers exited); fails after ``timeout``."""
    deadline = time.monotonic() + timeout
    os.set_blocking(fd, False)
    while time.monotonic() < deadline:
        try:
            if not os.read(fd, 1 << 16):
                return
        except BlockingIOError:
            time.sleep(0.01)
    pytest.fail(f"the enforcer's stdout still open {timeout} s later")


def test_the_end_of_a_run_leaves_no_thread_raised_and_no_traceback(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(LONG_PERIOD_SPEC, tmp_path, 1)
    period_s = json.loads(table.read_text())["plan"]["cores"][0]["period_ms"] / 1000.0
    assert period_s > 0.5
    # Stop ~50 ms into a period: the core scheduler has most of it still to run when the run ends.
    duration = -(-1.5 // period_s) * period_s + 0.05
    read_end, write_end = full_pipe()  # the summary catanc prints at the end waits until the test reads
    try:
        harness.start(table, "--start", "spec", duration=duration, stdout=write_end)
    finally:
        os.close(write_end)
    try:
        nodes = [f"n{i}" for i in range(1, 7)]
        for node in nodes:
            harness.lingering(node, 100.0)
        threads = harness.registered(nodes)
        poll(lambda: of_kind(harness.events(), "stop"), "the run's end")  # logged just before the restore
        time.sleep(period_s)  # catanc is blocked writing its summary: its core scheduler is not
        drain(read_end)
    finally:
        os.close(read_end)
    assert harness.wait() == 0
    assert {node: str(sched) for node, sched in sample(threads).items()} == dict.fromkeys(threads, str(OTHER))
    assert "Traceback" not in harness.stderr()


# --------------------------------------------------------------------------- cores coming and going


def test_a_core_count_change_re_plans_and_re_pins(harness: Harness, tmp_path: Path) -> None:
    """`catanc set-cores 1` mid-run: Stage I again for one core, and every node thread ends up on CPU 0."""
    table = compile_table(MIXED_SPEC, tmp_path, 2)
    harness.start(table, "--start", "spec", duration=6.0)
    scheduled = [node for node in MIXED_COMPUTE if node != "imu"]
    for node in scheduled:
        harness.worker({node: MIXED_COMPUTE[node]})
    threads = harness.registered(scheduled)
    before = {node: sched_of(pid, tid) for node, (pid, tid) in threads.items()}
    assert {1} <= {cpu for sched in before.values() if sched is not None for cpu in sched.cpus}  # both cores used
    command = [sys.executable, "-m", "catanc", "set-cores", "1", "--socket", str(harness.socket)]
    changed = subprocess.run(command, capture_output=True, text=True, timeout=WAIT_S, check=False)
    assert changed.returncode == 0, changed.stderr

    def re_planned() -> Event | None:
        return next((e for e in of_kind(harness.events(), "resolve") if e["reason"] == "cores"), None)

    event = poll(re_planned, "a re-plan for the new core count", timeout=5.0)
    assert event["stage1"] is True
    assert event["plan"]["cores"] == 1
    assert all(sub["cores"] == [0] for sub in event["plan"]["subchains"].values())

    wait_all_pinned_to(threads, 0)
    assert harness.wait(6.0 + WAIT_S) == 0


def test_plan_cores_are_the_cpus_the_enforcer_may_use(harness: Harness, tmp_path: Path) -> None:
    """Confined to CPU 1 (a cpuset, `taskset -c 1`), a one-core plan's core 0 is CPU 1, not CPU 0."""
    if missing_tools("taskset"):
        pytest.skip("needs taskset")
    table = compile_table(MIXED_SPEC, tmp_path, 1)
    harness.start(table, "--start", "spec", duration=3.0, prefix=["taskset", "-c", "1"])
    scheduled = [node for node in MIXED_COMPUTE if node != "imu"]
    for node in scheduled:
        harness.worker({node: MIXED_COMPUTE[node]})
    threads = harness.registered(scheduled)

    wait_all_pinned_to(threads, 1)
    assert harness.wait(3.0 + WAIT_S) == 0


def test_a_table_compiled_for_other_cpus_runs_its_cores_there(harness: Harness, tmp_path: Path) -> None:
    """``compile --cpus 1``: a one-core plan's core 0 is CPU 1 though CPUs 0 and 1 are both allowed."""
    table = compile_table(MIXED_SPEC, tmp_path, 1, cpus=(1,))
    harness.start(table, "--start", "spec", duration=3.0)
    scheduled = [node for node in MIXED_COMPUTE if node != "imu"]
    for node in scheduled:
        harness.worker({node: MIXED_COMPUTE[node]})
    threads = harness.registered(scheduled)

    wait_all_pinned_to(threads, 1)
    assert harness.wait(3.0 + WAIT_S) == 0


def test_losing_a_cpu_re_plans_for_the_cores_left(harness: Harness, tmp_path: Path) -> None:
    """The enforcer's CPU set shrinks mid-run (`taskset -a -p -c 0`, as a cpuset change would): Stage I for one core."""
    if missing_tools("taskset"):
        pytest.skip("needs taskset")
    table = compile_table(MIXED_SPEC, tmp_path, 2)
    harness.start(table, "--start", "spec", duration=6.0)
    scheduled = [node for node in MIXED_COMPUTE if node != "imu"]
    for node in scheduled:
        harness.worker({node: MIXED_COMPUTE[node]})
    threads = harness.registered(scheduled)
    shrink = ["taskset", "-a", "-p", "-c", "0", str(harness.pid)]
    subprocess.run(shrink, capture_output=True, text=True, timeout=WAIT_S, check=True)

    def re_planned() -> Event | None:
        return next((e for e in of_kind(harness.events(), "resolve") if e["reason"] == "cores"), None)

    event = poll(re_planned, "a re-plan for the cores left", timeout=5.0)
    assert event["plan"]["cores"] == 1

    wait_all_pinned_to(threads, 0)
    assert harness.wait(6.0 + WAIT_S) == 0


# --------------------------------------------------------------------------- multi-threaded nodes

# One subchain of one node on both cores.  With 2 threads at speedup 1.8 a run takes 20 / 1.8 =
# 11.1 ms against 20 ms on one, so Eq. 1 picks q = 2: period 11.1 ms, kept 5% idle (the default
# slack): 11.1 / 0.95 = 11.7 ms (85.5 Hz), and triggers say `threads: 2`.  The worker burns 11.1 ms
# of CPU on each of two threads.  The re-solve
# at 2 s must plan with the one-thread 20 ms (the measured 11.1 ms times the speedup); planning
# with the raw 11.1 ms would shrink the period to 11.1 / 1.8 = 6.2 ms, which no run can meet.
THREADED_SPEC = """\
catan: 1
app: threaded
nodes:
  solve: {compute_ms: 20, threads: {max: 2, speedup: [1.0, 1.8]}}
subchains: {solve: [solve]}
objective:
  - {node: solve, weight: 1.0}
runtime: {first_solve_after_s: 2, stage2_every_s: 1, stage1_every_s: 100}
"""
THREADED_ONE_THREAD_MS = 20.0
THREADED_SPEEDUP = 1.8


def test_a_multi_threaded_node_runs_on_its_threads_and_is_planned_with_its_one_thread_time(
    harness: Harness, tmp_path: Path
) -> None:
    table = compile_table(THREADED_SPEC, tmp_path, 2)
    planned = table_subchains(table)["solve"]
    run_ms = THREADED_ONE_THREAD_MS / THREADED_SPEEDUP
    assert planned["threads"] == 2
    assert planned["period_ms"] == pytest.approx(run_ms / 0.95, rel=1e-6)  # Eq. 1 with the slack, by hand
    duration = 6.0
    harness.start(table, "--start", "spec", duration=duration)
    worker = harness.worker({"solve": THREADED_ONE_THREAD_MS}, speedups={"solve": (1.0, THREADED_SPEEDUP)})
    harness.registered(["solve"])
    poll(lambda: len(threads_of(worker.pid)) >= 3 or None, "the worker's helper thread")  # main, node, helper
    assert harness.wait(duration + WAIT_S) == 0
    events = harness.events()

    computes = [e["ms"] for e in of_kind(events, "compute") if e["node"] == "solve" and e["ms"] is not None]
    assert len(computes) > 50
    median = sorted(computes)[len(computes) // 2]
    # One-thread time: ~20 ms, more when the enforcer's FIFO-4 threads preempt a burning thread
    # (wall time); unconverted it would be ~11-13 ms.  Only the lower bound tells them apart.
    assert median >= 0.85 * THREADED_ONE_THREAD_MS, f"compute logged as {median} ms"
    latencies = sorted(e["latency_ms"] for e in of_kind(events, "run") if e["subchain"] == "solve")
    typical = latencies[len(latencies) // 2]
    serial_ms = 2 * run_ms  # the two threads' 11.1 ms burns one after the other, on one core
    assert 0.9 * run_ms <= typical <= 0.9 * serial_ms, f"a run took {typical} ms: not in parallel"
    resolves = of_kind(events, "resolve")
    assert resolves, "no re-solve"
    for resolve in resolves:  # a p95 of wall times: above the median under load, never near the raw 11.1 ms
        assert resolve["compute_ms"]["solve"] >= 0.85 * THREADED_ONE_THREAD_MS
        assert resolve["plan"]["subchains"]["solve"]["period_ms"] >= 0.85 * run_ms


# A node thread that starts a helper thread on its first run, after the enforcer raised it: the
# helper inherits SCHED_FIFO and the node's CPUs.  Both live on after the run ends.
SPAWNING_NODE = """\
import sys, threading, time
from catanc.client import Node
from catanc.runtime.worker.burn import burn

import os
name, socket_path = sys.argv[1], sys.argv[2]
own = threading.Thread(target=time.sleep, args=(60,), daemon=True)  # the app's own real-time thread
own.start()
os.sched_setscheduler(own.native_id, os.SCHED_FIFO, os.sched_param(3))
with Node(name, socket_path=socket_path) as node:
    for seq, _trigger in enumerate(node):
        if seq == 0:
            threading.Thread(target=time.sleep, args=(60,), daemon=True).start()
        burn(5)
        node.done()
time.sleep(60)
"""


def test_threads_a_node_starts_while_raised_are_put_back_too(harness: Harness, tmp_path: Path) -> None:
    table = compile_table(THREADED_SPEC, tmp_path, 2)
    harness.start(table, "--start", "spec", duration=4.0)
    node = harness.node([sys.executable, "-c", SPAWNING_NODE, "solve", str(harness.socket)])
    ((pid, tid),) = harness.registered(["solve"]).values()

    def others() -> dict[int, Sched | None] | None:
        found = {t: sched_of(pid, t) for t in threads_of(pid) if t not in (pid, tid)}
        return found if len(found) >= 2 else None

    during = poll(others, "the app's own thread and the node's helper")
    own = [t for t, found in during.items() if found is not None and found.priority == UNSCHEDULED_FIFO]
    helpers = [t for t in during if t not in own]
    assert len(own) == 1, during
    assert all(during[t] == Sched(os.SCHED_FIFO, RUNNING_FIFO, BOTH) for t in helpers), during  # inherited
    assert harness.wait() == 0
    assert node.poll() is None  # still there, as an app's process would be
    assert [sched_of(pid, helper) for helper in [tid, *helpers]] == [OTHER] * (1 + len(helpers))
    assert [sched_of(pid, t) for t in own] == [Sched(os.SCHED_FIFO, UNSCHEDULED_FIFO, MINE)]  # older: not adopted
