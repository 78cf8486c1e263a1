"""``catanc bench``: the replay of measured runs, the baselines' triggers, and real runs on this kernel.

The replay and the trigger rules are pure and checked against hand-worked cases, and the
driver (with a fake socket and clock) against the simulator's :class:`TimerPolicy` on the
same app.  The real runs are short (2.5 s a policy, a tiny app on one core) and check what
must hold on any machine, however loaded: every chain has outputs, timers keep their rates,
catanc's subchain runs near its planned rate, the workers and the bench's own thread end
up as they started.
"""

from __future__ import annotations

import contextlib
import heapq
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from catanc.control.run_summary import summarise
from catanc.control.timers import TICK, TIMER, Clock, Triggers, trigger_rules
from catanc.errors import ExitCode, UsageError
from catanc.model.build import build_problem
from catanc.model.load import load_spec, parse_spec
from catanc.planning.planner import plan
from catanc.realbench import bench as bench_run
from catanc.realbench.bench import fifo_levels
from catanc.realbench.driver import BenchError, Driver
from catanc.realbench.replay import measured_result, replay, utilisation
from catanc.runtime.linux.sched import read_policy
from catanc.runtime.logs.report import load_events
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol.messages import Address
from catanc.runtime.worker.records import RunRecord, read_records
from catanc.sim.simulate import Setup, prepare, reported_chains, simulate_policies, workload_sampler
from catanc.spec.language import Spec
from tests.support.linux import WAIT_S, as_user, nobody_ids, poll

T0 = 5_000_000_000  # a window's start on CLOCK_MONOTONIC (ns): replayed times are relative to it
MS = 1_000_000


def spec_of(text: str, tmp_path: Path, name: str = "spec.yaml") -> Spec:
    path = tmp_path / name
    path.write_text(text)
    return load_spec(path)


def run(node: str, start_ms: float, end_ms: float, cpu_ms: float | None = None) -> RunRecord:
    """A run ``start_ms`` to ``end_ms`` after the window's start (its CPU time: its length unless given)."""
    cpu = end_ms - start_ms if cpu_ms is None else cpu_ms
    return RunRecord(node, T0 + round(start_ms * MS), T0 + round(end_ms * MS), round(cpu * MS))


# -- replaying measured runs -------------------------------------------------------------------

PIPE = """\
catan: 1
app: pipe
nodes:
  A: {compute_ms: 2}
  B: {compute_ms: 2}
  S: {scheduled: false, rate_hz: 100}
  out: {scheduled: false}
edges: [[A, B], [S, B], [B, out]]
subchains: {a: [A], b: [B]}
objective: [{chain: [A, B, out], weight: 1}]
baseline: {rates_hz: {A: 10}}
"""
CHAINS = [("A", "B", "out"), ("S", "B", "out")]


@pytest.fixture
def pipe(tmp_path: Path) -> Spec:
    return spec_of(PIPE, tmp_path)


def test_a_run_reads_the_latest_output_at_its_start_and_publishes_at_its_end(pipe: Spec) -> None:
    runs = [
        run("A", 0, 2),  # origin 0
        run("B", 3, 5),  # reads A's output of 2 (origin 0): 1 ms stale
        run("A", 10, 12),  # origin 10
        run("B", 11, 13),  # starts while A's second run is still going: reads origin 0 again, 9 ms stale
        run("B", 14, 16),  # reads origin 10
    ]
    flow = replay(pipe, CHAINS, runs, start_ns=T0, end_ns=T0 + 100 * MS)
    assert flow.records["A"].done_ms == [2, 12]
    assert flow.records["B"].done_ms == [5, 13, 16]
    # B's oldest input is A's or S's (ticks at 0, 10, ...): at 3, A's is 1 ms old, S's 3 ms.
    assert flow.records["B"].staleness_ms == pytest.approx([3, 9, 4])
    assert flow.arrivals[0] == [(0, 5), (10, 16)]  # B's output at 13 repeats origin 0: no new event reached it
    # The chain's window: the first output sets the origin; only a newer origin is a response,
    # from the previous origin (0) to the output that first reflects the newer one (16).
    assert measured(pipe, flow).chains[0].samples[:, 1].tolist() == [16]


def measured(spec: Spec, flow: Any) -> Any:
    chains = [(nodes, index == 0) for index, nodes in enumerate(CHAINS)]
    return measured_result("baseline", flow, chains, duration_s=0.1, utilisation=(0.5,))


def test_sensors_tick_from_the_windows_start_and_pass_their_origin_on(pipe: Spec) -> None:
    flow = replay(pipe, CHAINS, [run("B", 15, 17), run("B", 31, 33)], start_ns=T0, end_ns=T0 + 40 * MS)
    assert flow.records["S"].done_ms == [0, 10, 20, 30, 40]  # 100 Hz, the last at the window's end
    assert flow.arrivals[1] == [(10, 17), (30, 33)]  # each run read the tick before it
    assert flow.records["B"].staleness_ms == pytest.approx([5, 1])
    assert flow.records["out"].done_ms == [17, 33]  # a pure sink passes on at once


