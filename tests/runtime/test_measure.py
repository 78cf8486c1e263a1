"""Measuring compute times at runtime: catanc.control.measure.

Oracles: numpy's percentile (an independent implementation of the same
definition), hand-worked windows, a log-distance argmin for modes (the code
uses geometric-mean boundaries), and a plain-list model of the windows.
"""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from catanc.control.measure import (
    MIN_PLANNING_MS,
    ComputeWindow,
    Measurements,
    ModeStat,
    assign_mode,
    estimate,
    mode_boundaries,
    percentile,
    reconcile,
    split_modes,
    valid_sample,
)
from catanc.errors import UsageError
from catanc.model.load import load_spec, parse_spec
from catanc.planning.replan import Replanner
from catanc.runtime.linux.cpu_clocks import CpuClock, OpenCpuClocks, cpu_ms, parse_schedstat, schedstat_path
from catanc.spec.language import Spec

untimed = settings(deadline=None)  # tests never time things

ROOT = Path(__file__).resolve().parents[2]
NAV2D = ROOT / "specs" / "nav2d.yaml"

samples_ms = st.one_of(st.just(0.0), st.floats(1e-6, 1e6))  # no subnormals: scaling stays exact
windows = st.integers(1, 60)
percentiles = st.one_of(st.sampled_from([50.0, 95.0, 99.0, 100.0]), st.floats(0.0, 100.0))
mode_sets = st.lists(st.floats(0.01, 1000), min_size=2, max_size=4, unique=True).map(lambda ms: tuple(sorted(ms)))


def nearest_mode_oracle(sample: float, modes: tuple[float, ...]) -> int:
    """argmin |log x - log m|, ties to the higher mode; 0 to the lowest."""
    if sample == 0:
        return 0
    distances = [abs(math.log(sample) - math.log(m)) for m in modes]
    best = min(distances)
    return max(i for i, d in enumerate(distances) if d == best)


def near_tie(sample: float, modes: tuple[float, ...]) -> bool:
    """Whether ``sample`` is within rounding of halfway (on a log scale) between two modes."""
    if sample == 0:
        return False
    distances = sorted(abs(math.log(sample) - math.log(m)) for m in modes)
    return distances[1] - distances[0] < 1e-9


def modal_oracle(samples: list[float], q: float, modes: tuple[float, ...]) -> float:
    groups: dict[int, list[float]] = {}
    for x in samples:
        groups.setdefault(nearest_mode_oracle(x, modes), []).append(x)
    return sum(len(g) / len(samples) * float(np.percentile(g, q)) for g in groups.values())


# --------------------------------------------------------------------------- percentile


def test_percentile_hand_worked() -> None:
    # n = 5, q = 95: h = 4 * 0.95 = 3.8 -> x[3] + 0.8 * (x[4] - x[3]) = 4 + 0.8 * 6 = 8.8
    assert percentile([10.0, 1.0, 4.0, 2.0, 3.0], 95) == pytest.approx(8.8)
    # n = 50, q = 95: h = 46.55 -> x[46] + 0.55 * (x[47] - x[46]) with x[i] = i + 1
    assert percentile([float(i) for i in range(50, 0, -1)], 95) == pytest.approx(47.55)
    assert percentile([7.0], 95) == 7.0
    assert percentile([1.0, 2.0, 3.0], 100) == 3.0
    assert percentile([1.0, 2.0, 3.0], 0) == 1.0
    assert percentile([1.0, 2.0, 3.0, 4.0], 50) == pytest.approx(2.5)


def test_percentile_refuses_no_samples_and_bad_q() -> None:
    with pytest.raises(ValueError, match="no samples"):
        percentile([], 95)
    with pytest.raises(ValueError, match="must be in"):
        percentile([1.0], 101)


@untimed
@given(st.lists(samples_ms, min_size=1, max_size=80), percentiles)
def test_percentile_is_numpys_linear(samples: list[float], q: float) -> None:
    expected = float(np.percentile(samples, q))
    assert math.isclose(percentile(samples, q), expected, rel_tol=1e-12, abs_tol=1e-12)
    assert min(samples) <= percentile(samples, q) <= max(samples)


