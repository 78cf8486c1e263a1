"""``catanc run --launch`` and ``--attach`` on the real kernel, and the enforcer's CPU set growing mid-run.

Each test compiles a small spec into its folder and starts the enforcer as ``python -m catanc run``
would (``--socket`` and ``--log`` in the test's folders, ``--start spec`` so that the first plan is
the table's), as in tests/runtime/test_enforcer.py.  The app processes are the enforcer's own here:

- ``--launch`` starts the spec's ``deploy`` commands, which ``catanc compile`` writes into the
  runtime table as ``processes[].argv``.  The commands start :mod:`catanc.runtime.worker` without
  ``--socket``: a worker finds the enforcer through ``$CATANC_SOCKET``, which ``--launch`` sets.
  ``cam`` and ``track`` share the ROS node ``/front``, so one process hosts both (as nav2d's
  Operator hosts LM and LP); ``imu`` has no deploy entry and is not started.
- ``--attach NODE=PID`` takes a plain process started here that does not speak the protocol
  (:data:`PLAIN_APP`: two threads, each burning 1 ms every 10 ms).

What each thread runs at is read from ``/proc`` (:func:`tests.support.linux.sched_of`), never through
catanc; what the enforcer planned comes from its JSON-lines log (flushed once a second).  Every
process a test's enforcer starts inherits a marker in its environment (:data:`MARK_ENV`), so
"nothing left running" means: no live process on the machine carries the marker.  At teardown the
test's processes are SIGKILLed, the app's first, then the enforcer, then its watchdog and planner.

The tests that run the enforcer skip with the reason when SCHED_FIFO is not permitted or CPUs 0
and 1 are not both allowed; the ``--attach`` usage errors need neither.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from catanc.errors import ExitCode
from catanc.model.priorities import RUNNING_FIFO, SHARED_FIFO, UNSCHEDULED_FIFO
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
from catanc.runtime.protocol.messages import SOCKET_ENV
from catanc.runtime.worker.command import worker_command
from tests.support.enforcer_runs import ENFORCER_MAIN, EnforcerRun, Event, cmdline, compile_table, kill_groups, of_kind
from tests.support.linux import (
    BOTH_CPUS,
    WAIT_S,
    Sched,
    alive,
    missing_tools,
    poll,
    sched_of,
    stat_fields,
    threads_of,
)

WATCH_S = 0.6  # how long a test samples the app's threads mid-run
MINE = frozenset(os.sched_getaffinity(0))
MARK_ENV = "CATANC_TEST_RUN"  # set in the enforcer's environment: every process it starts inherits it
SPEC_PATH = Path(__file__).resolve().parents[2] / "specs" / "nav2d.yaml"

# Two cores: `front` (cam + track, 18 ms, capped at 25 Hz) alone on core 0 at FIFO 2; `map` and
# `plan` sharing core 1 (FIFO 1, raised to 2 for their slices); `imu` unscheduled (FIFO 3, every
# core).  On one core all three subchains share core 0.  No re-solve during a test.
SPEC = """\
catan: 1
app: procs
nodes:
  imu: {scheduled: false, rate_hz: 100}
  cam: {compute_ms: 10}
  track: {compute_ms: 8}
  map: {compute_ms: 12}
  plan: {compute_ms: 15}
edges: [[imu, track], [cam, track], [track, map], [map, plan]]
subchains: {front: [cam, track], map: [map], plan: [plan]}
objective:
  - {chain: [cam, track], weight: 1.0}
  - {node: map, weight: 0.3}
  - {node: plan, weight: 0.1}
constraints:
  - {node: cam, max_rate_hz: 25}
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""
SUBCHAINS = {"front": ("cam", "track"), "map": ("map",), "plan": ("plan",)}
LAUNCHED = ("cam", "track", "map", "plan")  # the nodes with a deploy command


def worker_line(nodes: dict[str, float]) -> str:
    """A deploy ``command`` starting a worker for ``nodes``; it reads the socket from ``$CATANC_SOCKET``."""
    return shlex.join(worker_command(nodes))