def test_runs_cut_by_the_window_are_left_out(pipe: Spec) -> None:
    runs = [run("A", -1, 1), run("A", 5, 7), run("A", 98, 101)]
    flow = replay(pipe, CHAINS, runs, start_ns=T0, end_ns=T0 + 100 * MS)
    assert flow.records["A"].done_ms == [7]
    busy = utilisation(runs, {}, 2, start_ns=T0, end_ns=T0 + 100 * MS)
    assert busy == pytest.approx((0.01, 0.01))  # 2 ms of CPU over 2 cores and 100 ms


def test_at_one_instant_ends_come_before_starts(pipe: Spec) -> None:
    # A ends and S ticks at 10 exactly when B starts: B sees both.  A run of no measurable length still works.
    flow = replay(pipe, CHAINS, [run("A", 8, 10), run("B", 10, 10)], start_ns=T0, end_ns=T0 + 20 * MS)
    assert flow.arrivals == [[(8, 10)], [(10, 10)]]
    assert flow.records["B"].staleness_ms == [0]


def test_replay_refuses_runs_of_unknown_or_unscheduled_nodes(pipe: Spec) -> None:
    with pytest.raises(ValueError, match="'S', which is not a scheduled node"):
        replay(pipe, CHAINS, [run("S", 1, 2)], start_ns=T0, end_ns=T0 + 10 * MS)
    with pytest.raises(ValueError, match=r"ends .* before it starts"):
        replay(pipe, CHAINS, [run("A", 3, 2)], start_ns=T0, end_ns=T0 + 10 * MS)


def test_utilisation_spreads_a_run_over_the_cores_its_node_may_use() -> None:
    runs = [run("A", 0, 10, cpu_ms=10), run("B", 0, 10, cpu_ms=20)]  # B burned on two threads
    busy = utilisation(runs, {"A": (1,), "B": (0, 1)}, 2, start_ns=T0, end_ns=T0 + 100 * MS)
    assert busy == pytest.approx((0.1, 0.2))


def test_a_measured_result_reports_like_a_simulated_one(pipe: Spec) -> None:
    runs = [run("A", 0, 2), run("B", 3, 5), run("A", 100, 102), run("B", 103, 105), run("A", 200, 202)]
    flow = replay(pipe, CHAINS, runs, start_ns=T0, end_ns=T0 + 1000 * MS)
    chains = [(nodes, index == 0) for index, nodes in enumerate(CHAINS)]
    result = measured_result("baseline", flow, chains, duration_s=1.0, utilisation=(0.25,), model={CHAINS[0]: 7.5})
    body = result.as_dict()
    assert body["chains"][0] == {
        "nodes": ["A", "B", "out"],
        "named": True,
        "response_ms": {"mean": 105.0, "p95": 105.0, "max": 105.0},
        "outputs": 1,
        "model_ms": 7.5,
    }
    assert body["nodes"]["A"] == {"rate_hz": 3.0, "staleness_ms_p95": None}
    assert body["cores"] == [{"core": 0, "utilisation": 0.25}]
    assert result.node_done_ms["B"].tolist() == [5, 105]


# -- the baselines' triggers -------------------------------------------------------------------


def test_a_busy_node_keeps_one_trigger_and_drops_the_rest(pipe: Spec) -> None:
    triggers = Triggers(trigger_rules(pipe))
    assert triggers.fire("A") == ["A"]
    assert triggers.fire("A") == []  # busy: it waits ...
    assert triggers.fire("A") == []  # ... and a third coalesces with it
    assert triggers.done("A") == ["B", "A"]  # A's output triggers B, then A's one waiting trigger
    assert triggers.done("A") == []  # B still runs: pending, not started
    assert triggers.done("B") == ["B"]  # B again, for A's second output
    assert triggers.done("B") == []


def test_input_triggered_nodes_follow_scheduled_inputs_first_then_sensors(tmp_path: Path) -> None:
    vr = load_spec(Path(__file__).parents[2] / "specs" / "vr_illixr.yaml")
    rules = trigger_rules(vr)
    assert rules.timers == pytest.approx({"Camera": 50.0, "Render": 1000 / 120, "Timewarp": 1000 / 120})
    assert rules.sensors == {"IMU": 5.0}
    assert rules.fed == {"Camera": ("VIO",)}  # VIO has Camera, so IMU does not trigger it
    assert trigger_rules(spec_of(PIPE, tmp_path)).fed == {"A": ("B",)}  # B has A: S does not trigger it
    only_sensor = PIPE.replace("[[A, B], [S, B], [B, out]]", "[[S, A], [S, B], [B, out]]")
    only_sensor = only_sensor.replace("[A, B, out]", "[S, B, out]")
    rules = trigger_rules(spec_of(only_sensor, tmp_path, "s.yaml"))
    assert rules.fed == {"S": ("B",)}  # B's only input is a sensor