# --------------------------------------------------------------------------- samples and modes


def test_valid_samples() -> None:
    assert valid_sample(0.0)
    assert valid_sample(0)
    assert valid_sample(12.5)
    for bad in (math.nan, math.inf, -math.inf, -0.1, -1, True, None, "3", [1.0]):
        assert not valid_sample(bad)


def test_rejected_samples_are_counted_not_kept() -> None:
    window = ComputeWindow(window=3)
    for bad in (math.nan, -1.0, math.inf):
        assert not window.add(bad)
    assert window.add(0.0)
    assert window.samples == (0.0,)
    assert (window.rejected, window.total) == (3, 1)
    assert window.estimate() == 0.0


def test_mode_boundaries_are_geometric_means() -> None:
    assert mode_boundaries((1.0, 12.0)) == pytest.approx((math.sqrt(12),))
    assert mode_boundaries((1.0, 4.0, 16.0)) == (2.0, 8.0)
    assert mode_boundaries((1e200, 1e300)) == pytest.approx((1e250,))  # no overflow


def test_assign_mode_hand_worked() -> None:
    modes = (1.0, 4.0, 16.0)  # boundaries at 2 and 8
    assert [assign_mode(x, modes) for x in (0.0, 1.0, 1.99, 2.0, 7.99, 8.0, 1e9)] == [0, 0, 0, 1, 1, 2, 2]
    gl = (1.0, 12.0)  # nav2d's GL: boundary sqrt(12) = 3.46 ms
    assert [assign_mode(x, gl) for x in (0.3, 3.4, 3.5, 30.0)] == [0, 0, 1, 1]


@untimed
@given(st.one_of(st.just(0.0), st.floats(1e-3, 1e5)), mode_sets)
def test_assign_mode_is_the_nearest_on_a_log_scale(sample: float, modes: tuple[float, ...]) -> None:
    index = assign_mode(sample, modes)
    oracle = nearest_mode_oracle(sample, modes)
    if index != oracle:  # only a rounding-level tie may differ
        assert sample > 0
        log = math.log(sample)
        assert math.isclose(abs(log - math.log(modes[index])), abs(log - math.log(modes[oracle])), abs_tol=1e-9)


def test_split_modes_keeps_order() -> None:
    assert split_modes([1.0, 13.0, 0.9, 11.0], (1.0, 12.0)) == ((1.0, 0.9), (13.0, 11.0))
    # on a boundary (the geometric means 2 and 8), the higher mode
    assert split_modes([8.0, 2.0, 1.99, 7.99], (1.0, 4.0, 16.0)) == ((1.99,), (2.0, 7.99), (8.0,))


@untimed
@given(st.lists(st.one_of(st.just(0.0), st.floats(1e-3, 1e5)), max_size=30), mode_sets)
def test_split_modes_groups_by_assign_mode(samples: list[float], modes: tuple[float, ...]) -> None:
    # assign_mode is held to the log-scale oracle above; split_modes computes the boundaries once
    expected: list[list[float]] = [[] for _ in modes]
    for sample in samples:
        expected[assign_mode(sample, modes)].append(sample)
    assert split_modes(samples, modes) == tuple(tuple(group) for group in expected)


# --------------------------------------------------------------------------- modal estimates


def test_modal_estimate_hand_worked() -> None:
    low = [0.8 + 0.05 * k for k in range(1, 17)]  # 16 samples 0.85 .. 1.6
    high = [10.0, 11.0, 12.0, 14.0]
    # low: h = 15 * 0.95 = 14.25 -> 1.55 + 0.25 * 0.05 = 1.5625
    # high: h = 3 * 0.95 = 2.85 -> 12 + 0.85 * 2 = 13.7
    # weights 16/20 and 4/20: 0.8 * 1.5625 + 0.2 * 13.7 = 1.25 + 2.74 = 3.99
    interleaved = low[:8] + high[:2] + low[8:] + high[2:]
    assert estimate(interleaved, 95, (1.0, 12.0)) == pytest.approx(3.99)
    # The plain p95 of the same window would be ~12.1: the modes matter.
    assert percentile(interleaved, 95) == pytest.approx(12.1)


