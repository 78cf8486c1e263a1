"""The re-optimiser's process: forked only from a process that runs one thread."""

from __future__ import annotations

import threading
from pathlib import Path

from catanc.model.load import load_spec, parse_spec
from catanc.runtime.enforcer.reoptimiser import PlannerProcess, Request
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


def test_each_plan_names_its_chains_where_they_are_measured_and_their_bounds() -> None:
    # What `catanc report` measures chains from origins with: the log's plans carry them.
    text = (SPECS / "face_tracking.yaml").read_text()
    text = text.replace("constraints:\n", "constraints:\n  - {chain: [camera, detection], max_response_ms: 500}\n")
    spec = parse_spec(text)
    planner = PlannerProcess(spec.model_dump(mode="json", by_alias=True), 1, bootstrap_ms=None)
    try:
        chains = planner.initial.summary["chains"]
    finally:
        planner.close()
    # Face tracking on one core: c(S) = 84 ms, period 84 / 0.95; R = 84 + 84 / 0.95 (tests/planning/test_hops.py).
    assert chains == [
        {
            "nodes": ["camera", "detection", "planning", "motor"],
            "last_scheduled": "planning",  # motor is an unscheduled sink
            "response_ms": round(84 + 84 / 0.95, 3),
            "max_response_ms": None,
        },
        {
            "nodes": ["camera", "detection"],
            "last_scheduled": "detection",
            "response_ms": round(84 + 84 / 0.95, 3),  # a stage is timed as its whole subchain's run
            "max_response_ms": 500.0,
        },
    ]