def test_a_baseline_must_reach_every_scheduled_node(tmp_path: Path) -> None:
    gap = spec_of(PIPE.replace("baseline: {rates_hz: {A: 10}}", "baseline: {rates_hz: {B: 5}}"), tmp_path)
    with pytest.raises(UsageError, match=r"gives A no rate in baseline\.rates_hz and no input with one"):
        trigger_rules(gap)
    none = spec_of(PIPE.replace("baseline: {rates_hz: {A: 10}}\n", ""), tmp_path, "none.yaml")
    with pytest.raises(UsageError, match=r"no baseline \(baseline.rates_hz\)"):
        trigger_rules(none)


def test_the_clock_fires_every_period_from_the_start_sensors_first(pipe: Spec) -> None:
    clock = Clock(trigger_rules(pipe), 1000.0)
    assert clock.next_ms() == 1000.0
    assert clock.due(999.0) == []
    assert clock.due(1000.0) == [(1000.0, TICK, "S"), (1000.0, TIMER, "A")]
    late = clock.due(1125.0)  # a late look gets every missed one, in time order (none skipped)
    assert [event for event in late if event[2] == "A"] == [(1100.0, TIMER, "A")]
    assert [at for at, _, node in late if node == "S"] == [1010.0 + 10 * i for i in range(12)]
    assert clock.next_ms() == 1130.0


def test_fifo_levels_are_the_papers_order_never_the_stealing_priorities() -> None:
    specs = Path(__file__).parents[2] / "specs"
    vr = load_spec(specs / "vr_illixr.yaml")  # schedule.priorities (stealing): timewarp 1, vio 0, render 0
    # docs/explanation/model.md section 7: Timewarp, then Render, then Camera and VIO (one subchain).
    assert fifo_levels(build_problem(vr), vr) == {"Timewarp": 3, "Render": 2, "Camera": 1, "VIO": 1}
    nav = load_spec(specs / "nav2d.yaml")  # weights: local 1.0 > GL 0.5 > the rest
    levels = fifo_levels(build_problem(nav), nav)
    assert levels["scan"] == levels["LM"] == levels["LP"] == max(levels.values())
    assert levels["GL"] == max(levels.values()) - 1
    assert sorted({levels[sub] for sub in ("scan", "GL", "GM", "GP", "NC")}) == [1, 2, 3, 4, 5]  # one each
    # The spec's baseline.priorities: equal ones share a level; the levels count from 1 and keep the order.
    text = (
        (specs / "vr_illixr.yaml")
        .read_text()
        .replace("baseline:\n", "baseline:\n  priorities: {timewarp: 9, render: 9}\n")
    )
    vr = parse_spec(text)
    assert fifo_levels(build_problem(vr), vr) == {"Timewarp": 2, "Render": 2, "Camera": 1, "VIO": 1}