def test_a_mode_without_samples_contributes_nothing() -> None:
    low = [1.0, 1.2, 0.9, 1.1]  # p95: h = 2.85 -> 1.1 + 0.85 * 0.1 = 1.185
    assert estimate(low, 95, (1.0, 12.0)) == pytest.approx(1.185)
    assert estimate(low, 95, (1.0, 12.0, 100.0)) == pytest.approx(1.185)


def test_nav2d_gl_window_counts_and_eviction() -> None:
    spec = load_spec(NAV2D)
    gl = ComputeWindow.for_node(spec.nodes["GL"], spec.runtime)
    assert gl.modes == (1.0, 12.0)
    assert (gl.window, gl.percentile, gl.bootstrap_ms) == (50, 95, 5)
    assert gl.estimate() == 5
    for _ in range(10):  # evicted by the 50 below
        gl.add(100.0)
    for k in range(50):
        gl.add(12.0 if k % 5 == 0 else 1.0)  # 10 at 12 ms, 40 at 1 ms
    assert len(gl.samples) == 50
    assert gl.estimate() == pytest.approx(0.8 * 1.0 + 0.2 * 12.0)
    snap = gl.snapshot("GL")
    assert snap.modes == (
        ModeStat(ms=1.0, count=40, share=0.8, percentile_ms=1.0),
        ModeStat(ms=12.0, count=10, share=0.2, percentile_ms=12.0),
    )
    assert (snap.count, snap.total, snap.rejected, snap.last_ms) == (50, 60, 0, 1.0)


def test_duplicate_or_single_modes_mean_unimodal() -> None:
    assert ComputeWindow(modes=[3.0, 3.0]).modes == ()
    assert ComputeWindow(modes=[3.0, 3.0, 9.0]).modes == (3.0, 9.0)
    with pytest.raises(ValueError, match="mode times"):
        ComputeWindow(modes=[0.0, 1.0])
    with pytest.raises(ValueError, match="window"):
        ComputeWindow(window=0)


# --------------------------------------------------------------------------- properties


def filled(samples: list[float], size: int, q: float, modes: tuple[float, ...] = ()) -> ComputeWindow:
    window = ComputeWindow(window=size, percentile=q, modes=modes)
    for x in samples:
        assert window.add(x)
    return window


@untimed
@given(st.lists(samples_ms, min_size=1, max_size=120), windows, percentiles, st.one_of(st.just(()), mode_sets))
def test_estimate_lies_within_the_window(samples: list[float], size: int, q: float, modes: tuple[float, ...]) -> None:
    window = filled(samples, size, q, modes)
    kept = window.samples
    assert len(kept) == min(size, len(samples))
    assert kept == tuple(samples[-size:])
    assert min(kept) <= window.estimate() <= max(kept)


@untimed
@given(st.lists(samples_ms, max_size=120), windows, percentiles, st.one_of(st.just(()), mode_sets))
def test_estimate_depends_only_on_the_last_window_samples(
    samples: list[float], size: int, q: float, modes: tuple[float, ...]
) -> None:
    everything = filled(samples, size, q, modes)
    last_only = filled(samples[-size:], size, q, modes)
    assert everything.estimate() == last_only.estimate()
    assert len(everything.samples) <= size


@untimed
@given(st.lists(samples_ms, min_size=1, max_size=120), windows, percentiles, mode_sets)
def test_modal_estimate_matches_the_log_distance_oracle(
    samples: list[float], size: int, q: float, modes: tuple[float, ...]
) -> None:
    samples = [x for x in samples if not near_tie(x, modes)]
    if not samples:
        return
    window = filled(samples, size, q, modes)
    expected = modal_oracle(list(window.samples), q, modes)
    assert math.isclose(window.estimate(), expected, rel_tol=1e-9, abs_tol=1e-12)


