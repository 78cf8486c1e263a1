"""The enforcer's own costs on this machine: switch latency and CPU use (needs root for SCHED_FIFO).

    python -m benchmarks.enforcer                 # nav2d and VR, 1 core, 20 s each
    python -m benchmarks.enforcer --duration 5    # shorter
    python -m benchmarks.enforcer --json

For each app: one synthetic worker process per scheduled node (started
here, so their CPU time is not counted), ``catanc run`` on the committed
1-core table for ``--duration`` seconds, then:

- switch latency: from a slot's scheduled switch time until its owner's
  threads are raised (and its head triggered), per shared core, from the
  enforcer's last status line (the paper: 0.12 ms per switch);
- CPU use of the enforcer with its planner and watchdog processes
  (``wait4`` rusage of the enforcer, which waits for both), in cores
  (the paper: under 0.05 cores, re-solves included);
- per enforcer thread, over the middle of the run (start-up excluded): its
  CPU use in cores and its wake-ups per second (``/proc/<pid>/task/<tid>``:
  ``stat`` utime + stime, ``status`` voluntary_ctxt_switches), which
  shows where the CPU goes: mostly the wake-ups themselves, see
  benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from catanc.artifacts.runtime_table import load_table
from catanc.runtime.log import read_log
from catanc.runtime.processes import demo_profiles
from catanc.runtime.worker import worker_command

ROOT = Path(__file__).resolve().parent.parent
APPS = ("nav2d", "vr_illixr")
PAPER_SWITCH_MS = 0.12
PAPER_CORES = 0.05


def measure(app: str, duration_s: float) -> dict[str, Any]:
    table_path = ROOT / "out" / app / "cores-1" / "runtime.json"
    table = load_table(table_path)
    with tempfile.TemporaryDirectory() as folder:
        sock = str(Path(folder) / "s.sock")
        log = Path(folder) / "run.jsonl"
        command = [sys.executable, "-m", "catanc", "run", str(table_path), "--quiet", "--start", "spec"]
        command += ["--duration", str(duration_s), "--socket", sock, "--log", str(log)]
        enforcer = subprocess.Popen(command, stdout=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while not Path(sock).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = [
            subprocess.Popen(worker_command({node: profile}, socket_path=sock), start_new_session=True)
            for node, profile in demo_profiles(table.spec).items()
        ]
        began = time.monotonic()
        time.sleep(duration_s / 3)
        first = thread_usage(enforcer.pid)
        time.sleep(duration_s / 3)
        second = thread_usage(enforcer.pid)
        window_s = duration_s / 3
        _, status, usage = os.wait4(enforcer.pid, 0)
        wall = time.monotonic() - began
        for worker in workers:
            if worker.poll() is None:
                os.killpg(worker.pid, signal.SIGTERM)
            worker.wait(timeout=5)
        events = read_log(log)
    last = next(e for e in reversed(events) if e["event"] in ("stop", "status"))
    fields = last.get("summary", last)
    resolves = [e for e in events if e["event"] == "resolve"]
    cpu_s = usage.ru_utime + usage.ru_stime
    return {
        "app": app,
        "exit_status": os.waitstatus_to_exitcode(status),
        "duration_s": round(wall, 2),
        "switch_ms": fields.get("switches", {}),
        "enforcer_cores": round(cpu_s / wall, 4),
        "threads": {
            name: {
                "cores": round((second[name][0] - cpu) / window_s, 4),
                "wakes_per_s": round((second[name][1] - wakes) / window_s, 1),
            }
            for name, (cpu, wakes) in first.items()
            if name in second
        },
        "resolves": len(resolves),
        "resolve_ms_median": sorted(e["solve_ms"] for e in resolves)[len(resolves) // 2] if resolves else None,
    }


def thread_usage(pid: int) -> dict[str, tuple[float, int]]:
    """Per thread of ``pid`` (by name; the enforcer names its threads): CPU seconds so far and voluntary switches."""
    found: dict[str, tuple[float, int]] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in sorted(Path(f"/proc/{pid}/task").iterdir(), key=lambda p: int(p.name)):
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            status = (task / "status").read_text()
            name = (task / "comm").read_text().strip()
        except OSError:
            continue
        wakes = next(int(line.split()[1]) for line in status.splitlines() if line.startswith("voluntary_ctxt_switches"))
        found[name] = ((int(fields[14 - 3]) + int(fields[15 - 3])) / tick, wakes)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--json", action="store_true")
    options = parser.parse_args()
    results = [measure(app, options.duration) for app in APPS]
    if options.json:
        sys.stdout.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
        return
    for result in results:
        print(f"{result['app']}: {result['duration_s']} s, exit {result['exit_status']}")
        for core, stats in result["switch_ms"].items():
            ratio = stats["p50_ms"] / PAPER_SWITCH_MS
            print(
                f"  switch latency core {core}: p50 {stats['p50_ms']:.3f} ms ({ratio:.2f}x the paper's "
                f"{PAPER_SWITCH_MS} ms), p95 {stats['p95_ms']:.3f} ms, max {stats['max_ms']:.3f} ms"
            )
        cores = result["enforcer_cores"]
        print(
            f"  enforcer CPU (with planner and watchdog): {cores:.4f} cores ({cores / PAPER_CORES:.2f}x the "
            f"paper's {PAPER_CORES}); {result['resolves']} re-solves, median {result['resolve_ms_median']} ms"
        )
        for name, use in result["threads"].items():
            print(f"    {name:<20} {use['cores']:.4f} cores, {use['wakes_per_s']:.0f} wake-ups/s (mid-run)")


if __name__ == "__main__":
    main()