@pytest.mark.usefixtures("real_kernel")
def test_fifo_static_runs_the_vr_threads_at_the_papers_levels_on_the_kernel(
    own_tmp: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the kernel says of each worker thread once the driver starts: SCHED_FIFO at the paper's
    order (Timewarp 3, Render 2, Camera and VIO 1), the driver above them (4)."""
    spec_path = Path(__file__).parents[2] / "specs" / "vr_illixr.yaml"
    tids: dict[str, int] = {}
    seen: dict[str, tuple[int, int]] = {}
    register, run = Driver._register, Driver.run

    def remember(self: Driver, hello: protocol.Hello, address: Address) -> None:
        tids[hello.node] = hello.tid
        register(self, hello, address)

    def look_then_run(self: Driver, start_ms: float, end_ms: float) -> None:
        for node, tid in [*tids.items(), ("driver", threading.get_native_id())]:
            policy = read_policy(tid)
            seen[node] = (policy.policy, policy.priority)
        run(self, start_ms, end_ms)

    monkeypatch.setattr(Driver, "_register", remember)
    monkeypatch.setattr(Driver, "run", look_then_run)
    bench_run.bench_policy(bench_run.BenchSetup(spec_path, load_spec(spec_path), 1, 0.5, 0), "fifo-static")
    fifo = os.SCHED_FIFO
    assert seen == {
        "Timewarp": (fifo, 3),
        "Render": (fifo, 2),
        "Camera": (fifo, 1),
        "VIO": (fifo, 1),
        "driver": (fifo, 4),
    }
    assert processes_mentioning(str(own_tmp)) == []


# -- the driver against the simulator's TimerPolicy --------------------------------------------

# No two events fall at one instant, and four cores hold every node at once: under fair
# sharing each run then takes exactly its compute time, so the simulator's completions are
# what the triggers alone decide.  det is slower than cam's period (it coalesces), ctl has two
# scheduled inputs, fus only a sensor.
TRIGGERED = """\
catan: 1
app: trig
nodes:
  cam: {compute_ms: 7.3}
  det: {compute_ms: 31.1}
  fus: {compute_ms: 2.3}
  ctl: {compute_ms: 3.7}
  imu: {scheduled: false, rate_hz: 40}
  act: {scheduled: false}
edges: [[cam, det], [det, ctl], [imu, fus], [fus, ctl], [ctl, act]]
subchains: {a: [cam, det], b: [ctl], c: [fus]}
objective: [{chain: [cam, det, ctl, act], weight: 1}]
baseline: {rates_hz: {cam: 50}}
"""


class FakeSocket:
    """The workers' side in fake time: a trigger is answered with a done ``compute_ms`` later."""

    def __init__(self, spec: Spec) -> None:
        self.now = 0.0
        self.compute = {name: float(node.compute_ms) for name, node in spec.nodes.items() if node.scheduled}  # type: ignore[arg-type]
        self.pending: list[tuple[float, str, int]] = []
        self.hellos = [protocol.Hello(name, 1, 1 + i) for i, name in enumerate(self.compute)]
        self.done_ms: dict[str, list[float]] = {name: [] for name in self.compute}

    def clock(self) -> float:
        return self.now

    def receive(self, timeout_s: float | None) -> tuple[protocol.Message, Address] | None:
        if self.hellos:
            hello = self.hellos.pop(0)
            return hello, hello.node
        assert timeout_s is not None
        until = self.now + timeout_s * 1000.0
        if self.pending and self.pending[0][0] <= until:
            self.now, node, seq = heapq.heappop(self.pending)
            self.done_ms[node].append(self.now)
            return protocol.Done(node, 1, seq), node
        self.now = until
        return None

    def send(self, message: protocol.Message, address: Address) -> bool:  # noqa: ARG002 - the socket's signature
        return True

    def welcome(self, hello: protocol.Hello, address: Address) -> bool:  # noqa: ARG002 - the socket's signature
        return True

    def send_bytes(self, datagram: bytes, address: Address) -> bool:  # noqa: ARG002
        trigger = protocol.decode(datagram)
        assert isinstance(trigger, protocol.Trigger)
        assert trigger.node not in [node for _, node, _ in self.pending], "a node was triggered while it ran"
        heapq.heappush(self.pending, (self.now + self.compute[trigger.node], trigger.node, trigger.seq))
        return True


def test_the_driver_triggers_as_the_simulators_timer_policy(tmp_path: Path) -> None:
    spec = spec_of(TRIGGERED, tmp_path)
    fake = FakeSocket(spec)
    placed: list[str] = []
    driver = Driver(fake, spec, trigger_rules(spec), place=lambda hello: placed.append(hello.node), clock=fake.clock)  # type: ignore[arg-type]
    driver.register(list(fake.compute), 1.0, alive=lambda: None)
    assert sorted(placed) == sorted(fake.compute)
    driver.run(0.0, 1000.0)

    def constant(spec: Spec, seed: int) -> Any:
        return lambda node, _at_s: float(spec.nodes[node].compute_ms)  # type: ignore[arg-type]

    [simulated] = simulate_policies(Setup(spec, 4, 1.0, 0), ["baseline"], constant)
    for node, done in fake.done_ms.items():
        expected = [t for t in simulated.node_done_ms[node] if t <= 1000.0]
        assert done == pytest.approx(expected, abs=1e-6), node
    assert len(fake.done_ms["cam"]) == 50
    assert 25 <= len(fake.done_ms["det"]) <= 33  # 31.1 ms runs back to back: coalesced triggers


@pytest.mark.parametrize(("grace_s", "waits_for_all"), [(2.0, True), (0.01, False)])
def test_the_driver_keeps_its_socket_for_the_last_runs_after_a_stop(
    tmp_path: Path, grace_s: float, waits_for_all: bool
) -> None:
    """det (28.8 ms) is in the middle of a run when the run ends: stop() returns once it reported it, or at the
    grace; nothing new is triggered meanwhile."""
    spec = spec_of(TRIGGERED, tmp_path)
    fake = FakeSocket(spec)
    driver = Driver(fake, spec, trigger_rules(spec), place=lambda _hello: None, clock=fake.clock)  # type: ignore[arg-type]
    driver.register(list(fake.compute), 1.0, alive=lambda: None)
    driver.run(0.0, 1005.0)
    last = max((t for t, node, _ in fake.pending if node == "det"), default=None)
    assert last is not None
    assert last > 1005.0 + 10.0, "det is mid-run at the end"
    finished = max(t for t, _, _ in fake.pending)
    done_before = {node: len(times) for node, times in fake.done_ms.items()}
    driver.stop(grace_s)
    if waits_for_all:
        assert fake.pending == []  # every run reported, and no new trigger was sent
        assert driver.running == {}
        assert fake.now == pytest.approx(finished)  # returned as the last run reported
        assert fake.done_ms["det"][-1] == pytest.approx(last)
    else:
        assert "det" in driver.running
        assert fake.now == pytest.approx(1005.0 + grace_s * 1000.0, abs=1e-6)
    assert all(len(times) - done_before[node] <= 1 for node, times in fake.done_ms.items())


def test_the_driver_rejects_nodes_it_does_not_run(tmp_path: Path) -> None:
    spec = spec_of(TRIGGERED, tmp_path)
    sent: list[protocol.Message] = []

    class Recorder(FakeSocket):
        def send(self, message: protocol.Message, address: Address) -> bool:  # noqa: ARG002
            sent.append(message)
            return True

        def welcome(self, hello: protocol.Hello, address: Address) -> bool:  # noqa: ARG002
            sent.append(protocol.Welcome(hello.node, 1))
            return True

    fake = Recorder(spec)
    fake.hellos = [protocol.Hello("imu", 1, 1), protocol.Hello("nope", 1, 2), protocol.Hello("cam", 1, 3)]
    driver = Driver(fake, spec, trigger_rules(spec), place=lambda _hello: None, clock=fake.clock)  # type: ignore[arg-type]
    with pytest.raises(BenchError, match="did not register"):
        driver.register(["cam", "det"], 0.2, alive=lambda: None)
    assert sent == [
        protocol.Reject("imu", "no scheduled node 'imu' in app trig"),
        protocol.Reject("nope", "no node 'nope' in app trig"),
        protocol.Welcome("cam", 1),
    ]


# -- real runs ---------------------------------------------------------------------------------

# On one core the plan shares it: fast (6 ms) every ~8.5 ms, slow (20 ms) in slices (planned
# ~118 Hz and ~11 Hz).  The baseline: cam at 20 Hz, det on each of cam's outputs, map at 2 Hz.
TINY = """\
catan: 1
app: tiny
nodes:
  cam: {compute_ms: 2}
  det: {compute_ms: 4}
  map: {compute_ms: 20}
  imu: {scheduled: false, rate_hz: 100}
  act: {scheduled: false}
edges: [[cam, det], [imu, det], [det, act], [det, map]]
subchains: {fast: [cam, det], slow: [map]}
objective:
  - {chain: [cam, det, act], weight: 1.0}
  - {node: map, weight: 0.05}
baseline:
  rates_hz: {cam: 20, map: 2}
"""
DURATION_S = 2.5
REALTIME_PRIORITY = 10  # conftest's real_kernel: the enforcer's threads at 4, its watchdog at 10
BENCH_MAIN = (  # `python -m catanc`, with Python's SIGINT handler even where the tests run with SIGINT ignored
    "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "sys.argv[0] = 'catanc'; from catanc.cli import main; main()"
)


def processes_mentioning(text: str) -> list[int]:
    """Every live process (not a zombie) whose command line mentions ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
            if text.encode() in (entry / "cmdline").read_bytes() and state not in ("Z", "X"):
                found.append(int(entry.name))
        except OSError:
            continue
    return found


@pytest.fixture
def own_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``tmp_path`` as the temporary folder of this process (the bench's run folders, the workers' files)."""
    folder = tmp_path / "t"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.fixture(scope="module")
def bench_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where :func:`bench_json`'s bench runs: its spec, plots (``plots/``) and run logs (``logs/``)."""
    return tmp_path_factory.mktemp("bench")


@pytest.fixture(scope="module")
def bench_json(real_kernel: None, bench_folder: Path) -> tuple[dict[str, Any], str, list[int]]:
    """One ``catanc bench`` of TINY, every policy, on one core: its JSON, its stderr, and what it left running."""
    folder = bench_folder
    spec = folder / "tiny.yaml"
    spec.write_text(TINY)
    runs = folder / "runs"
    runs.mkdir()
    argv = [sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", "--duration", str(DURATION_S), "--json"]
    finished = subprocess.run(
        [*argv, "--plot", str(folder / "plots"), "--log", str(folder / "logs")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "TMPDIR": str(runs)},
    )
    assert finished.returncode == 0, finished.stderr
    return json.loads(finished.stdout), finished.stderr, processes_mentioning(str(runs))


def test_a_bench_draws_the_simulators_plots(bench_json: tuple[dict[str, Any], str, list[int]]) -> None:
    written = [Path(line.removeprefix("plot: ")) for line in bench_json[1].splitlines() if line.startswith("plot: ")]
    assert sorted(path.name for path in written) == ["rates.png", "responses-cdf.png", "timeline.png"]
    for path in written:
        assert path.read_bytes().startswith(b"\x89PNG")


def test_a_bench_reports_every_policy_in_the_simulators_shape(
    bench_json: tuple[dict[str, Any], str, list[int]], tmp_path: Path
) -> None:
    payload, stderr, _ = bench_json
    assert set(payload["policies"]) == {"catan", "baseline", "fifo-static"}  # keys sorted, as simulate's
    progress = [line.split(":")[0] for line in stderr.splitlines() if not line.startswith("plot: ")]
    assert progress == ["catan", "baseline", "fifo-static"]
    spec = spec_of(TINY, tmp_path)
    chains = [list(nodes) for nodes, _ in reported_chains(spec, build_problem(spec))]  # the simulator's list
    for policy, body in payload["policies"].items():
        assert set(body) == {"duration_s", "chains", "nodes", "cores", "replans"}, policy
        assert [c["nodes"] for c in body["chains"]] == chains
        assert set(body["nodes"]) == set(spec.nodes)
        assert [core["core"] for core in body["cores"]] == [0]
        assert body["duration_s"] == DURATION_S
        for chain in body["chains"]:
            if chain["named"]:  # every named chain delivered outputs under every policy
                assert chain["outputs"] > 0, (policy, chain)
    named = next(c for c in payload["policies"]["catan"]["chains"] if c["named"])
    assert named["model_ms"] > 0  # the enforcer's last plan, replayed


@pytest.mark.parametrize("policy", ["baseline", "fifo-static"])
def test_baseline_timers_keep_their_rates(bench_json: tuple[dict[str, Any], str, list[int]], policy: str) -> None:
    # A 20 Hz timer fires 50 times in the 2.5 s window (51 with both ends); a run cut by the
    # window's end is left out, and cam is busy 4% of the time, so its triggers never coalesce
    # unless the machine stalls it for a whole period: within 10% even on a loaded machine.
    # map at 2 Hz: 5 runs (6 fires, the last at the very end), one either way.
    nodes = bench_json[0]["policies"][policy]["nodes"]
    assert 18.0 <= nodes["cam"]["rate_hz"] <= 22.0
    assert 1.6 <= nodes["map"]["rate_hz"] <= 2.4
    # det runs on each of cam's outputs (4 ms: done long before the next).
    assert abs(nodes["det"]["rate_hz"] - nodes["cam"]["rate_hz"]) <= 2 / DURATION_S
    # The app's CPU: cam 20 x 2 ms + det 20 x 4 ms + map 2 x 20 ms = 160 ms a second on one core.
    assert 0.13 <= bench_json[0]["policies"][policy]["cores"][0]["utilisation"] <= 0.2


def test_catans_subchain_runs_near_its_planned_rate(
    bench_json: tuple[dict[str, Any], str, list[int]], tmp_path: Path
) -> None:
    planned = 1000.0 / plan(spec_of(TINY, tmp_path), 1).subchains["fast"].period_ms
    nodes = bench_json[0]["policies"]["catan"]["nodes"]
    # At most one trigger a planned period (so at most the planned rate, 5% for the window's
    # edges); a run that overruns its slice (the workers' Python overhead, a busy machine)
    # loses a period now and then, so at least 70% of it.  The baseline's cam runs at 20 Hz.
    assert 0.7 * planned <= nodes["cam"]["rate_hz"] <= 1.05 * planned
    assert nodes["det"]["rate_hz"] <= nodes["cam"]["rate_hz"] + 1 / DURATION_S
    assert nodes["det"]["rate_hz"] >= 0.9 * nodes["cam"]["rate_hz"]  # one subchain: det follows each cam run
    assert nodes["map"]["rate_hz"] > 0
    # The rate the enforcer's last plan promised a head (its re-solves made again from the log): cam's. The
    # run's first 2 s ran the spec's plan, which a re-plan with measured costs may slow by 10-20%.
    promised = nodes["cam"]["planned_hz"]
    assert 0.7 * promised <= nodes["cam"]["rate_hz"] <= 1.25 * promised
    assert "planned_hz" not in nodes["det"]  # not a head: it runs when cam's run ends
    assert all("planned_hz" not in node for node in bench_json[0]["policies"]["baseline"]["nodes"].values())


# TINY with map growing 2x over 10 s: the first 20 s's tail and the whole run's differ.
GROWING = TINY.replace(
    "map: {compute_ms: 20}", "map: {compute_ms: 20, workload: {growth: {start: 1.0, end: 2.0, over_s: 10}}}"
)


@pytest.mark.parametrize(("policy", "duration_s"), [("static-fullrun", 30.0), ("static-20s", 30.0)])
def test_a_static_policy_plans_what_the_simulator_plans_and_never_re_solves(
    tmp_path: Path, policy: str, duration_s: float
) -> None:
    path = tmp_path / "growing.yaml"
    path.write_text(GROWING)
    spec = load_spec(path)
    setup = bench_run.BenchSetup(path, spec, 1, duration_s, 3)
    planned = bench_run.planned_spec(setup, policy)
    # The simulator's static plan, made by its own path (prepare: the problem with the tails).
    simulated = prepare(Setup(spec, 1, duration_s, 3), policy, workload_sampler).plan
    assert simulated is not None
    enforced = plan(planned, 1)
    assert enforced.objective == pytest.approx(simulated.objective, rel=1e-6)
    for name, sub in simulated.subchains.items():
        assert enforced.subchains[name].period_ms == pytest.approx(sub.period_ms, rel=1e-6)
    runtime = planned.runtime
    assert min(runtime.first_solve_after_s, runtime.stage2_every_s, runtime.stage1_every_s) > duration_s
    # The whole run's tail sees map at up to 2x; the first 20 s's too (growth ends at 10 s); both
    # exceed the spec's 20 ms, which catan starts from.
    profiled = planned.nodes["map"].compute_ms
    assert isinstance(profiled, float)
    assert profiled > 30.0
    assert spec.nodes["map"].compute_ms == 20  # the workers' spec is untouched


@pytest.mark.usefixtures("real_kernel")
def test_a_static_bench_runs_under_the_enforcer_without_re_solving(tmp_path: Path) -> None:
    spec = tmp_path / "growing.yaml"
    spec.write_text(GROWING)
    argv = [sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", "--duration", str(DURATION_S), "--json"]
    finished = subprocess.run(
        [*argv, "--policy", "static-fullrun"], capture_output=True, text=True, timeout=120, check=False
    )
    assert finished.returncode == 0, finished.stderr
    body = json.loads(finished.stdout)["policies"]["static-fullrun"]
    assert body["replans"] == 0
    static = plan(
        bench_run.planned_spec(bench_run.BenchSetup(spec, load_spec(spec), 1, DURATION_S, 0), "static-fullrun"), 1
    )
    planned_hz = 1000.0 / static.subchains["fast"].period_ms
    assert 0.7 * planned_hz <= body["nodes"]["cam"]["rate_hz"] <= 1.05 * planned_hz  # as catan's check above


def test_a_bench_keeps_each_enforced_policys_run_log_for_report(
    bench_json: tuple[dict[str, Any], str, list[int]], bench_folder: Path
) -> None:
    # catan runs under the enforcer, the baselines under the bench's own timers: one log, catan's;
    # every policy's worker records.
    logs = bench_folder / "logs"
    policies = ("baseline", "catan", "fifo-static")
    kept = sorted(["catan.jsonl", *(f"{policy}.runs.jsonl" for policy in policies)])
    assert sorted(path.name for path in logs.iterdir()) == kept
    for policy in policies:  # at least the runs the JSON counts in its window, with their thread clocks
        cam_runs = [run for run in read_records(logs / f"{policy}.runs.jsonl") if run.node == "cam"]
        assert len(cam_runs) >= 0.9 * bench_json[0]["policies"][policy]["nodes"]["cam"]["rate_hz"] * DURATION_S
        assert all(run.thread_cpu_start_ns + run.cpu_ns <= run.thread_cpu_done_ns for run in cam_runs)
    summary = summarise(load_events(logs / "catan.jsonl"))
    assert summary.complete
    runs = {sub.name: sub.runs for sub in summary.subchains}
    # The same run the JSON reports: cam heads subchain fast, one run each.
    measured = bench_json[0]["policies"]["catan"]["nodes"]["cam"]["rate_hz"] * DURATION_S
    assert runs["fast"] >= 0.9 * measured


def test_a_log_folder_that_is_a_file_is_refused_before_anything_runs(tmp_path: Path) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    taken = tmp_path / "logs"
    taken.write_text("not a folder")
    argv = [sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", "--log", str(taken)]
    finished = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    assert finished.returncode == 2
    assert f"--log {taken}: not a folder" in finished.stderr
    assert taken.read_text() == "not a folder"


def test_a_bench_leaves_no_process_behind(bench_json: tuple[dict[str, Any], str, list[int]]) -> None:
    assert bench_json[2] == []


@pytest.mark.usefixtures("real_kernel")
def test_ctrl_c_stops_every_worker(tmp_path: Path) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    runs = tmp_path / "runs"
    runs.mkdir()
    argv = [sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", "--duration", "60"]
    bench = subprocess.Popen(
        [*argv, "--policy", "fifo-static"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "TMPDIR": str(runs)},
        start_new_session=True,
    )
    try:
        poll(lambda: len(processes_mentioning(str(runs))) >= 3, "the three workers to start")
        time.sleep(1.0)  # they register, and the run begins
        bench.send_signal(signal.SIGINT)
        _, stderr = bench.communicate(timeout=WAIT_S)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(bench.pid, signal.SIGKILL)
        bench.wait()
    assert bench.returncode == 130, stderr
    assert "interrupted; every worker stopped" in stderr
    assert "Traceback" not in stderr
    assert processes_mentioning(str(runs)) == []


class InjectedError(Exception):
    pass


@pytest.mark.parametrize("policy", ["catan", "fifo-static"])
@pytest.mark.usefixtures("real_kernel")
def test_a_failed_run_stops_its_workers_and_puts_this_thread_back(
    policy: str, own_tmp: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec_path = tmp_path / "tiny.yaml"
    spec_path.write_text(TINY)
    setup = bench_run.BenchSetup(spec_path, load_spec(spec_path), 1, 30.0, 0)
    if policy == "catan":  # fails once the workers are started, inside the enforcer's run
        start = bench_run.Workers.start

        def failing_start(self: bench_run.Workers, socket_path: Path) -> None:
            start(self, socket_path)
            raise InjectedError

        monkeypatch.setattr(bench_run.Workers, "start", failing_start)
    else:  # fails once every node registered and this thread is the driver at SCHED_FIFO

        def failing_run(self: Driver, start_ms: float, end_ms: float) -> None:
            raise InjectedError

        monkeypatch.setattr(Driver, "run", failing_run)
    tid = threading.get_native_id()
    before = (read_policy(tid), sys.getswitchinterval(), signal.getsignal(signal.SIGINT))
    with pytest.raises(InjectedError):
        bench_run.bench_policy(setup, policy)
    assert (read_policy(tid), sys.getswitchinterval(), signal.getsignal(signal.SIGINT)) == before
    assert processes_mentioning(str(own_tmp)) == []
    assert list(own_tmp.iterdir()) == []  # the run's folder is gone too


def test_usage_errors_come_before_anything_starts(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from catanc.cli import app

    runner = CliRunner()
    no_baseline = tmp_path / "plain.yaml"
    no_baseline.write_text(TINY.split("baseline:", maxsplit=1)[0])
    result = runner.invoke(app, ["bench", str(no_baseline), "-k", "1"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "no baseline (baseline.rates_hz) to run" in result.output
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text(TINY)
    result = runner.invoke(app, ["bench", str(tiny), "-k", "1", "--policy", "static-30s"])
    assert result.exit_code == ExitCode.BAD_INPUT
    expected = "catan, catan-nosteal, baseline, fifo-static, static-fullrun, static-20s"
    assert f"unknown policy 'static-30s' (expected one of: {expected})" in result.output
    cpus = len(os.sched_getaffinity(0))
    result = runner.invoke(app, ["bench", str(tiny), "-k", str(cpus + 1), "--policy", "baseline"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert f"may use only {cpus} CPU(s)" in result.output


def bench_as_nobody(folder: Path, *options: str) -> subprocess.CompletedProcess[str]:
    """``catanc bench`` of TINY as ``nobody``: RLIMIT_RTPRIO 0, no capabilities."""
    uid, gid = nobody_ids()
    spec = folder / "tiny.yaml"
    spec.write_text(TINY)
    spec.chmod(0o644)
    return subprocess.run(
        [*as_user(uid, gid, rtprio=0), sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", *options],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        cwd="/",
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "TMPDIR": str(folder)},
    )


@pytest.mark.realtime  # as root, switching to nobody
def test_without_privilege_the_fifo_policies_exit_4_and_say_why(shared_folder: Path) -> None:
    refused = bench_as_nobody(shared_folder, "--duration", "1")
    assert refused.returncode == ExitCode.NO_PRIVILEGE, refused.stderr
    assert int(ExitCode.NO_PRIVILEGE) == 4  # as docs/reference/spec.md documents
    assert "catanc bench: catan and fifo-static run(s) the app under SCHED_FIFO" in refused.stderr
    assert "cannot use SCHED_FIFO priority" in refused.stderr
    assert "catanc bench SPEC --policy baseline" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert [p.name for p in shared_folder.iterdir()] == ["tiny.yaml"]  # refused before anything started


@pytest.mark.realtime  # as root, switching to nobody
def test_without_privilege_the_baseline_runs(shared_folder: Path) -> None:
    uid, gid = nobody_ids()
    probe = subprocess.run(
        ["setpriv", f"--reuid={uid}", f"--regid={gid}", "--clear-groups", sys.executable, "-c", PROBE],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
        cwd="/",
    )
    if probe.returncode != 0:  # e.g. a Python under /root: setpriv's own exec may reach it, nobody's cannot
        pytest.skip(f"nobody cannot start {sys.executable}: {(probe.stderr.strip().splitlines() or ['?'])[-1]}")
    allowed = bench_as_nobody(shared_folder, "--duration", "1", "--policy", "baseline", "--json")
    assert allowed.returncode == 0, allowed.stderr
    nodes = json.loads(allowed.stdout)["policies"]["baseline"]["nodes"]
    assert 16.0 <= nodes["cam"]["rate_hz"] <= 24.0  # 20 or 21 fires in 1 s, one either way


PROBE = "import subprocess, sys; subprocess.run([sys.executable, '-c', ''], check=True)"


@pytest.mark.usefixtures("real_kernel", "compiled_loop")
def test_a_bench_with_the_compiled_loop_runs_catans_plan(tmp_path: Path) -> None:
    """``--loop compiled`` reaches the enforcer: catan's head runs near its planned rate, its log says so."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    argv = [sys.executable, "-c", BENCH_MAIN, "bench", str(spec), "-k", "1", "--duration", str(DURATION_S)]
    argv += ["--json", "--policy", "catan", "--loop", "compiled", "--log", str(tmp_path / "logs")]
    finished = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert finished.returncode == 0, finished.stderr
    nodes = json.loads(finished.stdout)["policies"]["catan"]["nodes"]
    planned = 1000.0 / plan(spec_of(TINY, tmp_path), 1).subchains["fast"].period_ms
    assert 0.7 * planned <= nodes["cam"]["rate_hz"] <= 1.05 * planned
    assert nodes["det"]["rate_hz"] >= 0.9 * nodes["cam"]["rate_hz"]
    assert load_events(tmp_path / "logs" / "catan.jsonl")[-1]["event"] == "stop"
