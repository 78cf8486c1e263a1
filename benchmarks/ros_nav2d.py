"""The paper's nav2d as a real rclpy app (examples/ros/nav2d) under plain ROS 2 and under catanc, side by side.

    python -m benchmarks.ros_nav2d                      # plain and catanc, 1 and 2 cores, 30 s each
    python -m benchmarks.ros_nav2d --duration 10 --cores 1 --json
    python -m benchmarks.ros_nav2d --dds-other           # the middleware's threads left at SCHED_OTHER

Each case runs the example as its README says, from a scratch copy of its folder, with the robot
(``robot_sim.py``: odometry, and the base that records each command; at SCHED_FIFO 3 as root, as
docs/explanation/model.md section 6 runs unscheduled nodes, in every mode), all pinned to the case's CPUs
(``taskset``; plan core ``i`` is CPU ``i``, or ``--first-cpu`` + ``i``):

- **plain**: ``bash plain.sh CPUS``: every node on its own timer at the spec's baseline rates,
  Linux's default scheduling;
- **catanc**: ``catanc run out/cores-K/runtime.json --launch --start spec``: the spec's deploy
  commands, scheduled by the enforcer on the real kernel (root: SCHED_FIFO).

Once every node has run and the base receives commands the run warms up for ``--warmup`` s, then
is measured for ``--duration`` s from the nodes' own run records (``$NAV2D_RECORD_DIR``,
CLOCK_REALTIME, the clock of the messages' stamps):

- the local chain's response, scan stamp to the base's receipt of the command it led to (p50,
  p95, max; every command counts, a re-sent old one with its age), and to LP's command;
- the chain ``GL -> NC -> LP`` to LP's command: LP's run end minus the origin of the navigation
  command it used (GL's newest scan);
- the hops scan -> LM (between processes) and LM -> LP (inside the Operator): a producer's end to
  the consumer's start on the same scan;
- each subchain's rate (its last node's runs per second) against the plan: the baseline's rate
  for plain; for catanc the rate the enforcer's plans promised over the window (the log's last
  ``--duration`` seconds), each plan for as long as it was in force;
- stale runs: runs of a later node of the local subchain whose input is older than the head's
  newest run before them (``scan`` ended before LM's / LP's run started, with a newer stamp), in the
  window, and over the whole run beside it (the start-up included);
- for catanc: late runs (the enforcer's counters, whole run, and within the window: from its
  per-second status counters and the runs it logged between them) and the enforcer's CPU (every thread
  of the ``catanc run`` process over the window, /proc schedstat; its planner and watchdog
  processes not counted), with its own figures (share, hop inside a subchain) from its log.

``--dds-other`` is an experiment: once the app runs, it puts every middleware thread (``dds.*``) of
the app's processes back to SCHED_OTHER on all the case's CPUs, undoing what the enforcer gave them
(the level of nodes on their own clock, on their process's CPUs: docs/guide/ros2.md), to see what
that buys the hops between processes.  Plain ROS 2 leaves them there anyway.

The targets (issue 46; reported, never asserted): on 1 core catanc's local-chain p95 at least 3x
lower than plain ROS 2's; on 2 cores every bounded chain's p95 within its bound (nav2d bounds
none) and every subchain's rate within 5% of the plan.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from benchmarks.enforcer import load, process_cpu_ns
from catanc.control.measure import percentile
from catanc.control.run_summary import PlannedRate, summarise
from catanc.runtime.linux.sched import MIDDLEWARE_THREADS, thread_name, threads_of
from catanc.runtime.logs.writer import read_log

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ros" / "nav2d"
MODES = ("plain", "catanc", "launch.sh")
BENCHMARK_MODES = ("plain", "catanc")
RECORD_ENV = "NAV2D_RECORD_DIR"  # as examples/ros/nav2d/nav2d_common.py reads it
LOCAL_SUBCHAIN = ("scan", "LM", "LP")
APP_NODES = ("scan", "LM", "LP", "GL", "GM", "GP", "NC")
SUBCHAIN_LAST = {  # each subchain's last node: its runs are the subchain's
    "local": "LP",
    "GL": "GL",
    "GM": "GM",
    "GP": "GP",
    "NC": "NC",
}
READY_COMMANDS = 5
START_TIMEOUT_S = 120.0  # a loaded 2-core machine takes ~10 s to start the five processes
STOP_GRACE_S = 15.0
POLL_S = 0.2
ROBOT_PRIORITY = 3

Record = dict[str, Any]


@dataclass(frozen=True)
class Spread:
    """p50, p95 and max of some milliseconds, and how many."""

    count: int
    p50_ms: float
    p95_ms: float
    max_ms: float


def spread(samples: Sequence[float]) -> Spread | None:
    if not samples:
        return None
    return Spread(len(samples), percentile(samples, 50), percentile(samples, 95), max(samples))


# --------------------------------------------------------------------------- running the app


def copy_example(into: Path) -> Path:
    """A scratch copy of the example's folder (its commands are relative to it, launch.sh logs into it)."""
    folder = into / "nav2d"
    shutil.copytree(EXAMPLE, folder, ignore=shutil.ignore_patterns("__pycache__", "*.jsonl"))
    return folder


