"""The enforcer's own costs on this machine, as ratios to the machine's floor (needs root for SCHED_FIFO).

    python -m benchmarks.enforcer                     # nav2d and VR, 1 core, 30 s each
    python -m benchmarks.enforcer --duration 10 --app nav2d
    python -m benchmarks.enforcer --tree . --tree /path/to/another/catanc   # two trees, side by side
    python -m benchmarks.enforcer --workers cpp      # the nodes in C++ (examples/cpp/node.cpp)
    python -m benchmarks.enforcer --json

For each app, in one run:

- **the floor**: the slot switches the committed 1-core plan needs per second (sum over its
  shared cores of ``(slots + 1) / T``) times the CPU one wake-up costs in C
  (``benchmarks/wake_cost.c``: ``clock_nanosleep(TIMER_ABSTIME)`` at that rate, SCHED_FIFO 4, on the
  CPU the plan's core 0 runs on), measured just before the enforcer runs, and again beside it
  in the middle third (the app's threads on the same core make every wake-up dearer);
- ``catanc run`` on the committed 1-core table (``--start spec``) for ``--duration`` seconds, one
  synthetic worker process per scheduled node started here (their CPU is not counted): catanc's
  Python worker, or with ``--workers cpp`` the C++ example node (``examples/cpp/node.cpp``, built
  here with the system's compiler and ``catanc client --cflags``; a node of several modes burns
  their mean), as a robot's rclcpp nodes would be: the hop delay is mostly the clients' own;
- **steady state**: the CPU of every thread of the enforcer's process over the middle third of
  the run (``/proc/<pid>/task/*/schedstat``, exact nanoseconds), in cores and as a ratio to the
  floor (the issue: at most 2x, aim 1.5x);
- **whole run**: the enforcer with its planner and watchdog processes (``wait4`` rusage, which
  counts the children it reaped), start-up and re-solves included, in cores (the issue: under
  0.08 on nav2d);
- **switch latency** (a boundary's due time to its owner raised and head triggered) and **hop
  delay** (a node's end, or a trigger, to the next node's start), p50 and p95, from the log; the
  hop both ways, and apart: node to node inside a subchain (issue 31's hop: at most 0.1 ms at the
  p50) and a head's trigger to its start (the enforcer's send, its own next steps on the CPU, the
  head's wake-up);
- the load average before and after (the VM is shared: compare within one run).

``--tree`` (repeatable; default: this tree) names the catanc source trees to measure, each app
run once per tree, in turn, so two trees are compared in one run.  Each tree's processes (the
enforcer, its planner and watchdog, the workers) run its own interpreter (``TREE/.venv/bin/python``
if there is one, else this one) from a neutral folder with ``PYTHONPATH=TREE``: ``python -m`` and
``-c`` put the working folder first on ``sys.path``, ahead of ``PYTHONPATH``, so a run started from
this tree's root imported this tree whatever ``--tree`` said.  Before measuring, the interpreter is
asked which catanc it imports; a tree that is not the one imported stops the benchmark.  Each
tree's bytecode is cached first (``compileall``), as an installed catanc has it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.wake_cost import build_c_loop, c_loop, c_loop_argv, parsed_per_wake_us
from catanc.artifacts.runtime_table import PlanPayload, load_table
from catanc.runtime.enforcer.processes import demo_profiles
from catanc.runtime.logs.writer import read_log
from catanc.runtime.worker.command import worker_command
from catanc.runtime.worker.draws import Profile

ROOT = Path(__file__).resolve().parent.parent
APPS = ("nav2d", "vr_illixr")


def switches_per_s(plan: PlanPayload | None) -> float:
    """The slot switches a plan needs per second: sum over its shared cores of (slots + 1) / T."""
    if plan is None:
        raise SystemExit("benchmarks.enforcer: the runtime table has no plan")
    return float(sum(1000.0 * (len(core["order"]) + 1) / core["period_ms"] for core in plan["cores"]))


def mean_ms(profile: Profile) -> float:
    """A worker profile's mean compute time: its one time, or its modes' weighted mean."""
    return profile if isinstance(profile, float) else math.fsum(share * ms for share, ms in profile)


def build_cpp_node(folder: Path) -> Path:
    """``examples/cpp/node.cpp`` built with the system's C++ compiler and ``catanc client --cflags``."""
    compiler = shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        sys.exit("benchmarks.enforcer: --workers cpp needs a C++ compiler (c++ or g++)")
    flags = subprocess.run(
        [sys.executable, "-m", "catanc", "client", "--cflags"], capture_output=True, text=True, check=True
    ).stdout.split()
    binary = folder / "node"
    source = ROOT / "examples" / "cpp" / "node.cpp"
    subprocess.run([compiler, "-std=c++17", "-O2", "-pthread", *flags, str(source), "-o", str(binary)], check=True)
    return binary


