"""The enforcer's own costs on the real kernel: measured, reported, planned with, written as a machine profile.

- ``catanc run`` measures its switch latency, hop delay and CPU share; ``catanc report`` shows them;
- it re-plans with switch_ms and slack raised to cover them, each once (never below the spec's);
- ``catanc calibrate`` writes a machine profile that ``catanc compile --machine`` reads back.

Skips with the reason where SCHED_FIFO (up to the watchdog's priority) is not available.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from catanc.errors import ExitCode
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
from catanc.runtime.logs.writer import read_log
from catanc.spec.machine import read_machine
from tests.support.enforcer_runs import ENFORCER_MAIN, compile_table, of_kind

# One core, three subchains with short slices: many switches a second, and two hops per run of `a`.
BUSY_CORE = """\
catan: 1
app: costs
nodes:
  a1: {compute_ms: 0.5}
  a2: {compute_ms: 0.5}
  b: {compute_ms: 1}
  c: {compute_ms: 1}
edges: [[a1, a2]]
subchains: {a: [a1, a2], b: [b], c: [c]}
objective:
  - {chain: [a1, a2], weight: 1}
  - {node: b, weight: 0.3}
  - {node: c, weight: 0.3}
runtime: {first_solve_after_s: 1, stage2_every_s: 1, stage1_every_s: 100}
"""


REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: every test here needs SCHED_FIFO up to it
pytestmark = pytest.mark.usefixtures("real_kernel")


def test_a_run_measures_its_costs_reports_them_and_plans_with_them(tmp_path: Path) -> None:
    table = compile_table(BUSY_CORE, tmp_path, 1)
    log = tmp_path / "log.jsonl"
    folder = Path(tempfile.mkdtemp(prefix="catanc-costs-"))
    finished = subprocess.run(
        [
            *(sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--demo", "--start", "spec"),
            *("--duration", "8", "--socket", str(folder / "s.sock"), "--log", str(log)),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert finished.returncode == 0, finished.stderr
    events = read_log(log)
    costs = next(e for e in reversed(events) if e["event"] == "stop")["summary"]["costs"]
    assert costs["switch"]["count"] > 500
    assert 0 < costs["switch"]["p50_ms"] <= costs["switch"]["p95_ms"] < 50.0
    assert costs["hop"]["count"] > 100  # a1 -> a2, and each head's trigger to its start
    assert 0 <= costs["hop"]["p50_ms"] <= costs["hop"]["p95_ms"]
    assert costs["hop_inside"]["count"] > 50  # a1 -> a2 alone
    assert costs["hop_head"]["count"] > 50  # the heads' triggers alone
    assert costs["hop_inside"]["count"] + costs["hop_head"]["count"] >= costs["hop"]["count"]  # each kept apart too
    assert 0 < costs["overhead"][0] < 1
    spec_switch = 0.12  # the spec's default
    replans = [e for e in of_kind(events, "resolve") if e["reason"] == "costs"]
    assert replans, [e["reason"] for e in of_kind(events, "resolve")]
    for replan in replans:
        assert replan["error"] is None
        assert replan["plan"]["switch_ms"] >= spec_switch
        assert replan["plan"]["slack"] >= 0.05
    # Raised: the enforcer's own CPU comes off the RT budget (a slot pays only its head's hop beyond that CPU,
    # which may stay under the spec's 0.12 ms).
    assert replans[0]["plan"]["slack"] > 0.05
    report = subprocess.run(
        [sys.executable, "-m", "catanc", "report", str(log)], capture_output=True, text=True, timeout=60, check=True
    )
    assert "hop delay" in report.stdout
    assert "node to node" in report.stdout
    assert "trigger to head" in report.stdout
    assert "switch latency" in report.stdout
    as_json = json.loads(
        subprocess.run(
            [sys.executable, "-m", "catanc", "report", str(log), "--json"],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        ).stdout
    )
    assert as_json["costs"]["hop_ms"]["p50"] == pytest.approx(costs["hop"]["p50_ms"], abs=1e-3)


def test_calibrate_writes_a_profile_compile_reads(tmp_path: Path) -> None:
    profile = tmp_path / "machine.yaml"
    finished = subprocess.run(
        [sys.executable, "-m", "catanc", "calibrate", "--duration", "4", "--out", str(profile)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=tmp_path,
        env={**os.environ, "TTY_COMPATIBLE": "1"},  # as on a terminal: the seconds measured on stderr
    )
    assert finished.returncode == 0, finished.stderr
    assert "calibrate: measuring 4 s" in finished.stderr
    assert "4/4 s" in finished.stderr or "3/4 s" in finished.stderr  # drawn once a second, to the end
    assert f"{profile}: switch" in finished.stdout
    read = read_machine(profile).profile
    assert read.switch_ms > 0
    assert read.hop_ms > 0
    assert 0 < read.wake_ms < 50.0
    assert len(read.overhead) == len(os.sched_getaffinity(0))
    assert 0 < max(read.overhead) < 1
    spec = tmp_path / "spec.yaml"
    spec.write_text(BUSY_CORE)
    compiled = subprocess.run(
        [
            *(sys.executable, "-m", "catanc", "compile", str(spec), "-k", "1", "--machine", str(profile)),
            *("--out", str(tmp_path / "out")),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert compiled.returncode == ExitCode.OK, compiled.stderr
    plan = json.loads((tmp_path / "out" / "runtime.json").read_text())
    assert json.dumps(plan).count("measured") > 0