DEPLOY: dict[str, dict[str, str]] = {
    "cam": {"ros_node": "/front", "command": worker_line({"cam": 10.0, "track": 8.0})},
    "track": {"ros_node": "/front"},
    "map": {"command": worker_line({"map": 12.0})},
    "plan": {"command": worker_line({"plan": 15.0})},
}
MISSING = "/nonexistent/catanc-test/plan_node"
BROKEN_DEPLOY = {**DEPLOY, "plan": {"command": f"{MISSING} --rate 10"}}

# A process that knows nothing of catanc: two threads, each burning 1 ms of CPU every 10 ms.
PLAIN_APP = """\
import threading, time

def work():
    while True:
        end = time.thread_time() + 0.001
        while time.thread_time() < end:
            pass
        time.sleep(0.01)

threading.Thread(target=work, daemon=True).start()
work()
"""


# --------------------------------------------------------------------------- tables


def with_deploy(deploy: Mapping[str, Mapping[str, str]]) -> str:
    return SPEC + "deploy: " + json.dumps(deploy) + "\n"  # a JSON object is YAML flow style


@pytest.fixture(scope="module")
def launch_table(tmp_path_factory: pytest.TempPathFactory) -> Path:
    table = compile_table(with_deploy(DEPLOY), tmp_path_factory.mktemp("launch"), 2)
    processes = json.loads(table.read_text())["processes"]
    assert {p["key"]: p["nodes"] for p in processes if p["argv"]} == {
        "/front": ["cam", "track"],
        "map": ["map"],
        "plan": ["plan"],
    }
    return table


