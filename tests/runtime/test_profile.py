"""``catanc profile``'s core: hand-made logs with known samples give known p95s, modes and speedups.

Oracles: percentiles worked by hand from the documented definition (linear interpolation
between closest ranks), mode splits built in (clusters far apart, or a range too narrow for
any gap), and the bad logs the issue names.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.errors import ExitCode
from catanc.model.load import parse_spec
from catanc.runtime.logs.samples import MeasurementsError, read_samples
from catanc.runtime.profile.propose import (
    MIN_SAMPLES,
    deviations,
    find_modes,
    format_ms,
    profile_spec,
    propose,
    round_shares,
)
from tests.support.run_logs import SPEC, every_node, log_text

# --------------------------------------------------------------------------- known samples, known answers


def test_the_p95_of_1_to_100_is_95_05() -> None:
    """Worked by hand: h = 99 * 0.95 = 94.05, x[94] = 95, x[95] = 96: 95 + 0.05 * 1 = 95.05."""
    measured = read_samples(log_text(*every_node(cam=[float(i) for i in range(100, 0, -1)])), "run.jsonl")
    proposal = propose(parse_spec(SPEC), measured)["cam"]
    assert proposal.ms == 95.05
    assert proposal.modes == ()
    assert proposal.count == 100


def test_the_spec_percentile_is_the_one_proposed() -> None:
    """runtime.percentile 50 on 1..100: h = 49.5, 50 + 0.5 = 50.5."""
    spec = parse_spec(SPEC + "runtime: {percentile: 50}\n")
    measured = read_samples(log_text(*every_node(cam=[float(i) for i in range(1, 101)])), "run.jsonl")
    assert propose(spec, measured)["cam"].ms == 50.5


def test_two_clusters_are_two_modes_with_their_shares_and_p95s() -> None:
    """80 runs at 1 ms, 20 at 12 ms: modes 0.8 x 1 and 0.2 x 12; planned 0.8 + 2.4 = 3.2 ms."""
    measured = read_samples(log_text(*every_node(det=[1.0] * 80 + [12.0] * 20)), "run.jsonl")
    proposal = propose(parse_spec(SPEC), measured)["det"]
    assert [(m.share, m.ms, m.count) for m in proposal.modes] == [(0.8, 1.0, 80), (0.2, 12.0, 20)]
    assert proposal.planning_ms == pytest.approx(3.2)


def test_stray_samples_between_two_modes_do_not_hide_them() -> None:
    """80 runs at 1 ms, 20 at 12, strays at 2, 3.5 and 6 ms.  Worked by hand: the runtime's boundary between the
    modes' p95s (1 and 12) is sqrt(12) = 3.46, so 2 goes low (81 samples: p95 x[76] = 1) and 3.5, 6 high
    (22 samples: p95 between x[19] = x[20] = 12); shares 81/103 = 0.786 and 22/103 = 0.214 round to 0.79 and 0.21."""
    measured = read_samples(log_text(*every_node(det=[1.0] * 80 + [12.0] * 20 + [2.0, 3.5, 6.0])), "run.jsonl")
    proposal = propose(parse_spec(SPEC), measured)["det"]
    assert [(m.share, m.ms, m.count) for m in proposal.modes] == [(0.79, 1.0, 81), (0.21, 12.0, 22)]


def test_a_rare_spike_is_no_mode() -> None:
    """2 of 100 runs at 50 ms: under 5% of the samples, so no mode; the p95 (x[94] = x[95] = 1) is 1."""
    measured = read_samples(log_text(*every_node(cam=[1.0] * 98 + [50.0] * 2)), "run.jsonl")
    proposal = propose(parse_spec(SPEC), measured)["cam"]
    assert proposal.modes == ()
    assert proposal.ms == 1.0


def test_a_gap_under_twice_is_no_mode() -> None:
    measured = read_samples(log_text(*every_node(cam=[1.0] * 50 + [1.9] * 50)), "run.jsonl")
    assert propose(parse_spec(SPEC), measured)["cam"].modes == ()


def test_speedup_is_the_ratio_of_one_thread_to_two_thread_p95s() -> None:
    """20 one-thread runs of 10 ms, 20 two-thread runs whose own (wall) time is 5.5 ms: 10 / 5.5 = 1.82."""
    ms = [10.0] * 20 + [8.25] * 20  # the enforcer's one-thread figure: 5.5 x the spec's 1.5
    threads = [1] * 20 + [2] * 20
    walls: list[float | None] = [*([10.0] * 20), *([5.5] * 20)]
    batches = [*every_node()[:2], ("plan", ms, threads, walls)]
    proposal = propose(parse_spec(SPEC), read_samples(log_text(*batches), "run.jsonl"))["plan"]
    assert proposal.speedups == (1.0, 1.82)
    assert proposal.ms == 10.0  # from the one-thread runs only
    assert proposal.threads == {1: 20, 2: 20}


def test_without_one_thread_runs_no_speedup_is_measured() -> None:
    batches = [*every_node()[:2], ("plan", [9.0] * 20, [2] * 20, [6.0] * 20)]
    proposal = propose(parse_spec(SPEC), read_samples(log_text(*batches), "run.jsonl"))["plan"]
    assert proposal.speedups == (1.0, None)
    assert proposal.ms == 9.0
    assert any("one-thread runs" in note for note in proposal.notes)


def test_deviations_name_the_nodes_beyond_the_tolerance() -> None:
    """cam measured 5.5 ms for 5: +10%; plan 13 for 10: +30%."""
    measured = read_samples(log_text(*every_node(cam=[5.5] * 20, plan=[13.0] * 20)), "run.jsonl")
    spec = parse_spec(SPEC, "demo.yaml")
    proposals = propose(spec, measured)
    assert deviations(spec, proposals, 0.15) == [
        "demo.yaml:7:10: nodes.plan.compute_ms: 10 ms planned, 13 ms measured (+30%, more than 15% off)"
    ]
    assert len(deviations(spec, proposals, 0.05)) == 2
    assert deviations(spec, proposals, 0.31) == []


# --------------------------------------------------------------------------- properties


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(min_value=1.0, max_value=1.99), min_size=1, max_size=300), st.floats(0.01, 100.0))
def test_samples_within_a_factor_of_two_never_split(samples: list[float], scale: float) -> None:
    """No sorted sample can be twice the one before it when the largest is under twice the smallest."""
    assert len(find_modes([s * scale for s in samples])) == 1


@settings(max_examples=200, deadline=None)
@given(
    low=st.floats(0.01, 100.0),
    far=st.floats(2.5, 50.0),
    counts=st.tuples(st.integers(5, 200), st.integers(5, 200)),
    spread=st.lists(st.floats(0.0, 0.1), min_size=400, max_size=400),
)
def test_two_clusters_far_apart_are_found(low: float, far: float, counts: tuple[int, int], spread: list[float]) -> None:
    """Clusters [low, 1.1 low] and [h, 1.1 h] with h >= 2.5 x 1.1 low, each >= 5 samples and >= 5%."""
    first, second = counts
    total = first + second
    if min(first, second) < 0.05 * total:
        return
    high = far * 1.1 * low
    a = [low * (1 + spread[i]) for i in range(first)]
    b = [high * (1 + spread[200 + i]) for i in range(second)]
    groups = find_modes(a + b)
    assert [len(g) for g in groups] == [first, second]
    assert sorted(groups[0]) == sorted(a)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.05, 1.0), min_size=1, max_size=6))
def test_rounded_shares_sum_to_one_and_stay_within_a_hundredth(weights: list[float]) -> None:
    total = math.fsum(weights)
    shares = [w / total for w in weights]
    rounded = round_shares(shares)
    assert math.fsum(rounded) == pytest.approx(1.0, abs=1e-9)
    assert all(abs(r - s) < 0.01 + 1e-9 for r, s in zip(rounded, shares, strict=True))


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=0.001, max_value=1e6))
def test_a_written_time_has_four_significant_digits_and_reads_back(ms: float) -> None:
    text = format_ms(ms)
    assert "e" not in text.lower()
    assert float(text) == pytest.approx(ms, rel=5e-4)


def test_what_the_kernel_counted_is_reported_beside_the_proposal() -> None:
    # cam: 20 runs the client timed at 5 ms; the kernel checked 5 of them, counting 0.3 ms more
    # on four (the client's own work: its figure kept) and 4 ms more on one (its count stood in).
    own = [5.0] * 20
    kernel: list[float | None] = [None] * 20
    kernel[0:5] = [5.3, 5.3, 9.0, 5.3, 5.3]
    ms = [k if k == 9.0 else o for o, k in zip(own, kernel, strict=True)]
    batches = every_node()
    batches[0] = ("cam", ms, None, own)
    spec = parse_spec(SPEC, "demo.yaml")
    measured = read_samples(log_text(*batches, kernels={"cam": kernel}), "run.jsonl")
    proposals = propose(spec, measured)
    kernel_check = proposals["cam"].kernel
    assert kernel_check is not None
    assert (kernel_check.runs, kernel_check.replaced) == (5, 1)
    assert kernel_check.extra_ms == pytest.approx(0.3)
    assert proposals["det"].kernel is None  # nothing checked
    result = profile_spec(SPEC, "demo.yaml", log_text(*batches, kernels={"cam": kernel}), "run.jsonl", tolerance=1.0)
    cam = [line for line in result.summary if line.lstrip().startswith("cam:")]
    assert "5 runs checked by the kernel: +0.300 ms a run over the node's own figure" in cam[0]
    assert "the kernel's count stood in for the node's own figure on 1 of 5 checked runs" in cam[1]


# --------------------------------------------------------------------------- bad logs


def error_of(text: str) -> str:
    with pytest.raises(MeasurementsError) as caught:
        propose(parse_spec(SPEC, "demo.yaml"), read_samples(text, "run.jsonl"))
    assert caught.value.exit_code == ExitCode.BAD_INPUT
    return str(caught.value)


def test_a_torn_last_line_is_a_truncated_log() -> None:
    text = log_text(*every_node(), stop=False)
    torn = text + '{"t": 3.0, "event": "compute_ba'
    lines = torn.count("\n") + 1
    assert error_of(torn) == (
        f"run.jsonl:{lines}: a torn last line: the run was killed while writing (the log is truncated or corrupt)"
    )


def test_a_log_without_its_stop_is_truncated() -> None:
    message = error_of(log_text(*every_node(), stop=False))
    assert message.startswith("run.jsonl:4: truncated: the log ends without the enforcer's stop event")


def test_a_corrupt_line_is_named() -> None:
    lines = log_text(*every_node()).splitlines(keepends=True)
    lines[2] = "not json\n"
    assert error_of("".join(lines)).startswith("run.jsonl:3: not a JSON object")


@pytest.mark.parametrize(
    ("fmt", "expected"),
    [
        (None, "run.jsonl:1: log format missing: written by an older catanc (this one reads format 1)"),
        (2, "run.jsonl:1: log format 2: this catanc reads format 1"),
    ],
)
def test_another_format_is_refused(fmt: object, expected: str) -> None:
    assert error_of(log_text(*every_node(), fmt=fmt)).startswith(expected)


def test_a_node_without_samples_is_named_with_its_line() -> None:
    batches = every_node()
    message = error_of(log_text(batches[0], ("det", [1.0] * (MIN_SAMPLES - 1), None, None)))
    assert "demo.yaml:5:3: nodes.det: only 9 compute samples in run.jsonl" in message
    assert "demo.yaml:7:3: nodes.plan: no compute samples in run.jsonl" in message


def test_not_a_log_at_all() -> None:
    assert error_of("") == "run.jsonl: empty: not a catanc run log"
    assert error_of('{"event": "run"}\n').startswith("run.jsonl:1: the log does not begin with a start event")


# --------------------------------------------------------------------------- the whole command's core


def test_profile_spec_writes_what_it_proposes_and_keeps_the_rest() -> None:
    log = log_text(*every_node(cam=[6.0] * 20, det=[1.0] * 80 + [12.0] * 20, plan=[11.0] * 20))
    result = profile_spec(SPEC, "demo.yaml", log, "run.jsonl", tolerance=0.15)
    expected = SPEC.replace("{compute_ms: 5}          #", "{compute_ms: 6}          #")
    expected = expected.replace(
        "{share: 0.5, ms: 2}, {share: 0.5, ms: 20}", "{share: 0.8, ms: 1}, {share: 0.2, ms: 12}"
    )
    expected = expected.replace("compute_ms: 10,", "compute_ms: 11,")
    assert result.text == expected
    assert result.diff.startswith("--- a/demo.yaml\n+++ b/demo.yaml\n")
    again = profile_spec(result.text, "demo.yaml", log, "run.jsonl", tolerance=0.0)
    assert again.text == result.text
    assert again.diff == ""
    assert again.off == ()


# --------------------------------------------------------------------------- hops


EDGES = "edges: [[cam, det], [det, plan], [plan, motor]]\n"


def _hop_spec(hops: str) -> str:
    """The demo spec with ``hops`` (YAML lines) right after its edges."""
    return SPEC.replace(EDGES, EDGES + hops)


# cam -> det measured at p95 1.23456 ms over 40 hops (4 digits: 1.235), det -> plan at 0.04321 (0.0432: at most
# 4 decimals, as the log keeps them); plan -> motor is no edge inside a subchain (never proposed).
MEASURED = {"cam -> det": (1.23456, 40), "det -> plan": (0.04321, 12), "plan -> motor": (9.0, 50)}


@pytest.mark.parametrize(
    ("written", "expected"),
    [
        # none yet: a block at the end of the file
        ("", "hops_ms:\n  cam -> det: 1.235\n  det -> plan: 0.0432\n"),
        # a flow mapping: new keys before its brace, the given one rewritten where it is
        ("hops_ms: {cam -> det: 0.5}   # measured\n", "hops_ms: {cam -> det: 1.235, det -> plan: 0.0432} # measured\n"),
        ("hops_ms: {}\n", "hops_ms: {cam -> det: 1.235, det -> plan: 0.0432}\n"),
        # a block mapping: new keys after its last, at its indent; a comment after a value stays in its column
        (
            "hops_ms:\n    det->plan: 2      # by hand\n",
            "hops_ms:\n    det->plan: 0.0432 # by hand\n    cam -> det: 1.235\n",
        ),
    ],
)
def test_profile_writes_each_measured_hop_inside_a_subchain_and_keeps_the_rest(written: str, expected: str) -> None:
    spec = _hop_spec(written)
    log = log_text(*every_node(), hops=MEASURED)
    result = profile_spec(spec, "demo.yaml", log, "run.jsonl", tolerance=0.15)
    assert result.hops == {("cam", "det"): 1.235, ("det", "plan"): 0.0432}
    want = spec.replace(written, "") + expected if not written else spec.replace(written, expected)
    assert result.text == want
    assert parse_spec(result.text).hops_ms  # reads back as a valid spec
    again = profile_spec(result.text, "demo.yaml", log, "run.jsonl", tolerance=0.0)
    assert again.text == result.text
    assert again.off == ()


def test_too_few_hops_are_not_proposed_and_check_flags_a_hop_off_by_more_than_both_tolerances() -> None:
    log = log_text(*every_node(), hops={"cam -> det": (1.5, 40), "det -> plan": (3.0, MIN_SAMPLES - 1)})
    # cam -> det: 1.5 measured against 1.2 written: 0.3 ms off, 25% > 15%: off.
    result = profile_spec(_hop_spec("hops_ms: {cam -> det: 1.2}\n"), "demo.yaml", log, "run.jsonl", tolerance=0.15)
    assert result.hops == {("cam", "det"): 1.5}
    assert [line for line in result.off if "hops_ms" in line] == [
        "demo.yaml:10:11: hops_ms.cam -> det: 1.2 ms planned, 1.5 ms measured (more than 15% and 0.1 ms off)"
    ]
    # 1.26 written: 0.24 ms off but only 19% of it: off at 15%, not at 20%.
    near = _hop_spec("hops_ms: {cam -> det: 1.26}\n")
    assert any("hops_ms" in line for line in profile_spec(near, "d.yaml", log, "r", tolerance=0.15).off)
    assert not any("hops_ms" in line for line in profile_spec(near, "d.yaml", log, "r", tolerance=0.2).off)
    # A spec without hops against catanc's own trigger hop of 0.06 ms: within 0.1 ms, no drift.
    small = log_text(*every_node(), hops={"cam -> det": (0.06, 40)})
    assert not any("hops_ms" in line for line in profile_spec(SPEC, "d.yaml", small, "r", tolerance=0.15).off)


# --------------------------------------------------------------------------- dispatches


# cam (main's head) measured at p95 2.41234 ms over 900 triggers (4 digits: 2.412); det is no head (never
# proposed, though a log said so).
DISPATCHES = {"cam": (2.41234, 900), "det": (5.0, 50)}


@pytest.mark.parametrize(
    ("written", "expected"),
    [
        # none yet: a block at the end of the file
        ("", "dispatch_ms:\n  cam: 2.412\n"),
        # given: rewritten where it is, its comment kept
        ("dispatch_ms: {cam: 0.12}   # measured\n", "dispatch_ms: {cam: 2.412}  # measured\n"),
        ("dispatch_ms: {}\n", "dispatch_ms: {cam: 2.412}\n"),
    ],
)
def test_profile_writes_each_heads_measured_dispatch(written: str, expected: str) -> None:
    spec = _hop_spec(written)
    log = log_text(*every_node(), dispatches=DISPATCHES)
    result = profile_spec(spec, "demo.yaml", log, "run.jsonl", tolerance=0.15)
    assert result.dispatches == {"cam": 2.412}
    want = spec.replace(written, "") + expected if not written else spec.replace(written, expected)
    assert result.text == want
    assert parse_spec(result.text).dispatch_ms == {"cam": 2.412}
    assert "  dispatch cam: 900 samples; spec " in "\n".join(result.summary)
    again = profile_spec(result.text, "demo.yaml", log, "run.jsonl", tolerance=0.0)
    assert again.text == result.text
    assert again.off == ()


def test_too_few_dispatches_are_not_proposed_and_check_flags_one_off_by_more_than_both_tolerances() -> None:
    few = log_text(*every_node(), dispatches={"cam": (2.0, MIN_SAMPLES - 1)})
    assert profile_spec(SPEC, "d.yaml", few, "r", tolerance=0.15).dispatches == {}
    log = log_text(*every_node(), dispatches={"cam": (0.7, 40)})
    # 0.5 planned against 0.7 measured: 40% and 0.2 ms off, over both 15% and 0.1 ms.
    result = profile_spec(_hop_spec("dispatch_ms: {cam: 0.5}\n"), "demo.yaml", log, "run.jsonl", tolerance=0.15)
    assert [line for line in result.off if "dispatch_ms" in line] == [
        "demo.yaml:10:15: dispatch_ms.cam: 0.5 ms planned, 0.7 ms measured (more than 15% and 0.1 ms off)"
    ]
    # 0.65 against 0.7: 7.7% and 0.05 ms off: within both.
    near = _hop_spec("dispatch_ms: {cam: 0.65}\n")
    assert not any("dispatch_ms" in line for line in profile_spec(near, "d.yaml", log, "r", tolerance=0.15).off)
    # None in the spec against a plain client's 0.06 ms: within 0.1 ms, no drift; against 0.7 ms, off.
    small = log_text(*every_node(), dispatches={"cam": (0.06, 40)})
    assert not any("dispatch_ms" in line for line in profile_spec(SPEC, "d.yaml", small, "r", tolerance=0.15).off)
    assert any(
        "dispatch_ms.cam: 0 ms planned" in line for line in profile_spec(SPEC, "d.yaml", log, "r", tolerance=0.15).off
    )


def test_a_head_sharing_its_thread_with_another_subchain_gets_no_dispatch() -> None:
    # cam and a second head, radar, in one executor thread: radar's trigger waits for cam's runs there, so
    # neither delay is a dispatch; the summary says why.
    spec = SPEC.replace("  motor: {scheduled: false}\n", "  motor: {scheduled: false}\n  radar: {compute_ms: 1}\n")
    spec = spec.replace(EDGES, "edges: [[cam, det], [det, plan], [plan, motor], [radar, motor]]\n")
    spec = spec.replace("  main: [cam, det, plan]\n", "  main: [cam, det, plan]\n  ranging: [radar]\n")
    spec += "executors: {sensors: [cam, radar]}\n"
    log = log_text(*every_node(), ("radar", [1.0] * 20, None, None), dispatches={"cam": (0.7, 40), "radar": (9.0, 40)})
    result = profile_spec(spec, "demo.yaml", log, "run.jsonl", tolerance=0.15)
    assert result.dispatches == {}
    assert "dispatch_ms" not in result.text
    assert "  dispatch radar: 40 samples, p95 9 ms: not proposed, its thread runs subchain main too" in "\n".join(
        result.summary
    )