@untimed
@given(samples_ms, st.integers(1, 80), windows, percentiles, st.one_of(st.just(()), mode_sets))
def test_constant_samples_give_that_value(x: float, count: int, size: int, q: float, modes: tuple[float, ...]) -> None:
    assert filled([x] * count, size, q, modes).estimate() == x


@untimed
@given(st.lists(samples_ms, min_size=1, max_size=80), windows, percentiles, st.floats(1e-3, 1e3))
def test_scaling_unimodal_samples_scales_the_estimate(samples: list[float], size: int, q: float, k: float) -> None:
    base = filled(samples, size, q).estimate()
    scaled = filled([k * x for x in samples], size, q).estimate()
    assert math.isclose(scaled, k * base, rel_tol=1e-9, abs_tol=1e-300)


@untimed
@given(st.lists(samples_ms, min_size=1, max_size=80), windows, percentiles, mode_sets, st.integers(-20, 20))
def test_scaling_modal_samples_and_modes_scales_the_estimate(
    samples: list[float], size: int, q: float, modes: tuple[float, ...], power: int
) -> None:
    # Mode centres come from the spec, so a modal node scales when its profile scales too
    # (a log-scale distance is then unchanged).  Powers of two keep every step exact.
    k = 2.0**power
    base = filled(samples, size, q, modes).estimate()
    scaled = filled([k * x for x in samples], size, q, tuple(k * m for m in modes)).estimate()
    assert math.isclose(scaled, k * base, rel_tol=1e-12)


def test_scaling_samples_alone_moves_them_between_fixed_modes() -> None:
    # The converse is not a property: with fixed centres 1 and 12, samples 1 and 12 scaled
    # by 10 all fall in the 12 ms mode (10 is nearer 12 than 1 on a log scale).
    samples = [1.0] * 8 + [12.0] * 2
    assert estimate(samples, 95, (1.0, 12.0)) == pytest.approx(3.2)
    assert estimate([10 * x for x in samples], 95, (1.0, 12.0)) == pytest.approx(120.0)


# --------------------------------------------------------------------------- all nodes of a spec


def test_measurements_for_nav2d() -> None:
    spec = load_spec(NAV2D)
    measurements = Measurements.for_spec(spec)
    assert measurements.nodes == ("GL", "GM", "GP", "LM", "LP", "NC", "scan")
    assert measurements.estimates() == dict.fromkeys(measurements.nodes, 5.0)
    assert measurements.estimates(measured_only=True) == {}
    assert measurements.record("GP", 80.0)
    assert not measurements.record("GP", math.nan)
    assert measurements.estimates(measured_only=True) == {"GP": 80.0}
    snap = measurements.snapshot()
    assert snap["GP"].as_dict() == {
        "node": "GP",
        "count": 1,
        "total": 1,
        "rejected": 1,
        "last_ms": 80.0,
        "percentile_ms": 80.0,
        "estimate_ms": 80.0,
        "modes": [],
    }
    assert snap["GL"].count == 0
    assert snap["GL"].last_ms is None
    assert [m.ms for m in snap["GL"].modes] == [1.0, 12.0]
    assert all(m.share == 0 and m.percentile_ms is None for m in snap["GL"].modes)


def test_recording_an_unmeasured_node_is_an_error() -> None:
    measurements = Measurements.for_spec(load_spec(NAV2D))
    with pytest.raises(UsageError, match=r"'odom': not a scheduled node"):
        measurements.record("odom", 1.0)
    with pytest.raises(UsageError, match=r"did you mean 'LM'"):
        measurements.record("LN", 1.0)