def catanc_program() -> str:
    beside = Path(sys.executable).with_name("catanc")
    return str(beside) if beside.exists() else (shutil.which("catanc") or "catanc")


def app_environment(records: Path) -> dict[str, str]:
    """This environment (ROS domain and discovery included), with this interpreter's ``python3`` first on PATH."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env[RECORD_ENV] = str(records)
    env["CATANC"] = catanc_program()
    env["PYTHONUNBUFFERED"] = "1"
    return env


FIRST_CPU = [0]
"""The case's first CPU (``--first-cpu``): a case on ``cores`` cores runs on the CPUs from it on."""


def case_cpus(cores: int) -> range:
    return range(FIRST_CPU[0], FIRST_CPU[0] + cores)


def cpu_list(cores: int) -> str:
    return ",".join(str(cpu) for cpu in case_cpus(cores))


def robot_priority() -> list[str]:
    """The robot as catanc-model.md section 6 runs unscheduled nodes, SCHED_FIFO 3, in every mode (as root):
    a base starved behind the app would add its own wait to every chain it ends."""
    return ["chrt", "-f", str(ROBOT_PRIORITY)] if os.geteuid() == 0 else []


def launcher_argv(mode: str, cores: int, log: Path) -> list[str]:
    """The command the example's README gives for ``mode`` on ``cores`` cores (run in its folder)."""
    cpus = cpu_list(cores)
    table = f"out/cores-{cores}/runtime.json"
    if mode == "plain":
        return ["bash", "plain.sh", cpus]
    if mode == "catanc":
        socket = log.with_name("catanc.sock")  # its own: never another enforcer's (a test's) default one
        run = ["run", table, "--launch", "--start", "spec", "--quiet", "--log", str(log), "--socket", str(socket)]
        return ["taskset", "-c", cpus, catanc_program(), *run]
    if mode == "launch.sh":
        return ["bash", f"out/cores-{cores}/launch.sh"]
    raise ValueError(f"unknown mode {mode!r} (expected one of {', '.join(MODES)})")


