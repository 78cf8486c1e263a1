"""A node that leaves while ``catanc run`` walks its shared core with the compiled loop (real kernel, root).

The compiled walk reads each node's ring at the address its reader mapped it; a node's bye closes that
reader.  The walk must be laid out again before it runs on: a walk that read the closed ring crashed the
enforcer (SIGSEGV) the moment the node left.  Here A and B share one core; A's process ends (its bye) while
B goes on, and the enforcer must keep triggering B, then stop normally.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
from tests.support.client_nodes import client_run, python_node
from tests.support.enforcer_runs import compile_table, of_kind

REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: the enforcer's watchdog runs at it

# Two subchains on one core: the shared core's walk reads both rings.
SPEC = """\
catan: 1
app: leaving
nodes:
  A: {compute_ms: 2}
  B: {compute_ms: 2}
edges: []
subchains: {a: [A], b: [B]}
objective: [{node: A, weight: 1.0}, {node: B, weight: 1.0}]
constraints: [{node: A, max_rate_hz: 50}, {node: B, max_rate_hz: 50}]
runtime: {first_solve_after_s: 100, stage2_every_s: 100, stage1_every_s: 100}
"""


def test_a_node_that_leaves_a_shared_core_leaves_the_compiled_enforcer_running(
    real_kernel: None, tmp_path: Path
) -> None:
    table = compile_table(SPEC, tmp_path, cores=1)
    argv = python_node(tmp_path, sys.executable)
    with client_run(tmp_path) as run:
        run.start(table, duration=30.0, extra=["--loop", "compiled"])
        a = run.node([*argv, "A:2"])
        run.node([*argv, "B:2"])
        run.registered(["A", "B"])
        time.sleep(1.0)  # both run under the walk
        a.send_signal(signal.SIGTERM)  # its loop ends: a bye for A
        assert a.wait(timeout=10.0) == 0, a.stderr.read() if a.stderr else ""
        time.sleep(2.0)  # the walk goes on with B alone (each log flush is about a second apart)
        assert run.enforcer is not None
        assert run.enforcer.poll() is None, f"the enforcer ended ({run.enforcer.returncode}): {run.stderr()}"
        run.enforcer.send_signal(signal.SIGINT)
        assert run.wait() == 0, run.stderr()
        events = run.events()
    last_of_a = max(e["t"] for e in of_kind(events, "run") if e["subchain"] == "a")
    after = [e for e in of_kind(events, "run") if e["subchain"] == "b" and e["t"] > last_of_a + 1.0]
    assert after, "B ran no more once A had left"