def test_estimates_feed_the_replanner() -> None:
    spec = load_spec(NAV2D)
    measurements = Measurements.for_spec(spec)
    for k in range(50):
        measurements.record("GL", 12.0 if k % 5 == 0 else 1.0)
        measurements.record("scan", 0.0)  # a zero sample: planned at the floor
        measurements.record("GP", 60.0 + k)
    estimates = measurements.estimates()
    assert estimates["scan"] == MIN_PLANNING_MS
    assert estimates["GL"] == pytest.approx(3.2)
    replanner = Replanner(spec, 1)
    plan = replanner.resolve(estimates)
    assert plan.cores == 1
    assert dict(zip(*_nodes_and_times(replanner), strict=True))["GL"] == pytest.approx(3.2)


def _nodes_and_times(replanner: Replanner) -> tuple[list[str], list[float]]:
    subchains = replanner.problem.subchains
    nodes = [n for sub in subchains for n in sub.nodes]
    times = [c for sub in subchains for c in sub.node_compute_ms]
    return nodes, times


MODAL_SPEC = """
catan: 1
app: twonodes
runtime: {window: 5, percentile: 90, bootstrap_ms: 2}
nodes:
  a: {compute_ms: 3}
  b: {compute_ms: {modes: [{share: 0.5, ms: 1}, {share: 0.5, ms: 10}]}}
  sink: {scheduled: false}
edges: [[a, b], [b, sink]]
subchains: {sa: [a], sb: [b]}
objective: [{chain: [a, b, sink], weight: 1}]
"""


def modal_spec() -> Spec:
    return parse_spec(MODAL_SPEC, "twonodes.yaml")


class MeasurementsMachine(RuleBasedStateMachine):
    """Measurements against a plain-list model, with numpy and the log-distance oracle."""

    def __init__(self) -> None:
        super().__init__()
        self.measurements = Measurements.for_spec(modal_spec())
        self.model: dict[str, list[float]] = {"a": [], "b": []}
        self.rejected = {"a": 0, "b": 0}

    @rule(node=st.sampled_from(["a", "b"]), x=samples_ms)
    def record_valid(self, node: str, x: float) -> None:
        assert self.measurements.record(node, x)
        self.model[node].append(x)

    @rule(node=st.sampled_from(["a", "b"]), x=st.sampled_from([math.nan, math.inf, -math.inf, -1.0, -1e-9]))
    def record_invalid(self, node: str, x: float) -> None:
        assert not self.measurements.record(node, x)
        self.rejected[node] += 1

    @invariant()
    def agrees_with_the_model(self) -> None:
        snapshot = self.measurements.snapshot()
        estimates = self.measurements.estimates()
        for node, history in self.model.items():
            window = history[-5:]
            snap = snapshot[node]
            assert (snap.count, snap.total, snap.rejected) == (len(window), len(history), self.rejected[node])
            assert snap.last_ms == (window[-1] if window else None)
            if not window:
                expected = 2.0
            elif node == "a":
                expected = float(np.percentile(window, 90))
            else:
                expected = modal_oracle(window, 90, (1.0, 10.0))
            assert math.isclose(snap.estimate_ms, expected, rel_tol=1e-9, abs_tol=1e-12)
            assert estimates[node] == max(snap.estimate_ms, MIN_PLANNING_MS)
            if node == "b" and window:
                assert math.isclose(sum(m.share for m in snap.modes), 1.0)
                assert sum(m.count for m in snap.modes) == len(window)


MeasurementsMachine.TestCase.settings = settings(max_examples=50, stateful_step_count=30, deadline=None)
TestMeasurementsMachine = MeasurementsMachine.TestCase