@pytest.fixture(scope="module")
def one_core_table(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_table(with_deploy(DEPLOY), tmp_path_factory.mktemp("one-core"), 1)


@pytest.fixture(scope="module")
def broken_table(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_table(with_deploy(BROKEN_DEPLOY), tmp_path_factory.mktemp("broken"), 2)


@pytest.fixture(scope="module")
def nav2d_table(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_table(SPEC_PATH.read_text(), tmp_path_factory.mktemp("nav2d"), 2)


REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: these tests need SCHED_FIFO up to it


# --------------------------------------------------------------------------- reading /proc and the log


def parent_and_group(pid: int) -> tuple[int, int]:
    fields = stat_fields(f"/proc/{pid}/stat")  # from field 3 on: ppid is field 4, pgrp field 5
    return int(fields[1]), int(fields[2])


def environment(pid: int) -> dict[str, str]:
    words = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace").split("\0")
    return dict(word.partition("=")[::2] for word in words if word)


def placement(node: str, plan: Mapping[str, Any], cpus: Sequence[int]) -> tuple[set[int], frozenset[int]]:
    """The SCHED_FIFO levels ``node``'s threads may show under ``plan``, and their CPUs.

    Plan core ``i`` is the ``i``-th CPU the enforcer may use (``cpus``, sorted).
    """
    for name, nodes in SUBCHAINS.items():
        if node in nodes:
            planned = plan["subchains"][name]
            levels = {SHARED_FIFO, RUNNING_FIFO} if planned["shared"] else {RUNNING_FIFO}
            return levels, frozenset(cpus[core % len(cpus)] for core in planned["cores"])
    return {UNSCHEDULED_FIFO}, frozenset(cpus[core % len(cpus)] for core in range(plan["cores"]))


def watch(threads: Mapping[str, Sequence[tuple[int, int]]], plan: Mapping[str, Any], seconds: float) -> None:
    """For ``seconds``, every ~20 ms: each node's threads run at its planned SCHED_FIFO level on its CPUs."""
    expected = {node: placement(node, plan, sorted(BOTH_CPUS)) for node in threads}
    deadline = time.monotonic() + seconds
    samples = 0
    while time.monotonic() < deadline:
        for node, tids in threads.items():
            levels, cpus = expected[node]
            for pid, tid in tids:
                found = sched_of(pid, tid)
                assert found is not None, f"{node}'s thread {tid} exited during the run"
                wanted = f"SCHED_FIFO {sorted(levels)} on {sorted(cpus)}"
                assert found.policy == os.SCHED_FIFO, f"{node} thread {tid}: {found}, expected {wanted}"
                assert found.priority in levels, f"{node} thread {tid}: {found}, expected {wanted}"
                assert found.cpus == cpus, f"{node} thread {tid}: {found}, expected {wanted}"
        samples += 1
        time.sleep(0.02)
    assert samples >= 5


# --------------------------------------------------------------------------- the processes


@dataclass
class Run(EnforcerRun):
    """One test's enforcer and the processes it started; :meth:`close` kills what is left of them."""

    mark: str = field(default_factory=lambda: uuid.uuid4().hex)
    plain: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def start(self, table: Path, *options: str, duration: float, prefix: Sequence[str] = ()) -> None:
        """Start ``catanc run`` (``prefix`` before it, e.g. taskset) with the run's marker in its environment."""
        argv = [*prefix, sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--start", "spec"]
        argv += ["--socket", str(self.socket), "--log", str(self.log), "--duration", str(duration), *options]
        env = {**os.environ, MARK_ENV: self.mark, "PYTHONDONTWRITEBYTECODE": "1"}
        with (self.folder / "enforcer.out").open("wb") as out, (self.folder / "enforcer.err").open("wb") as err:
            self.enforcer = subprocess.Popen(argv, stdout=out, stderr=err, env=env, start_new_session=True)

    def first(self, kind: str) -> Event:
        """The first ``kind`` event, once the log has it (the log is flushed once a second)."""
        return poll(lambda: next(iter(of_kind(self.events(), kind)), None), f"a {kind!r} event in the log")

    def plain_app(self) -> int:
        """Start :data:`PLAIN_APP` (not marked: the enforcer did not start it); its pid once both threads run."""
        proc = subprocess.Popen([sys.executable, "-c", PLAIN_APP], start_new_session=True)
        self.plain.append(proc)
        poll(lambda: len(threads_of(proc.pid)) == 2, "the plain app's two threads")
        return proc.pid

    def marked(self) -> list[int]:
        """Every live process on the machine with this run's marker: the enforcer and what it started."""
        tag = f"{MARK_ENV}={self.mark}".encode()
        found = []
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                environ = (entry / "environ").read_bytes()
            except OSError:
                continue
            if tag in environ.split(b"\0") and alive(int(entry.name)):
                found.append(int(entry.name))
        return sorted(found)

    def close(self) -> None:
        enforcer = self.enforcer.pid if self.enforcer is not None else None
        apps = [pid for pid in self.marked() if pid != enforcer and "watchdog" not in cmdline(pid)]
        apps += [proc.pid for proc in self.plain if proc.poll() is None]
        for pid in apps:  # the app first: none may be left at SCHED_FIFO without its enforcer
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        kill_groups([*self.plain, *([self.enforcer] if self.enforcer is not None else [])])
        for pid in self.marked():  # the watchdog and the planner
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(self.short, ignore_errors=True)


@pytest.fixture
def run(tmp_path: Path) -> Iterator[Run]:
    made = Run(tmp_path, Path(tempfile.mkdtemp(prefix="catanc-test-")))
    try:
        yield made
    finally:
        made.close()


def end(run: Run, how: str, duration: float) -> int:
    """End the run: wait for its ``duration`` to pass, or send the enforcer SIGINT (a Ctrl-C)."""
    if how == "sigint":
        os.kill(run.pid, signal.SIGINT)
        return run.wait()
    return run.wait(duration + WAIT_S)


def assert_nothing_left(run: Run) -> None:
    """No process of the run is left (so no thread of it at SCHED_FIFO): app, watchdog, planner."""

    def leftovers() -> dict[str, list[str]]:
        return {
            f"{pid} {cmdline(pid)[:80]}": [str(sched_of(pid, tid)) for tid in threads_of(pid)] for pid in run.marked()
        }

    deadline = time.monotonic() + 5.0
    while (left := leftovers()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not left, f"still running after the enforcer exited: {left}"


# --------------------------------------------------------------------------- --launch


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("how", ["duration", "sigint"])
def test_launch_runs_the_deploy_commands_and_stops_them_at_the_end(run: Run, launch_table: Path, how: str) -> None:
    duration = 2.5 if how == "duration" else 60.0
    run.start(launch_table, "--launch", duration=duration)
    threads = run.registered(LAUNCHED)
    assert "imu" not in {e["node"] for e in of_kind(run.events(), "register")}  # no deploy entry: not started
    assert threads["cam"][0] == threads["track"][0], "/front hosts cam and track: one process"
    launched = sorted({pid for pid, _ in threads.values()})
    assert len(launched) == 3
    for pid in launched:
        parent, group = parent_and_group(pid)
        assert parent == run.pid, f"{pid} ({cmdline(pid)}) was not started by the enforcer"
        assert group == pid, "a launched process has its own process group"
        assert environment(pid).get(SOCKET_ENV) == str(run.socket)  # the only way its command finds the enforcer

    plan = run.first("start")["plan"]
    watch({node: [thread] for node, thread in threads.items()}, plan, WATCH_S)
    returncode = end(run, how, duration)
    assert returncode == ExitCode.OK, run.stderr()
    assert "Traceback" not in run.stderr()
    gone = [pid for pid in launched if not alive(pid)]
    assert gone == launched, "the enforcer stopped every process it launched before it exited"
    events = run.events()
    assert events[-1]["event"] == "stop"
    counts = {name: len([e for e in of_kind(events, "run") if e["subchain"] == name]) for name in SUBCHAINS}
    assert min(counts.values()) >= 10, f"runs per subchain: {counts}"
    assert not of_kind(events, "gone"), "no node thread exited before the end"
    assert_nothing_left(run)


@pytest.mark.usefixtures("real_kernel")
def test_a_deploy_command_that_does_not_exist_exits_2_and_leaves_nothing_running(run: Run, broken_table: Path) -> None:
    """`plan`'s command does not exist: `/front` and `map`, started before it, are stopped again."""
    run.start(broken_table, "--launch", duration=30.0)
    returncode = run.wait()
    stderr = run.stderr()
    assert returncode == ExitCode.BAD_INPUT, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("catanc: cannot start plan"), stderr
    assert MISSING in lines[0]
    assert "No such file or directory" in lines[0]
    assert_nothing_left(run)


@pytest.mark.usefixtures("real_kernel")
def test_a_failed_launch_puts_an_attached_process_back(run: Run, broken_table: Path) -> None:
    """`--attach map=PID --launch` where a deploy command does not exist: the attached threads end as they began."""
    as_map = run.plain_app()
    threads = threads_of(as_map)
    before = {tid: str(sched_of(as_map, tid)) for tid in threads}
    run.start(broken_table, "--attach", f"map={as_map}", "--launch", duration=30.0)
    assert run.wait() == ExitCode.BAD_INPUT, run.stderr()
    assert_nothing_left(run)
    time.sleep(0.2)
    assert {tid: str(sched_of(as_map, tid)) for tid in threads} == before
    assert [e["event"] for e in run.events()][-1:] == ["stop"], "the log ends with the run's stop"


# --------------------------------------------------------------------------- --attach


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("how", ["duration", "sigint"])
def test_attach_gives_a_plain_process_the_nodes_placement_and_puts_it_back(
    run: Run, launch_table: Path, how: str
) -> None:
    """Two plain processes attached as `map` (shared core 1) and `imu` (unscheduled, every core)."""
    as_map, as_imu = run.plain_app(), run.plain_app()
    # Not the defaults, so that putting back is seen: each second thread at SCHED_BATCH on one CPU.
    for pid, cpu in ((as_map, 0), (as_imu, 1)):
        second = threads_of(pid)[1]
        os.sched_setscheduler(second, os.SCHED_BATCH, os.sched_param(0))
        os.sched_setaffinity(second, {cpu})
    nodes = {"map": as_map, "imu": as_imu}
    threads = {node: [(pid, tid) for tid in threads_of(pid)] for node, pid in nodes.items()}
    before = {tid: sched_of(pid, tid) for tids in threads.values() for pid, tid in tids}
    assert sorted(str(s) for s in before.values()) == sorted(
        [str(Sched(os.SCHED_OTHER, 0, MINE))] * 2 + ["BATCH 0 on [0]", "BATCH 0 on [1]"]
    )

    duration = 2.5 if how == "duration" else 60.0
    run.start(launch_table, "--attach", f"map={as_map}", "--attach", f"imu={as_imu}", duration=duration)
    plan = run.first("start")["plan"]
    assert plan["subchains"]["map"] == {**plan["subchains"]["map"], "cores": [1], "shared": True}
    watch(threads, plan, WATCH_S)
    returncode = end(run, how, duration)
    assert returncode == ExitCode.OK, run.stderr()
    assert "Traceback" not in run.stderr()
    after = {tid: sched_of(pid, tid) for tids in threads.values() for pid, tid in tids}
    assert {tid: str(s) for tid, s in after.items()} == {tid: str(s) for tid, s in before.items()}
    assert [pid for pid in (as_map, as_imu) if alive(pid)] == [as_map, as_imu], "not the enforcer's to stop"
    assert run.events()[-1]["event"] == "stop"
    assert_nothing_left(run)


@pytest.mark.parametrize(
    ("item", "reason"),
    [
        ("LM", "--attach 'LM': expected NODE=PID"),
        ("nosuch=123", "--attach 'nosuch=123': no node 'nosuch' in app nav2d"),
        ("LM=999999999", "--attach 'LM=999999999': no process 999999999"),
    ],
)
def test_a_bad_attach_exits_2_with_a_one_line_error(run: Run, nav2d_table: Path, item: str, reason: str) -> None:
    run.start(nav2d_table, "--attach", item, duration=5.0)
    returncode = run.wait()
    stderr = run.stderr()
    assert returncode == ExitCode.BAD_INPUT, stderr
    assert stderr.strip().splitlines() == [stderr.strip()], stderr
    assert stderr.startswith(f"catanc: {reason}"), stderr
    assert not run.log.exists(), "refused before it started anything"
    assert_nothing_left(run)


# --------------------------------------------------------------------------- the CPU set changing


def set_cpus_of_every_thread(pid: int, cpus: frozenset[int]) -> None:
    """What `taskset -a -p` (or a cpuset change) does: every thread of ``pid`` may run on ``cpus``."""
    for tid in threads_of(pid):
        with contextlib.suppress(ProcessLookupError):
            os.sched_setaffinity(tid, cpus)
    assert {frozenset(os.sched_getaffinity(tid)) for tid in threads_of(pid)} == {cpus}


def pinned_as(threads: Mapping[str, tuple[int, int]], plan: Mapping[str, Any], cpus: Sequence[int]) -> None:
    """Wait (2.5 s at most) until each node thread runs on its CPUs under ``plan`` (plan core i = ``cpus[i]``)."""
    expected = {node: placement(node, plan, cpus)[1] for node in threads}

    def check() -> bool:
        return all((s := sched_of(*threads[node])) is not None and s.cpus == want for node, want in expected.items())

    try:
        poll(check, "every node thread pinned as planned", timeout=2.5)
    except pytest.fail.Exception:
        found = {node: str(sched_of(*thread)) for node, thread in threads.items()}
        wanted = {node: sorted(cpus) for node, cpus in expected.items()}
        pytest.fail(f"node threads: {found}; planned CPUs: {wanted}")


def needs_taskset() -> None:
    if missing_tools("taskset"):
        pytest.skip("needs taskset")


@pytest.mark.usefixtures("real_kernel")
def test_gaining_a_cpu_after_starting_on_one_core_re_plans_for_two(run: Run, launch_table: Path) -> None:
    """On CPU 1 with `--cores 1`, then CPUs 0 and 1: Stage I again for two cores, and re-pinning."""
    needs_taskset()
    run.start(launch_table, "--launch", "--cores", "1", duration=8.0, prefix=["taskset", "-c", "1"])
    threads = run.registered(LAUNCHED)
    start = run.first("start")["plan"]
    assert start["cores"] == 1
    pinned_as(threads, start, [1])
    set_cpus_of_every_thread(run.pid, BOTH_CPUS)

    def re_planned() -> Event | None:
        return next((e for e in of_kind(run.events(), "resolve") if e["reason"] == "cores"), None)

    event = poll(re_planned, "a re-plan for the CPUs gained", timeout=5.0)
    assert event["stage1"] is True
    assert event["error"] is None
    assert event["plan"]["cores"] == 2
    assert event["allocation_changed"] is True
    pinned_as(threads, event["plan"], sorted(BOTH_CPUS))
    watch({node: [thread] for node, thread in threads.items()}, event["plan"], 0.5)
    assert end(run, "sigint", 0.0) == ExitCode.OK
    assert [e["reason"] for e in of_kind(run.events(), "resolve")] == ["cores"]
    assert_nothing_left(run)


@pytest.mark.usefixtures("real_kernel")
def test_gaining_a_cpu_re_plans_a_two_core_table_for_two_cores(run: Run, launch_table: Path) -> None:
    """A two-core table, the enforcer on CPU 1 alone, then on CPUs 0 and 1: a re-plan for two cores."""
    needs_taskset()
    run.start(launch_table, "--launch", duration=8.0, prefix=["taskset", "-c", "1"])
    threads = run.registered(LAUNCHED)
    start = run.first("start")["plan"]
    on_cpu_1 = {node: str(sched_of(*thread)) for node, thread in threads.items()}
    assert start["cores"] == 1, f"a {start['cores']}-core plan on CPU 1 alone: {on_cpu_1}"
    set_cpus_of_every_thread(run.pid, BOTH_CPUS)

    def re_planned() -> Event | None:
        return next((e for e in of_kind(run.events(), "resolve") if e["reason"] == "cores"), None)

    event = poll(re_planned, "a re-plan for the CPUs gained", timeout=3.0)
    assert event["plan"]["cores"] == 2
    pinned_as(threads, event["plan"], sorted(BOTH_CPUS))


@pytest.mark.usefixtures("real_kernel")
def test_moving_to_another_cpu_re_pins_every_node(run: Run, one_core_table: Path) -> None:
    """A one-core plan on CPU 1, then the enforcer moved to CPU 0 (a cpuset change): the nodes follow it."""
    needs_taskset()
    run.start(one_core_table, "--launch", duration=8.0, prefix=["taskset", "-c", "1"])
    threads = run.registered(LAUNCHED)
    plan = run.first("start")["plan"]
    pinned_as(threads, plan, [1])
    set_cpus_of_every_thread(run.pid, frozenset({0}))
    pinned_as(threads, plan, [0])  # the enforcer looks at its CPU set once a second


def test_a_run_that_cannot_bind_its_socket_lets_the_watchdog_go_quietly(run: Run, tmp_path: Path) -> None:
    """A second enforcer on a socket in use exits with the reason alone: it had started its watchdog, which
    must not report a death ("closed its pipe without restoring its threads") for a run that raised nothing."""
    table = compile_table(SPEC, tmp_path / "table", 1)
    run.start(table, duration=6.0)
    run.first("start")  # the first one's socket is up
    argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--loop", "python"]
    argv += ["--socket", str(run.socket), "--log", str(tmp_path / "second.jsonl"), "--duration", "1"]
    second = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    assert second.returncode == ExitCode.BAD_INPUT, second.stderr
    assert "another catanc enforcer is running" in second.stderr
    assert "watchdog" not in second.stderr, second.stderr
    os.kill(run.pid, signal.SIGINT)
    assert run.wait() == ExitCode.OK
