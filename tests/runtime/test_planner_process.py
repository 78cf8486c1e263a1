"""The re-optimiser's process: forked only from a process that runs one thread."""

from __future__ import annotations

import threading
from pathlib import Path

from catanc.core.load import load_spec
from catanc.runtime.planning import PlannerProcess, Request
from tests.support.enforcer_runs import cmdline, process_name

SPECS = Path(__file__).parents[2] / "specs"


def test_a_threaded_parent_starts_a_fresh_interpreter_that_plans() -> None:
    """A fork copies only the calling thread: a lock another thread held would stay held in the child."""
    spec = load_spec(SPECS / "nav2d.yaml")
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        planner = PlannerProcess(spec.model_dump(mode="json", by_alias=True), 1, bootstrap_ms=None)
    finally:
        stop.set()
        other.join()
    try:
        pid = planner.pid
        assert "serve_fd" in cmdline(pid)
        assert process_name(pid) != "catanc-planner"  # a fresh interpreter, not a named fork
        assert planner.initial.error is None
        assert planner.initial.summary["cores"] == 1
        # What the log's plans promise (catanc report): GL's rate less the triggers GM's runs in their
        # thread take (the simulator runs 38.0 Hz of 50: tests/planning/test_executor_trade.py).
        subchains = planner.initial.summary["subchains"]
        assert 35.0 < subchains["GL"]["rate_as_run_hz"] < 1000.0 / subchains["GL"]["period_ms"]
        assert "rate_as_run_hz" not in subchains["local"]
        answer = planner.ask(Request("resolve", {}))
        assert answer.error is None
    finally:
        planner.close()