def test_concurrent_recording_and_reading() -> None:
    """Writers on several threads while a reader polls: nothing is lost, every read is consistent."""
    measurements = Measurements.for_spec(modal_spec())
    writers, per_writer = 4, 500
    values = {"a": (1.0, 2.0, 3.0), "b": (1.0, 10.0)}
    done = threading.Event()
    problems: list[str] = []

    def write(seed: int) -> None:
        for k in range(per_writer):
            node = "a" if (seed + k) % 2 else "b"
            measurements.record(node, values[node][k % len(values[node])])
            if k % 50 == 0:
                measurements.record(node, math.nan)

    def read() -> None:
        while not done.is_set():
            for node, snap in measurements.snapshot().items():
                if snap.count and not min(values[node]) <= snap.estimate_ms <= max(values[node]):
                    problems.append(f"{node}: {snap.estimate_ms}")
                if snap.count > 5:
                    problems.append(f"{node}: window of {snap.count}")
            measurements.estimates()

    reader = threading.Thread(target=read)
    reader.start()
    threads = [threading.Thread(target=write, args=(seed,)) for seed in range(writers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    done.set()
    reader.join()
    assert problems == []
    snapshot = measurements.snapshot()
    assert sum(snap.total for snap in snapshot.values()) == writers * per_writer
    assert sum(snap.rejected for snap in snapshot.values()) == writers * (per_writer // 50)


# --------------------------------------------------------------------------- the kernel's figure


def test_parse_schedstat() -> None:
    assert parse_schedstat("30519373 5730774 61\n") == 30519373
    for bad in ("", "abc 1 2", "-5 1 2"):
        with pytest.raises(ValueError, match="schedstat"):
            parse_schedstat(bad)


def test_cpu_clock_reads_the_first_field(tmp_path: Path) -> None:
    assert schedstat_path(12, 34) == Path("/proc/12/task/34/schedstat")
    clock = CpuClock(pid=12, tid=34, proc=tmp_path)
    assert clock.path == tmp_path / "12" / "task" / "34" / "schedstat"
    clock.path.parent.mkdir(parents=True)
    clock.path.write_text("2500000 999 3\n", encoding="ascii")
    assert clock.read_ns() == 2_500_000
    with pytest.raises(FileNotFoundError):
        CpuClock(pid=12, tid=35, proc=tmp_path).read_ns()


def test_open_cpu_clocks_read_again_on_each_call_and_fail_once_the_thread_is_gone(tmp_path: Path) -> None:
    clocks = OpenCpuClocks(proc=tmp_path)
    path = schedstat_path(12, 34, tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text("2500000 999 3\n", encoding="ascii")
    assert clocks.read_ns(12, 34) == 2_500_000
    with path.open("r+", encoding="ascii") as same_file:  # same inode: the kept descriptor sees it
        same_file.write("7500000 999 4\n")
    assert clocks.read_ns(12, 34) == 7_500_000
    with pytest.raises(FileNotFoundError):
        clocks.read_ns(12, 35)

    finished = threading.Event()
    worker = threading.Thread(target=finished.wait)
    worker.start()
    tid = worker.native_id
    assert tid is not None
    live = OpenCpuClocks()
    try:
        first = live.read_ns(os.getpid(), tid)
        assert first <= CpuClock(os.getpid(), tid).read_ns()
    finally:
        finished.set()
        worker.join()
    # join() returns just before the kernel ends the thread: allow it a moment. Then the descriptor,
    # which still names the exited thread, fails instead of reading another thread's count.
    deadline = time.monotonic() + 3.0
    failed: OSError | None = None
    while failed is None and time.monotonic() < deadline:
        try:
            live.read_ns(os.getpid(), tid)
        except OSError as exc:
            failed = exc
        time.sleep(0.01)
    assert isinstance(failed, ProcessLookupError), failed
    live.close()
    clocks.close()


def test_open_cpu_clocks_read_opened_threads_only(tmp_path: Path) -> None:
    """The enforcer's loop reads only what registration opened: an unopened thread is no path lookup but None."""
    clocks = OpenCpuClocks(proc=tmp_path)
    path = schedstat_path(12, 34, tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text("2500000 999 3\n", encoding="ascii")
    assert clocks.read_opened_ns(34) is None
    assert clocks.open(12, 34)
    path.unlink()  # were it looked up again, it would be missing
    assert clocks.read_opened_ns(34) == 2_500_000
    assert not clocks.open(12, 35)  # no such thread
    assert clocks.read_opened_ns(35) is None
    assert not clocks.open(12, 34)  # reopened: gone now, and its old descriptor is closed
    assert clocks.read_opened_ns(34) is None
    clocks.close()


def test_cpu_ms() -> None:
    assert cpu_ms(1_000_000, 3_500_000) == 2.5
    assert cpu_ms(7, 7) == 0.0
    with pytest.raises(ValueError, match="backwards"):
        cpu_ms(2, 1)


def test_schedstat_follows_a_busy_thread() -> None:
    """The kernel's count for a thread that burns ~20 ms of CPU is near thread_time's (parses the right field)."""
    tid_box: list[int] = []
    burned: list[float] = []
    ready, go, finished, release = threading.Event(), threading.Event(), threading.Event(), threading.Event()

    def burn() -> None:
        tid_box.append(threading.get_native_id())
        ready.set()
        go.wait()
        start = time.thread_time()
        while time.thread_time() - start < 0.020:
            pass
        burned.append((time.thread_time() - start) * 1000)
        finished.set()
        release.wait()  # stay alive (and off the CPU) while the main thread reads

    worker = threading.Thread(target=burn)
    worker.start()
    try:
        ready.wait()
        clock = CpuClock(pid=os.getpid(), tid=tid_box[0])
        if not clock.path.exists():
            pytest.skip(f"{clock.path} is missing (kernel without CONFIG_SCHED_INFO?)")
        before = clock.read_ns()
        go.set()
        finished.wait()
        after = clock.read_ns()
    finally:
        go.set()
        release.set()
        worker.join()
    kernel = cpu_ms(before, after)
    assert burned[0] * 0.5 <= kernel <= burned[0] * 1.5


def test_reconcile_hand_worked() -> None:
    # Within max(0.05 ms, 10% of the kernel's): the client's figure.
    assert reconcile(10.9, 10.0) == 10.9
    assert reconcile(9.1, 10.0) == 9.1
    assert reconcile(0.24, 0.2) == 0.24  # 0.04 ms apart: under the 0.05 ms floor
    # Above: the kernel's (wall-clock that includes preemption, or a lie).
    assert reconcile(15.0, 12.0) == 12.0
    assert reconcile(0.26, 0.2) == 0.2  # 0.06 ms above: over the 0.05 ms floor
    # Below by up to the client's own work per run (0.5 ms) more: the client's.
    assert reconcile(0.2, 0.5) == 0.2  # the kernel counted 0.3 ms of the client's own work too
    assert reconcile(0.2, 0.75) == 0.2  # 0.55 ms below: 0.5 + the 0.05 ms floor, just
    assert reconcile(10.0, 11.5) == 10.0  # 1.5 ms below: 0.5 + 10% of 11.5 ms = 1.65 ms allowed
    # Further below: CPU the thread used that the client did not report, the kernel's.
    assert reconcile(0.2, 0.8) == 0.8
    assert reconcile(5.0, 12.0) == 12.0
    assert reconcile(0.2, 0.5, client_ms=0.0) == 0.5  # no allowance for the client's work: as before issue 32
    # Only one usable figure: that one.
    assert reconcile(3.0, None) == 3.0
    assert reconcile(3.0, math.nan) == 3.0
    assert reconcile(math.nan, 4.0) == 4.0
    assert reconcile(-1.0, 4.0) == 4.0
    assert math.isnan(reconcile(math.nan, None))  # and Measurements.record then rejects it
    assert reconcile(15.0, 12.0, rel_tol=0.5) == 15.0


@untimed
@given(samples_ms, samples_ms, st.floats(0, 1), st.floats(0, 10), st.floats(0, 10))
def test_reconcile_keeps_the_clients_figure_exactly_where_the_kernel_makes_it_plausible(
    reported: float, kernel: float, rel_tol: float, abs_tol: float, client: float
) -> None:
    chosen = reconcile(reported, kernel, rel_tol=rel_tol, abs_tol_ms=abs_tol, client_ms=client)
    tol = max(abs_tol, rel_tol * kernel)
    plausible = kernel - client - tol <= reported <= kernel + tol
    assert chosen == (reported if plausible else kernel)
    assert kernel - client - tol <= chosen <= kernel + tol  # never more than the kernel counted, nor far below it