@dataclass
class AppRun:
    """The robot and one launcher of the example, started in ``folder``; their output in ``output``."""

    folder: Path
    records: Path
    log: Path
    robot: subprocess.Popen[bytes]
    launcher: subprocess.Popen[bytes]
    output: Path

    def commands(self) -> list[Record]:
        """The base's commands so far that carry an origin."""
        return [row for row in read_records(self.records, "robot") if row.get("origin_ns") is not None]

    def missing(self, commands: int) -> list[str]:
        """The DAG nodes that have not run yet, and ``base`` until it has ``commands`` commands."""
        ran = {row["node"] for row in all_records(self.records)}
        short = ["base"] if len(self.commands()) < commands else []
        return [node for node in APP_NODES if node not in ran] + short

    def wait_ready(self, commands: int = READY_COMMANDS, timeout_s: float = START_TIMEOUT_S) -> None:
        """Until every node has run and the base has ``commands`` commands; RuntimeError (with the processes'
        output) if a process ends or that takes longer than ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while missing := self.missing(commands):
            ended = [name for name, process in self.processes() if process.poll() is not None]
            if ended or time.monotonic() > deadline:
                why = f"{', '.join(ended)} ended" if ended else f"{', '.join(missing)} not running in {timeout_s:.0f} s"
                raise RuntimeError(f"the app did not start: {why}\n{self.output_text()}")
            time.sleep(POLL_S)

    def processes(self) -> list[tuple[str, subprocess.Popen[bytes]]]:
        return [("launcher", self.launcher), ("robot", self.robot)]

    def output_text(self) -> str:
        return "\n".join(path.read_text(errors="replace")[-4000:] for path in sorted(self.output.glob("*.txt")))

    def stop(self) -> dict[str, int | None]:
        """Ctrl-C for each process group, as a terminal sends it; each one's exit status (None: killed)."""
        codes: dict[str, int | None] = {}
        launched = descendants(self.launcher.pid)  # catanc run --launch starts each in a session of its own
        for _, process in self.processes():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGINT)
        deadline = time.monotonic() + STOP_GRACE_S
        for name, process in self.processes():
            try:
                codes[name] = process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                codes[name] = None
        for _, process in self.processes():  # what is left of a group, the launched nodes included
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        for pid in launched:  # a node an enforcer killed here left behind: on its own timer, at SCHED_FIFO, for ever
            if str(self.folder) in _cmdline(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        return codes


@contextlib.contextmanager
def running(mode: str, cores: int, scratch: Path) -> Iterator[AppRun]:
    """The example in ``mode`` on CPUs ``0..cores-1``, from a copy in ``scratch``; stopped (SIGINT) on exit."""
    folder = copy_example(scratch)
    records = scratch / "records"
    output = scratch / "output"
    records.mkdir()
    output.mkdir()
    env = app_environment(records)
    log = scratch / "catanc-run.jsonl"
    robot_argv = ["taskset", "-c", cpu_list(cores), *robot_priority(), sys.executable, "robot_sim.py"]
    with (output / "robot.txt").open("wb") as robot_out, (output / "launcher.txt").open("wb") as launcher_out:
        robot = subprocess.Popen(
            robot_argv, cwd=folder, env=env, stdout=robot_out, stderr=subprocess.STDOUT, start_new_session=True
        )
        launcher = subprocess.Popen(
            launcher_argv(mode, cores, log),
            cwd=folder,
            env=env,
            stdout=launcher_out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    app = AppRun(
        folder, records, log if mode == "catanc" else folder / "catanc-run-nav2d.jsonl", robot, launcher, output
    )
    try:
        yield app
    finally:
        if any(process.poll() is None for _, process in app.processes()):
            app.stop()


def read_records(folder: Path, process: str) -> list[Record]:
    """One process's run records (a torn last line is skipped)."""
    path = folder / f"{process}.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        with contextlib.suppress(json.JSONDecodeError):
            rows.append(json.loads(line))
    return rows


def all_records(folder: Path) -> list[Record]:
    return [row for path in sorted(folder.glob("*.jsonl")) for row in read_records(folder, path.stem)]


# --------------------------------------------------------------------------- what the records say


def within(rows: Sequence[Record], start_ns: int, end_ns: int) -> list[Record]:
    """The runs that started in ``[start_ns, end_ns)``."""
    return [row for row in rows if start_ns <= row["start_ns"] < end_ns]


def of_node(rows: Sequence[Record], node: str) -> list[Record]:
    return [row for row in rows if row["node"] == node]


def local_chain_ms(rows: Sequence[Record]) -> list[float]:
    """Scan stamp to the base's receipt, per command."""
    return [(row["start_ns"] - row["origin_ns"]) / 1e6 for row in of_node(rows, "base") if row["origin_ns"] is not None]


def local_to_lp_ms(rows: Sequence[Record]) -> list[float]:
    """Scan stamp to LP's command (its run's end), per LP run: the local chain without the hop to the base."""
    return [(row["end_ns"] - row["origin_ns"]) / 1e6 for row in of_node(rows, "LP") if row["origin_ns"] is not None]


def navigation_chain_ms(rows: Sequence[Record]) -> list[float]:
    """GL's newest scan to LP's command, per LP run that used a navigation command."""
    return [(row["end_ns"] - row["nav_origin_ns"]) / 1e6 for row in of_node(rows, "LP") if row.get("nav_origin_ns")]


def hop_ms(rows: Sequence[Record], producer: str, consumer: str) -> list[float]:
    """``producer``'s end to ``consumer``'s start on the same data (same origin), per ``consumer`` run: the message's
    hop through DDS and the consumer's executor, plus (on its own timer) the wait for its next tick."""
    ends: dict[int, int] = {}
    for row in of_node(rows, producer):
        if row["origin_ns"] is not None:
            ends.setdefault(row["origin_ns"], row["end_ns"])
    return [
        (row["start_ns"] - ends[row["origin_ns"]]) / 1e6
        for row in of_node(rows, consumer)
        if row["origin_ns"] in ends and row["start_ns"] >= ends[row["origin_ns"]]
    ]


def late_within(events: Sequence[Mapping[str, Any]], from_s: float) -> dict[str, tuple[int, int]]:
    """Per subchain, ``(late, runs)`` from the last status event before ``from_s`` (log time) to the last one: the
    difference of its cumulative late counters, and the run events logged between the two."""
    statuses = [event for event in events if event.get("event") == "status"]
    if not statuses:
        return {}
    first = max((event for event in statuses if event["t"] <= from_s), key=lambda event: event["t"], default=None)
    last = statuses[-1]
    start_s = first["t"] if first is not None else 0.0
    before = first["subchains"] if first is not None else {}
    found = {}
    for name, row in last["subchains"].items():
        late = int(row.get("late") or 0) - int(before.get(name, {}).get("late") or 0)
        runs = sum(
            1
            for event in events
            if event.get("event") == "run" and event.get("subchain") == name and start_s < event["t"] <= last["t"]
        )
        found[name] = (late, runs)
    return found


def stale_runs(rows: Sequence[Record], head: str, later: str, start_ns: int, end_ns: int) -> tuple[int, int]:
    """``later``'s runs that started in ``[start_ns, end_ns)`` whose input is older than ``head``'s newest run that
    ended before them, of all such runs.

    Each is compared with every head run recorded in ``rows`` (those before the window too, so the window's
    first runs have their predecessors).  Runs of ``later`` before the window are not counted: like every other
    figure here, the target is the measured window's (the start-up, before the first re-plans and while the
    enforcer places the threads, is not; :func:`stale_runs` over the whole run shows it).
    """
    heads = sorted((row["end_ns"], row["origin_ns"]) for row in of_node(rows, head))
    stale = total = 0
    index, newest = 0, None
    for run in sorted(of_node(rows, later), key=lambda row: row["start_ns"]):
        while index < len(heads) and heads[index][0] <= run["start_ns"]:
            newest = heads[index][1] if newest is None else max(newest, heads[index][1])
            index += 1
        if run["origin_ns"] is None or newest is None or not start_ns <= run["start_ns"] < end_ns:
            continue
        total += 1
        stale += run["origin_ns"] < newest
    return stale, total


def rate_hz(rows: Sequence[Record], node: str, window_s: float) -> float:
    return len(of_node(rows, node)) / window_s


# --------------------------------------------------------------------------- plans


def baseline_rates(spec: Mapping[str, Any]) -> dict[str, float]:
    """Each subchain's planned rate in plain ROS 2: the baseline rate of its last node."""
    rates = spec["baseline"]["rates_hz"]
    return {subchain: float(rates[node]) for subchain, node in SUBCHAIN_LAST.items()}


def table_of(folder: Path, cores: int) -> dict[str, Any]:
    table: dict[str, Any] = json.loads((folder / "out" / f"cores-{cores}" / "runtime.json").read_text())
    return table


def mean_planned_hz(planned: Sequence[PlannedRate], start_s: float, end_s: float) -> float | None:
    """The rate the plans in force over ``[start_s, end_s]`` of a run promise, each for as long as it was in force
    (the enforcer re-plans every few seconds)."""
    runs = 0.0
    for index, rate in enumerate(planned):
        until = planned[index + 1].t_s if index + 1 < len(planned) else end_s
        runs += rate.expected_hz * max(0.0, min(until, end_s) - max(rate.t_s, start_s))
    return runs / (end_s - start_s) if planned and end_s > start_s else None


def planned_local_response_ms(table: Mapping[str, Any]) -> float:
    chains = table["plan"]["chains"]
    return float(
        next(chain["response_ms"] for chain in chains if chain["nodes"][: len(LOCAL_SUBCHAIN)] == list(LOCAL_SUBCHAIN))
    )


# --------------------------------------------------------------------------- one case


@dataclass(frozen=True)
class SubchainRate:
    name: str
    measured_hz: float
    planned_hz: float | None
    late: int | None = None
    runs: int | None = None  # catanc: runs the enforcer counted over the whole run
    window_late: int | None = None  # catanc: late runs between the enforcer's status events that span the window
    window_runs: int | None = None  # catanc: runs it logged between them

    @property
    def off(self) -> float | None:
        """Measured over planned, minus 1."""
        return None if not self.planned_hz else self.measured_hz / self.planned_hz - 1.0


@dataclass(frozen=True)
class Case:
    mode: str
    cores: int
    window_s: float
    local: Spread | None
    local_lp: Spread | None
    navigation: Spread | None
    planned_local_ms: float | None
    subchains: tuple[SubchainRate, ...]
    hop_scan_lm: Spread | None
    hop_lm_lp: Spread | None
    stale_lm: tuple[int, int]  # in the window
    stale_lp: tuple[int, int]
    stale_lm_run: tuple[int, int]  # over the whole run, the start-up included
    stale_lp_run: tuple[int, int]
    enforcer_cores: float | None
    enforcer_share: float | None
    hop_inside: Spread | None
    resolves: int | None
    stopped: dict[str, int | None]
    load_before: str
    load_after: str


def _cmdline(pid: int) -> str:
    """A process's command line ("" once it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from /proc's children lists)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            for child in (task / "children").read_text().split():
                found += [int(child), *descendants(int(child))]
    return found


def lower_middleware(pids: Sequence[int], cpus: Sequence[int]) -> int:
    """Every middleware thread (as the enforcer names them) of ``pids`` to SCHED_OTHER on ``cpus``; how many (an
    experiment: what does the enforcer's placement of them buy the hops between processes?)."""
    lowered = 0
    for pid in pids:
        for tid in threads_of(pid):
            if (thread_name(pid, tid) or "").startswith(MIDDLEWARE_THREADS):
                with contextlib.suppress(OSError):
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                    os.sched_setaffinity(tid, cpus)
                    lowered += 1
    return lowered


def measure_case(
    mode: str, cores: int, duration_s: float, warmup_s: float, dds_other: bool = False, *, keep: Path | None = None
) -> Case:
    load_before = load()
    with tempfile.TemporaryDirectory(prefix=f"ros-nav2d-{mode}-{cores}-") as scratch_name:
        scratch = Path(scratch_name)
        with running(mode, cores, scratch) as app:
            app.wait_ready()
            if dds_other and mode != "plain":
                time.sleep(2.0)  # the enforcer places them once a second: after that, they stay put
                lowered = lower_middleware(descendants(app.launcher.pid), case_cpus(cores))
                print(f"# {lowered} middleware threads back at SCHED_OTHER", file=sys.stderr, flush=True)
            time.sleep(warmup_s)
            start_ns = time.time_ns()
            enforcer_before = process_cpu_ns(app.launcher.pid) if mode == "catanc" else 0
            time.sleep(duration_s)
            enforcer_cpu_ns = process_cpu_ns(app.launcher.pid) - enforcer_before if mode == "catanc" else None
            end_ns = time.time_ns()
            stopped = app.stop()
        rows = all_records(app.records)
        table = table_of(app.folder, cores)
        window = within(rows, start_ns, end_ns)
        window_s = (end_ns - start_ns) / 1e9
        events = read_log(app.log) if mode != "plain" and app.log.exists() else None
        log_summary = summarise(events) if events is not None else None
        if keep is not None and log_summary is not None:  # for `catanc report` and `catanc profile`
            keep.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(app.log, keep / f"{mode}-cores-{cores}.jsonl")
            for text in app.output.glob("*.txt"):  # what the launcher and the robot said (a stop that hung)
                shutil.copyfile(text, keep / f"{mode}-cores-{cores}-{text.name}")
            shutil.copytree(app.records, keep / f"{mode}-cores-{cores}-records", dirs_exist_ok=True)  # runs, traced
    planned: dict[str, float | None]
    counters: dict[str, tuple[int | None, int | None]] = {}
    if log_summary is None:
        planned = dict(baseline_rates(table["spec"]))
    else:
        planned = {}
        window_end_s = log_summary.length_s  # the stop came right after the window
        for row in log_summary.subchains:
            planned[row.name] = mean_planned_hz(row.planned, window_end_s - window_s, window_end_s)
            counters[row.name] = (row.late, row.runs)
    in_window = late_within(events or [], log_summary.length_s - window_s) if log_summary is not None else {}
    subchains = tuple(
        SubchainRate(
            name,
            rate_hz(window, node, window_s),
            planned.get(name),
            *counters.get(name, (None, None)),
            *in_window.get(name, (None, None)),
        )
        for name, node in SUBCHAIN_LAST.items()
    )
    costs = None if log_summary is None else log_summary.costs
    hop = None if costs is None or costs.hop_inside is None else costs.hop_inside
    return Case(
        mode=mode,
        cores=cores,
        window_s=window_s,
        local=spread(local_chain_ms(window)),
        local_lp=spread(local_to_lp_ms(window)),
        navigation=spread(navigation_chain_ms(window)),
        planned_local_ms=None if mode == "plain" else planned_local_response_ms(table),
        subchains=subchains,
        hop_scan_lm=spread(hop_ms(window, "scan", "LM")),
        hop_lm_lp=spread(hop_ms(window, "LM", "LP")),
        stale_lm=stale_runs(rows, "scan", "LM", start_ns, end_ns),
        stale_lp=stale_runs(rows, "scan", "LP", start_ns, end_ns),
        stale_lm_run=stale_runs(rows, "scan", "LM", 0, end_ns),
        stale_lp_run=stale_runs(rows, "scan", "LP", 0, end_ns),
        enforcer_cores=None if enforcer_cpu_ns is None else enforcer_cpu_ns / (end_ns - start_ns),
        enforcer_share=None if costs is None else costs.share,
        hop_inside=None if hop is None else Spread(hop.count, hop.p50_ms, hop.p95_ms, hop.max_ms),
        resolves=None if log_summary is None else len(log_summary.resolves),
        stopped=stopped,
        load_before=load_before,
        load_after=load(),
    )


# --------------------------------------------------------------------------- report


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _spread(value: Spread | None) -> str:
    return "-" if value is None else f"{value.p50_ms:.2f} / {value.p95_ms:.2f} / {value.max_ms:.2f} (n={value.count})"


def _stale(counts: tuple[int, int]) -> str:
    stale, total = counts
    return f"{stale}/{total}" + (f" ({100 * stale / total:.1f}%)" if total else "")


def render(cases: Sequence[Case]) -> str:
    lines = []
    for case in cases:
        lines.append(
            f"## {case.mode}, {case.cores} core(s): {case.window_s:.1f} s measured, load {case.load_before} -> "
            f"{case.load_after}"
        )
        lines.append(
            f"  local chain scan -> base, ms p50 / p95 / max: {_spread(case.local)}"
            + ("" if case.planned_local_ms is None else f"   (plan's response {case.planned_local_ms:.2f})")
        )
        lines.append(f"  local chain scan -> LP's command, ms:          {_spread(case.local_lp)}")
        lines.append(f"  GL -> NC -> LP, ms p50 / p95 / max:          {_spread(case.navigation)}")
        lines.append(f"  hop scan -> LM, ms:  {_spread(case.hop_scan_lm)}")
        lines.append(f"  hop LM -> LP, ms:    {_spread(case.hop_lm_lp)}")
        lines.append(
            f"  stale runs: LM {_stale(case.stale_lm)}, LP {_stale(case.stale_lp)} (whole run, start-up included: "
            f"LM {_stale(case.stale_lm_run)}, LP {_stale(case.stale_lp_run)})"
        )
        for row in case.subchains:
            off = "-" if row.off is None else f"{100 * row.off:+.1f}%"
            late = "" if row.late is None else f", late {row.late} of {row.runs} runs"
            if row.window_late is not None:
                late += f" ({row.window_late} of {row.window_runs} in the window)"
            lines.append(
                f"  subchain {row.name:<5} {row.measured_hz:8.2f} Hz, plan {_ms(row.planned_hz):>8} Hz ({off}){late}"
            )
        if case.mode == "catanc":
            lines.append(
                f"  enforcer CPU: {_ms(case.enforcer_cores)} cores (schedstat), share {_ms(case.enforcer_share)} "
                f"(its own figure); hop inside a subchain ms p50 / p95 / max {_spread(case.hop_inside)}; "
                f"re-plans {case.resolves}"
            )
        lines.append(f"  exit on Ctrl-C: {case.stopped}")
    by = {(case.mode, case.cores): case for case in cases}
    for cores in sorted({case.cores for case in cases}):
        plain, catanc = by.get(("plain", cores)), by.get(("catanc", cores))
        if plain and catanc and plain.local and catanc.local:
            lines.append(
                f"{cores} core(s): local-chain p95 plain / catanc = {plain.local.p95_ms / catanc.local.p95_ms:.1f}x"
            )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--duration", type=float, default=30.0, help="seconds measured per case (default 30)")
    parser.add_argument("--warmup", type=float, default=5.0, help="seconds after the first commands, unmeasured")
    parser.add_argument("--cores", type=int, action="append", choices=(1, 2), help="repeat; default 1 and 2")
    parser.add_argument("--mode", action="append", choices=BENCHMARK_MODES, help="repeat; default both")
    parser.add_argument("--json", action="store_true", help="print the cases as JSON")
    parser.add_argument(
        "--dds-other",
        action="store_true",
        help="an experiment: put the app's middleware threads back to SCHED_OTHER once it runs (catanc mode)",
    )
    parser.add_argument(
        "--keep-logs",
        type=Path,
        metavar="DIR",
        help="copy each catanc case's run log, output and the nodes' run records to DIR/<mode>-cores-<K>*",
    )
    parser.add_argument(
        "--first-cpu",
        type=int,
        default=0,
        help="run each case on the CPUs from this one on (default 0; the enforcer plans on the CPUs it may use)",
    )
    args = parser.parse_args(argv)
    FIRST_CPU[0] = args.first_cpu
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 + os.getpid() % 100))  # apart from the tests' 1..100
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    cases = []
    for cores in args.cores or [1, 2]:
        for mode in args.mode or BENCHMARK_MODES:
            print(f"# {mode}, {cores} core(s) ...", file=sys.stderr, flush=True)
            cases.append(measure_case(mode, cores, args.duration, args.warmup, args.dds_other, keep=args.keep_logs))
    print(json.dumps([asdict(case) for case in cases], indent=2) if args.json else render(cases))


if __name__ == "__main__":
    main()
