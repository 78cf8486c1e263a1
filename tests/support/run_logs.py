"""Hand-made ``catanc run`` logs for the tests of ``catanc profile``: known samples in the enforcer's format."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence

from catanc.runtime.logs.writer import LOG_FORMAT

SPEC = """catan: 1
app: demo
nodes:
  cam: {compute_ms: 5}          # camera shim
  det:                          # a detector with two modes
    compute_ms: {modes: [{share: 0.5, ms: 2}, {share: 0.5, ms: 20}]}
  plan: {compute_ms: 10, threads: {max: 2, speedup: [1.0, 1.5]}}
  motor: {scheduled: false}
edges: [[cam, det], [det, plan], [plan, motor]]
subchains:
  main: [cam, det, plan]
objective:
  - {chain: [cam, det, plan, motor], weight: 1.0}
"""

Batch = tuple[str, Sequence[float], Sequence[int] | None, Sequence[float | None] | None]


def log_text(
    *batches: Batch,
    stop: bool = True,
    fmt: object = LOG_FORMAT,
    kernels: Mapping[str, Sequence[float | None]] = {},
    hops: Mapping[str, tuple[float, int]] = {},
    ages: Mapping[str, Sequence[float]] = {},
    dispatches: Mapping[str, tuple[float, int]] = {},
) -> str:
    """A log as the enforcer writes it: a start, one compute batch per (node, ms, threads, own figures), a stop.

    ``kernels``: per node, the kernel's counts of its batch's runs (None where unchecked; default all None).
    ``hops``: per edge ``"a -> b"``, the p95 and count of its hops in the stop's costs (``hop_by_edge``).
    ``dispatches``: per head, the p95 and count of its triggers' delays to its starts (``dispatch_by_head``).
    ``ages``: per node, runs' ages (end less origin, ms), one ``compute`` event each (of 1 ms) after the batches.
    """
    start = {"t": 0.0, "event": "start", "cores": 1, "plan": {}}
    if fmt is not None:
        start["format"] = fmt
    lines = [start]
    for t, (node, ms, threads, walls) in enumerate(batches, start=1):
        lines.append(
            {
                "t": float(t),
                "event": "compute_batch",
                "node": node,
                "at": [float(t)] * len(ms),
                "ms": list(ms),
                "reported_ms": list(walls) if walls is not None else list(ms),
                "kernel_ms": list(kernels.get(node, [None] * len(ms))),
                "threads": list(threads) if threads is not None else [1] * len(ms),
            }
        )
    for node, values in ages.items():
        lines += [
            {"t": 8.0, "event": "compute", "node": node, "ms": 1.0, "reported_ms": 1.0, "kernel_ms": None}
            | {"threads": 1, "age_ms": age}
            for age in values
        ]
    if stop:
        costs = {
            field_name: {
                key: {"p50_ms": p95 / 2, "p95_ms": p95, "max_ms": p95 * 2, "count": count}
                for key, (p95, count) in figures.items()
            }
            for field_name, figures in (("hop_by_edge", hops), ("dispatch_by_head", dispatches))
            if figures
        }
        lines.append({"t": 9.0, "event": "stop", "summary": {"costs": costs} if costs else {}})
    return "".join(json.dumps(line, sort_keys=True) + "\n" for line in lines)


def every_node(cam: Sequence[float] = (), det: Sequence[float] = (), plan: Sequence[float] = ()) -> list[Batch]:
    return [
        ("cam", cam or [5.0] * 20, None, None),
        ("det", det or [2.0] * 10 + [20.0] * 10, None, None),
        ("plan", plan or [10.0] * 20, None, None),
    ]