def process_cpu_ns(pid: int) -> int:
    """CPU time of every thread of ``pid`` so far (ns, from each thread's schedstat)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            total += int((task / "schedstat").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return total


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


class Tree:
    """A catanc source tree to measure: its interpreter and the environment its processes run in."""

    def __init__(self, path: Path, neutral: Path) -> None:
        self.path = path.resolve()
        venv = self.path / ".venv" / "bin" / "python"
        self.python = str(venv) if venv.exists() else sys.executable
        self.cwd = neutral  # no catanc here: sys.path[0] of `-m` and `-c` finds nothing
        self.env = dict(os.environ, PYTHONPATH=str(self.path))
        self.env.pop("PYTHONSAFEPATH", None)
        self.env.pop("PYTHONDONTWRITEBYTECODE", None)  # this VM sets it: see check

    def check(self) -> None:
        """Stop unless this tree's interpreter, run as the benchmark runs it, imports this tree's catanc; then cache
        the tree's bytecode, as ``pip install`` does (without it every run compiled catanc's modules again at its
        start: ~0.13 s of CPU for the enforcer and its planner, measured 2026-11-29)."""
        found = subprocess.run(
            [self.python, "-c", "import catanc, catanc.runtime.enforcer.reoptimiser; print(catanc.__file__)"],
            cwd=self.cwd,
            env=self.env,
            capture_output=True,
            text=True,
            check=False,
        )
        imported = Path(found.stdout.strip()).resolve().parent.parent if found.returncode == 0 else None
        if imported != self.path:
            why = found.stderr.strip().splitlines()[-1:] if found.returncode else [f"imports {imported}"]
            sys.exit(f"benchmarks.enforcer: {self.python} does not import catanc from {self.path}: {' '.join(why)}")
        subprocess.run([self.python, "-m", "compileall", "-q", str(self.path / "catanc")], env=self.env, check=True)

    def table(self, app: str) -> Path:
        """The tree's own committed 1-core table of ``app`` (this tree's if it has none)."""
        own = self.path / "out" / app / "cores-1" / "runtime.json"
        return own if own.exists() else ROOT / "out" / app / "cores-1" / "runtime.json"


def measure(  # noqa: PLR0917 - the benchmark's axes
    app: str, duration_s: float, binary: Path, tree: Tree, cpp_node: Path | None = None, loop: str = "python"
) -> dict[str, Any]:
    table_path = tree.table(app)
    table = load_table(table_path)
    rate = switches_per_s(table.plan)
    cpu = sorted(os.sched_getaffinity(0))[0]  # the plan's core 0: the enforcer's loop runs there
    load_before = load()
    per_wake_us, floor_line = c_loop(binary, rate, 4.0, cpu)
    floor_cores = rate * per_wake_us / 1e6
    env = tree.env
    with tempfile.TemporaryDirectory() as folder:
        sock = str(Path(folder) / "s.sock")
        log = Path(folder) / "run.jsonl"
        command = [tree.python, "-m", "catanc", "run", str(table_path), "--quiet", "--start", "spec"]
        command += ["--duration", str(duration_s), "--socket", sock, "--log", str(log)]
        command += ["--loop", loop]
        began = time.monotonic()
        enforcer = subprocess.Popen(command, stdout=subprocess.DEVNULL, env=env, cwd=tree.cwd)
        deadline = time.monotonic() + 30
        while not Path(sock).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = [
            subprocess.Popen(
                worker_command({node: profile}, socket_path=sock, python=tree.python)
                if cpp_node is None
                else [str(cpp_node), f"{node}:{mean_ms(profile)!r}"],
                start_new_session=True,
                stdout=subprocess.DEVNULL,
                env=env if cpp_node is None else dict(env, CATANC_SOCKET=sock),
                cwd=tree.cwd,
            )
            for node, profile in demo_profiles(table.spec).items()
        ]
        time.sleep(max(began + duration_s / 3 - time.monotonic(), 0.0))
        first, first_at = process_cpu_ns(enforcer.pid), time.monotonic()
        # The floor again, beside the app (same core, same level): a wake-up costs more in a busy core's caches.
        loaded = subprocess.Popen(c_loop_argv(binary, rate, duration_s / 3, cpu), stdout=subprocess.PIPE, text=True)
        time.sleep(duration_s / 3)
        second, second_at = process_cpu_ns(enforcer.pid), time.monotonic()
        loaded_line = loaded.communicate(timeout=30)[0].strip()
        loaded_us = parsed_per_wake_us(loaded_line)
        _, status, usage = os.wait4(enforcer.pid, 0)
        wall = time.monotonic() - began
        for worker in workers:
            if worker.poll() is None:
                os.killpg(worker.pid, signal.SIGTERM)
            worker.wait(timeout=10)
        events = read_log(log)
    end = next(e for e in reversed(events) if e["event"] in ("stop", "status"))
    fields = end.get("summary", end)
    costs = fields.get("costs") or {}
    steady = (second - first) / 1e9 / (second_at - first_at)
    whole = (usage.ru_utime + usage.ru_stime) / wall
    resolves = [e for e in events if e["event"] == "resolve"]
    return {
        "app": app,
        "tree": str(tree.path),
        "workers": "python" if cpp_node is None else "cpp",
        "loop": loop,
        "python": tree.python,
        "exit_status": os.waitstatus_to_exitcode(status),
        "wall_s": round(wall, 2),
        "load_before": load_before,
        "load_after": load(),
        "floor": {
            "switches_per_s": round(rate, 1),
            "us_per_wake": round(per_wake_us, 2),
            "cores": round(floor_cores, 5),
            "wake_cost": floor_line,
            "loaded_us_per_wake": round(loaded_us, 2),
            "loaded_cores": round(rate * loaded_us / 1e6, 5),
        },
        "steady_cores": round(steady, 5),
        "steady_ratio": round(steady / floor_cores, 2),
        "steady_ratio_loaded": round(steady / (rate * loaded_us / 1e6), 2),
        "whole_run_cores": round(whole, 5),
        "whole_run_ratio": round(whole / floor_cores, 2),
        "switch": costs.get("switch") or _old_switches(fields),
        "hop": costs.get("hop"),
        "hop_inside": costs.get("hop_inside"),
        "hop_head": costs.get("hop_head"),
        "wakes": costs.get("wakes"),
        "cpu_per_wake_ms": costs.get("cpu_per_wake_ms"),
        "resolves": len(resolves),
        "cost_replans": sum(1 for e in resolves if e.get("reason") == "costs"),  # each builds the models again
    }


def _old_switches(fields: dict[str, Any]) -> dict[str, Any] | None:
    """A log written by a catanc before issue 31 keeps its switch latencies per core only."""
    switches = fields.get("switches") or {}
    return next(iter(switches.values()), None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--app", action="append", choices=APPS, help="nav2d or vr_illixr (default: both)")
    parser.add_argument(
        "--tree",
        type=Path,
        action="append",
        help="a catanc source tree to measure (repeat it to compare trees in one run; default: this tree)",
    )
    parser.add_argument(
        "--workers", choices=("python", "cpp"), default="python", help="the nodes' processes (default: python)"
    )
    parser.add_argument(
        "--loop",
        action="append",
        choices=("python", "compiled"),
        help="the enforcer's loop: python, or compiled (catanc run --loop); repeat it to compare (default: python)",
    )
    parser.add_argument("--json", action="store_true")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        binary = build_c_loop(Path(folder), "benchmarks.enforcer")
        neutral = Path(folder) / "neutral"
        neutral.mkdir()
        trees = [Tree(path, neutral) for path in options.tree or [ROOT]]
        for tree in trees:
            tree.check()
        cpp_node = build_cpp_node(Path(folder)) if options.workers == "cpp" else None
        results = [
            measure(app, options.duration, binary, tree, cpp_node, loop)
            for app in options.app or APPS
            for tree in trees
            for loop in options.loop or ["python"]
        ]
    if options.json:
        sys.stdout.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
        return
    for r in results:
        floor = r["floor"]
        where = f"{r['app']} (1 core, {r['workers']} workers, {r['loop']} loop), {r['tree']}"
        print(f"{where}: {r['wall_s']} s, exit {r['exit_status']}")
        print(f"  load average {r['load_before']} before, {r['load_after']} after")
        per_s, us, cores = floor["switches_per_s"], floor["us_per_wake"], floor["cores"]
        print(f"  floor: {per_s} switches/s x {us} us = {cores:.4f} cores")
        print(f"  floor beside the app: {floor['loaded_us_per_wake']} us = {floor['loaded_cores']:.4f} cores")
        print(f"  steady state: {r['steady_cores']:.4f} cores = {r['steady_ratio']}x the floor", end="")
        print(f" ({r['steady_ratio_loaded']}x the floor beside the app)")
        resolves = f"{r['resolves']} re-solves, {r['cost_replans']} with new costs"
        print(f"  whole run:    {r['whole_run_cores']:.4f} cores = {r['whole_run_ratio']}x ({resolves})")
        labels = {"switch": "switch", "hop": "hop", "hop_inside": "  node to node", "hop_head": "  trigger to head"}
        for key, label in labels.items():
            stats = r.get(key)
            if stats:
                quantiles = f"p50 {stats['p50_ms']:.3f} ms, p95 {stats['p95_ms']:.3f} ms, max {stats['max_ms']:.3f} ms"
                print(f"  {label}: {quantiles}")


if __name__ == "__main__":
    main()
