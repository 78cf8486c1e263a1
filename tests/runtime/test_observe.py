"""``catanc run --observe``: runs cut from the kernel's CPU counts, and real processes on their own timers.

Oracles: CPU counts built from known runs (each run's CPU spread over any number of polls,
runs separated by idle polls) must come back as those runs; real processes burning a known
CPU time every period must be measured at it, and left at the scheduling they had.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from catanc.cli import app
from catanc.errors import ExitCode
from catanc.runtime.enforcer.observe import MIN_RUN_MS, Bursts, launched_nodes
from catanc.runtime.profile.propose import profile_spec
from tests.support.enforcer_runs import compile_table

TIMER_NODE = Path(__file__).parents[1] / "support" / "timer_node.py"
runner = CliRunner()


def cut(counts: list[int]) -> list[float]:
    bursts = Bursts()
    return [ms for count in counts if (ms := bursts.poll(count)) is not None]


def test_one_run_is_the_cpu_between_idle_polls() -> None:
    assert cut([0, 0, 1_000_000, 3_000_000, 5_000_000, 5_000_000, 5_000_000]) == [5.0]


def test_a_wake_up_too_small_for_a_run_is_none() -> None:
    assert cut([0, 0, 1_000, 1_000, 1_000]) == []


def test_a_thread_leaving_mid_run_keeps_the_count() -> None:
    """Two threads: 4 ms counted on one that exits, 1 ms then on the other; the run is what was seen (5 ms)."""
    bursts = Bursts()
    assert bursts.poll(10_000_000) is None
    assert bursts.poll(14_000_000) is None  # 4 ms in the run, 10 of it on the thread about to exit
    bursts.rebase(10_000_000)
    assert bursts.poll(5_000_000) is None  # the other thread: 4 -> 5
    assert bursts.poll(5_000_000) == pytest.approx(5.0)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.lists(st.integers(1, 5_000_000), min_size=1, max_size=8),  # a run's CPU per poll while it runs
            st.integers(1, 4),  # idle polls after it
        ),
        max_size=20,
    )
)
def test_runs_separated_by_idle_polls_come_back(runs: list[tuple[list[int], int]]) -> None:
    counts, total, want = [0, 0], 0, []
    for pieces, idle in runs:
        for piece in pieces:
            total += piece
            counts.append(total)
        counts += [total] * idle
        if sum(pieces) / 1e6 >= MIN_RUN_MS:
            want.append(sum(pieces) / 1e6)
    assert cut(counts) == pytest.approx(want)


def test_launched_processes_of_several_nodes_are_not_observed() -> None:
    assert launched_nodes([(["a"], 10), (["b", "c"], 11), ([], 12)]) == ({"a": 10}, [["b", "c"]])


SPEC = """catan: 1
app: timers
nodes:
  fast: {compute_ms: 1}    # a guess
  slow: {compute_ms: 1}    # a guess
edges: [[fast, slow]]
subchains:
  main: [fast, slow]
objective:
  - {chain: [fast, slow], weight: 1.0}
"""


@pytest.fixture
def timer_nodes() -> Iterator[dict[str, subprocess.Popen[bytes]]]:
    started = {
        "fast": subprocess.Popen([sys.executable, str(TIMER_NODE), "2", "15"]),
        "slow": subprocess.Popen([sys.executable, str(TIMER_NODE), "8", "40"]),
    }
    try:
        yield started
    finally:
        for process in started.values():
            process.kill()
            process.wait()


def test_observe_measures_nodes_on_their_own_timers(
    tmp_path: Path, timer_nodes: dict[str, subprocess.Popen[bytes]]
) -> None:
    """fast burns 2 ms every 15 ms, slow 8 ms every 40: the profile says so; their scheduling stays as it was."""
    table = compile_table(SPEC, tmp_path / "out", cores=1)
    before = {node: (os.sched_getscheduler(p.pid), os.sched_getaffinity(p.pid)) for node, p in timer_nodes.items()}
    log = tmp_path / "observe.jsonl"
    attach = [word for node, p in timer_nodes.items() for word in ("--attach", f"{node}={p.pid}")]
    command = [sys.executable, "-m", "catanc", "run", str(table), "--observe", *attach]
    terminal = {**os.environ, "TTY_COMPATIBLE": "1"}  # as on a terminal: a bar of the seconds observed
    done = subprocess.run(
        [*command, "--duration", "3", "--log", str(log)], capture_output=True, timeout=60, check=False, env=terminal
    )
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    assert "observing: " in done.stderr.decode()
    assert " runs" in done.stderr.decode()
    assert b"observing" not in done.stdout  # the bar stays off stdout
    after = {node: (os.sched_getscheduler(p.pid), os.sched_getaffinity(p.pid)) for node, p in timer_nodes.items()}
    assert after == before
    spec = tmp_path / "timers.yaml"
    spec.write_text(SPEC)
    result = profile_spec(SPEC, str(spec), log.read_text(), str(log), tolerance=0.15)
    assert result.proposals["fast"].ms == pytest.approx(2.0, rel=0.15), result.summary
    assert result.proposals["slow"].ms == pytest.approx(8.0, rel=0.15), result.summary
    assert "observed (own timers)" in result.summary[0]


def test_observe_launches_the_spec_commands_without_a_socket(tmp_path: Path) -> None:
    # Runs of 6 and 12 ms: the observer's 1 ms polls and a cold process's wake-up add up to ~0.5 ms to a run
    # on a slow minute of the VM (3 ms runs once measured 3.457 ms at the p95, over 15%).
    deploy = f"""deploy:
  fast: {{command: "{sys.executable} {TIMER_NODE} 6 40"}}
  slow: {{command: "{sys.executable} {TIMER_NODE} 12 60"}}
"""
    table = compile_table(SPEC + deploy, tmp_path / "out", cores=1)
    log = tmp_path / "observe.jsonl"
    env = {**os.environ, "CATANC_SOCKET": str(tmp_path / "none.sock")}
    command = [sys.executable, "-m", "catanc", "run", str(table), "--observe", "--launch", "--duration", "3"]
    done = subprocess.run([*command, "--log", str(log)], capture_output=True, timeout=60, check=False, env=env)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    result = profile_spec(SPEC, "timers.yaml", log.read_text(), str(log), tolerance=0.15)
    assert result.proposals["fast"].ms == pytest.approx(6.0, rel=0.15), result.summary
    assert result.proposals["slow"].ms == pytest.approx(12.0, rel=0.15), result.summary


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--demo"], "--observe with --demo"),
        ([], "give --launch or --attach NODE=PID"),
    ],
)
def test_observe_needs_nodes_on_their_own_timers(tmp_path: Path, options: list[str], message: str) -> None:
    table = compile_table(SPEC, tmp_path / "out", cores=1)
    result = runner.invoke(app, ["run", str(table), "--observe", *options])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert message in result.stderr
