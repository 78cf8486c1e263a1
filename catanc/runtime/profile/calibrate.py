"""``catanc calibrate``: run the enforcer on a small synthetic app and measure its own costs on this machine.

The app (:data:`CALIBRATION_SPEC`) keeps one core switching: a three-node subchain (two hops per
run) and three one-node subchains share it, each with a short slice, so a few seconds give
thousands of switches and hops.  The enforcer runs it as ``catanc run --demo`` would (synthetic
workers, SCHED_FIFO, its watchdog), from the app's plan, and reports what it measured of itself
(:mod:`catanc.runtime.enforcer.costs`):

- ``switch_ms``: the p95 of its switch latency (a boundary's due time to its owner raised and its
  head triggered);
- ``hop_ms``: the p95 of the hop delay while the subchain runs raised (a trigger, or a node's end,
  to the next node's start);
- ``wake_ms``: its own CPU per wake-up (part of each head's hop on its core, and of its overhead);
- ``overhead``: its CPU share of each core (its loop runs on one of them; the others' is 0);
- the kernel's real-time limit (``/proc/sys/kernel/sched_rt_{runtime,period}_us``).

The result is a :class:`~catanc.spec.machine.MachineProfile` (the CLI writes its
:func:`~catanc.spec.machine.profile_text` with :func:`~catanc.artifacts.output.replace_file`).
:func:`calibrate` reports its phases to a callback (``planning``, ``starting``, ``measuring``,
``done``) so a front end can show progress.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from catanc.errors import CatancError, ExitCode
from catanc.runtime.enforcer.costs import measured_profile, rt_limit, this_machine
from catanc.runtime.linux.sched import Restorer
from catanc.spec.machine import MachineProfile

CALIBRATION_SPEC = """\
catan: 1
app: calibrate
nodes:
  a1: {compute_ms: 0.5}
  a2: {compute_ms: 0.5}
  a3: {compute_ms: 0.5}
  b: {compute_ms: 1}
  c: {compute_ms: 1}
  d: {compute_ms: 1}
edges: [[a1, a2], [a2, a3]]
subchains: {a: [a1, a2, a3], b: [b], c: [c], d: [d]}
objective:
  - {chain: [a1, a2, a3], weight: 1}
  - {node: b, weight: 0.3}
  - {node: c, weight: 0.3}
  - {node: d, weight: 0.3}
runtime: {first_solve_after_s: 1000, stage2_every_s: 1000, stage1_every_s: 1000}
"""
"""Four subchains on one core: about five switches and two hops every few milliseconds."""

DEFAULT_DURATION_S = 6.0
MIN_SWITCHES = 200
"""Switches a calibration must measure (a few seconds of the app give thousands)."""

Progress = Callable[[str, str], None]
"""(phase, detail): planning, starting, measuring, done."""


class CalibrationError(CatancError):
    """The calibration measured too little to stand for the machine (the message says what)."""

    exit_code = ExitCode.INTERNAL


def calibrate(
    *,
    duration_s: float = DEFAULT_DURATION_S,
    restorer: Restorer,
    progress: Progress | None = None,
    each_second: Callable[[float], None] | None = None,
) -> MachineProfile:
    """Run the calibration app under the enforcer for ``duration_s``; the machine profile of what it measured.

    ``progress`` hears each phase; ``each_second`` the seconds measured so far, once a second, from
    the enforcer's loop (keep it short: the loop is what is being measured).
    """
    from catanc.artifacts.compile import compile_spec  # noqa: PLC0415 - the planner is needed only here
    from catanc.artifacts.output import write  # noqa: PLC0415
    from catanc.artifacts.runtime_table import load_table  # noqa: PLC0415
    from catanc.runtime.enforcer.processes import Children, start_demo  # noqa: PLC0415
    from catanc.runtime.enforcer.run import Enforcer  # noqa: PLC0415

    tell = progress or (lambda _phase, _detail: None)
    cores = len(os.sched_getaffinity(0))
    with tempfile.TemporaryDirectory(prefix="catanc-calibrate-") as folder:
        tell("planning", "the calibration app on one core")
        spec = Path(folder) / "calibrate.yaml"
        spec.write_text(CALIBRATION_SPEC)
        target = compile_spec(spec, 1, out=Path(folder) / "cores-1")
        write(target.folder, target.files)
        table = load_table(target.folder / "runtime.json")
        socket_path = str(Path(folder) / "s.sock")
        children = Children()
        enforcer = Enforcer(table, socket_path=socket_path, rt=True, start="spec", cores=1, restorer=restorer)

        def begin(_running: Enforcer) -> None:
            tell("starting", "synthetic workers")
            start_demo(children, table.spec, socket_path)
            tell("measuring", f"{duration_s:g} s")

        def tick(running: Enforcer) -> None:
            if each_second is not None:
                each_second(running.elapsed_s())

        try:
            enforcer.run(duration_s, on_start=begin, on_tick=tick)
        finally:
            children.stop()
    summary = (enforcer.final or enforcer.status())["costs"]
    overhead = list(summary.get("overhead") or [0.0])
    summary = {**summary, "overhead": overhead + [0.0] * (cores - len(overhead))}  # its loop ran on one core
    profile = measured_profile(summary, rt=rt_limit(), machine=this_machine(), minimum=MIN_SWITCHES)
    if profile is None:
        switch = summary.get("switch") or {}
        raise CalibrationError(
            f"the calibration measured {switch.get('count', 0)} switches in {duration_s:g} s, fewer than "
            f"{MIN_SWITCHES}: the machine is too busy, or the run too short (--duration)"
        )
    tell("done", f"switch p95 {profile.switch_ms:.3f} ms, hop p95 {profile.hop_ms:.3f} ms")
    return profile
