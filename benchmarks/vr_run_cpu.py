"""Issue 49 item 3: the CPU a bench worker's thread spends around each run, and each chain's ratios.

    for i in 1 2 3; do taskset -c 1 catanc bench specs/vr_illixr.yaml --cores 1 --duration 15 \\
        --policy catan --policy fifo-static --log runs-$i --json -q > runs-$i.json; done
    python -m benchmarks.vr_run_cpu runs-1 runs-2 runs-3

Reads each folder's worker records (``<policy>.runs.jsonl``, which ``--log`` keeps) and prints, per
policy and node, the CPU its thread spent around its runs (``CLOCK_THREAD_CPUTIME_ID``): *after* a
run, from its recorded end to its done report returning (the record, the ring entry, the done
datagram, the hop's trigger and yield), and *before* one, from the previous done back through the
thread's wait to its recorded start (the loop, the blocking receive, the wake-up and the trigger's
parse).  Then, from ``<folder>.json`` when it is there, each chain's mean and p95 against
fifo-static's, per run.  The enforcer's own CPU per wake-up is ``catanc report``'s.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
from collections import defaultdict
from pathlib import Path

from benchmarks.scenarios import VR_CHAINS
from catanc.control.measure import percentile
from catanc.runtime.worker.records import RunRecord, read_records

POLICIES = ("catan", "fifo-static")


def around_ms(runs: list[RunRecord]) -> dict[str, tuple[list[float], list[float]]]:
    """Per node: the CPU (ms) before each run since the previous one's done, and after it until its done
    (from its second run on: the first one's wait includes the worker's start)."""
    by_node: dict[str, list[RunRecord]] = defaultdict(list)
    for run in runs:
        if run.thread_cpu_done_ns:
            by_node[run.node].append(run)
    out = {}
    for node, mine in sorted(by_node.items()):
        mine.sort(key=lambda run: run.start_ns)
        after = [(r.thread_cpu_done_ns - r.thread_cpu_start_ns - r.cpu_ns) / 1e6 for r in mine[1:]]
        before = [(r.thread_cpu_start_ns - p.thread_cpu_done_ns) / 1e6 for p, r in itertools.pairwise(mine)]
        out[node] = (before, after)
    return out


def spread(values: list[float]) -> str:
    return f"mean {statistics.mean(values):.3f} p50 {statistics.median(values):.3f} p95 {percentile(values, 95):.3f}"


def ratios(path: Path) -> dict[str, tuple[float, float]] | None:
    """Each chain's (mean, p95) against fifo-static's, from a ``catanc bench --json`` output."""
    if not path.exists():
        return None
    policies = json.loads(path.read_text(encoding="utf-8"))["policies"]
    figures = {
        policy: {tuple(chain["nodes"]): chain["response_ms"] for chain in policies[policy]["chains"]}
        for policy in POLICIES
    }
    out = {}
    for name, nodes in VR_CHAINS.items():
        catan, fifo = figures["catan"][tuple(nodes)], figures["fifo-static"][tuple(nodes)]
        out[name] = (catan["mean"] / fifo["mean"] - 1, catan["p95"] / fifo["p95"] - 1)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path, help="catanc bench --log folders")
    args = parser.parse_args()
    print("CPU around a run on the node's thread, ms: before (wait, wake, read) / after (record, done)")
    for policy in POLICIES:
        pooled: dict[str, tuple[list[float], list[float]]] = defaultdict(lambda: ([], []))
        for folder in args.folders:
            for node, (before, after) in around_ms(read_records(folder / f"{policy}.runs.jsonl")).items():
                pooled[node][0].extend(before)
                pooled[node][1].extend(after)
        for node, (before, after) in sorted(pooled.items()):
            both = [b + a for b, a in zip(before, after, strict=True)]
            print(
                f"{policy:12s} {node:9s} runs {len(after):5d}"
                f"  before {spread(before)}  after {spread(after)}"
                f"  both mean {statistics.mean(both):.3f}"
            )
    print("catan against fifo-static, per chain: mean / p95")
    for folder in args.folders:
        figures = ratios(folder.with_name(folder.name + ".json"))
        if figures is not None:
            cells = [f"{name} {100 * m:+.1f} / {100 * p:+.1f}%" for name, (m, p) in figures.items()]
            print(f"{folder.name:12s}", " | ".join(cells))


if __name__ == "__main__":
    main()
