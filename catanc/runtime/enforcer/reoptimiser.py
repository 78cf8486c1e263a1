"""The re-optimiser as its own process: a warm :class:`~catanc.planning.replan.Replanner` behind a pipe.

The enforcer's trigger and scheduler threads are Python threads at
SCHED_FIFO 4 and need the interpreter lock within microseconds of waking.
A solver call holds that lock for its whole run (Stage I's MILP, tens of
milliseconds), so solving in the enforcer's process would delay every
trigger and slot switch behind it.  Here the solvers run in a child
process at SCHED_OTHER that keeps its Replanner (and every Stage II model
it built) for the whole run: a Stage II re-solve never rebuilds a model.
The enforcer's process never imports a solver.  The child is forked while the enforcer's process
runs one thread (it inherits the spec's language and pydantic, imported already: ~0.2 s of CPU a
run), else started as a fresh interpreter.
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import socket
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Literal, NoReturn, Protocol

from catanc.artifacts.runtime_table import rate_as_run_hz
from catanc.control.schedule import RuntimeSchedule
from catanc.errors import UsageError
from catanc.runtime.linux.sched import name_thread

Kind = Literal["resolve", "reallocate", "reconfigure"]


@dataclass(frozen=True)
class Request:
    kind: Kind
    compute_ms: dict[str, float]  # new compute times for scheduled nodes (empty: keep)
    cores: int | None = None
    reason: str = ""  # why it is asked (for the log): stage1, stage2, cores, costs
    costs: tuple[float, float] | None = None  # reconfigure: plan with this (switch_ms, slack) from now on


@dataclass(frozen=True)
class Answer:
    schedule: RuntimeSchedule
    layout: tuple[tuple[str, tuple[int, ...], bool], ...]  # per subchain: cores, shared; a change restarts cores
    summary: dict[str, Any]  # objective, cores and per subchain cores/period: for the log
    solve_ms: float
    error: str | None = None


class PlannerProcess:
    """The parent's handle: :meth:`ask` sends a request and waits for its answer (releasing the GIL)."""

    def __init__(self, spec_data: dict[str, Any], cores: int, *, bootstrap_ms: float | None) -> None:
        mine, theirs = socket.socketpair()
        try:
            self._process = _start_child(theirs.fileno())
        except OSError as exc:
            mine.close()
            theirs.close()
            raise UsageError(f"cannot start the planner process ({sys.executable}): {exc.strerror or exc}") from None
        theirs.close()
        self._conn = Connection(mine.detach())
        self._conn.send((spec_data, cores, bootstrap_ms))
        first = self._conn.recv()
        if isinstance(first, BaseException):
            raise first
        self.initial: Answer = first

    def ask(self, request: Request) -> Answer:
        """Send ``request`` and wait for its answer."""
        self.send(request)
        return self.receive()

    def send(self, request: Request) -> None:
        """Send ``request``; its answer is read with :meth:`receive` once :meth:`fileno` is readable."""
        self._conn.send(request)

    def receive(self) -> Answer:
        answer: Answer = self._conn.recv()
        return answer

    @property
    def pid(self) -> int:
        """The re-optimiser's process id."""
        return self._process.pid

    def fileno(self) -> int:
        """The connection's descriptor: readable when an answer waits (for ``select``)."""
        return self._conn.fileno()

    def close(self) -> None:
        with contextlib.suppress(OSError):  # the child may be gone already
            self._conn.send(None)
        try:
            self._process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._conn.close()


class _Child(Protocol):
    """What :meth:`PlannerProcess.close` needs of the child (a :class:`subprocess.Popen` has it)."""

    @property
    def pid(self) -> int: ...

    def wait(self, timeout: float | None = None) -> int: ...

    def kill(self) -> None: ...


@dataclass
class _ForkedChild:
    pid: int
    returncode: int | None = None

    def wait(self, timeout: float | None = None) -> int:
        """Its exit status; :class:`subprocess.TimeoutExpired` if it runs ``timeout`` seconds more."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, 0 if deadline is None else os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere
                self.returncode = -1
                break
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
            elif deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(f"planner process {self.pid}", timeout or 0.0)
            else:
                time.sleep(0.005)
        return self.returncode

    def kill(self) -> None:
        if self.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)


def _one_thread() -> bool:
    """Whether this process runs a single thread, native ones counted (a BLAS pool, say)."""
    try:
        return sum(1 for _ in Path("/proc/self/task").iterdir()) == 1
    except OSError:
        return False


def _start_child(fd: int) -> _Child:
    """The re-optimiser serving on socket ``fd``: a fork while this process runs one thread (a fork of
    a threaded process may inherit a lock another thread held), else a fresh interpreter."""
    if not _one_thread():
        argv = [sys.executable, "-c", f"from catanc.runtime.enforcer.reoptimiser import serve_fd; serve_fd({fd})"]
        return subprocess.Popen(argv, pass_fds=[fd])
    pid = os.fork()
    if pid == 0:
        _serve_forked(fd)
    return _ForkedChild(pid)


def _serve_forked(fd: int) -> NoReturn:
    """The forked child: the parent's descriptors closed, its objects never collected, gone via ``_exit``."""
    status = 1
    try:
        gc.freeze()  # a parent's object collected here could close a descriptor number the child reuses
        os.closerange(3, fd)  # the parent's log, sockets, watchdog pipe: only the parent may hold them
        os.closerange(fd + 1, os.sysconf("SC_OPEN_MAX"))
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C ends the parent, which ends this (EOF)
        for signum in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(signum, signal.SIG_DFL)
        name_thread("catanc-planner")
        serve(Connection(fd))
        status = 0
    except BaseException:  # say why on stderr; never return into the parent's code
        with contextlib.suppress(Exception):
            traceback.print_exc()
            sys.stderr.flush()
    finally:
        os._exit(status)


def serve(conn: Connection) -> None:
    """The child: plan once (with every node at ``bootstrap_ms`` if given), then answer requests until None."""
    from catanc.planning.replan import Replanner  # noqa: PLC0415 - only the child loads the solvers
    from catanc.spec.language import Spec  # noqa: PLC0415

    spec_data, cores, bootstrap_ms = conn.recv()
    try:
        spec = Spec.model_validate(spec_data)
        began = time.perf_counter()
        replanner = Replanner(spec, cores)
        if bootstrap_ms is not None:  # the model, section 5: every node 5 ms, both stages, then measure
            nodes = [node for sub in replanner.problem.subchains for node in sub.nodes]
            replanner.reallocate(dict.fromkeys(nodes, bootstrap_ms))
    except Exception as exc:  # the parent re-raises it
        conn.send(exc)
        return
    conn.send(_answer(replanner, began))
    while True:
        try:
            request = conn.recv()
        except EOFError:  # the enforcer is gone
            return
        if request is None:
            return
        began = time.perf_counter()
        try:
            if request.kind == "resolve":
                replanner.resolve(request.compute_ms)
            elif request.kind == "reconfigure" and request.costs is not None:
                switch_ms, slack = request.costs  # the runtime's own costs, measured
                replanner.reconfigure(switch_ms, slack, request.compute_ms or None)
            else:
                replanner.reallocate(request.compute_ms or None, cores=request.cores)
        except Exception as exc:  # a bad measurement must not end the run: keep the last plan
            conn.send(_answer(replanner, began, error=f"{type(exc).__name__}: {exc}"))
            continue
        conn.send(_answer(replanner, began))


def _answer(replanner: Any, began: float, error: str | None = None) -> Answer:
    from catanc.control.schedule import runtime_schedule  # noqa: PLC0415

    plan, spec = replanner.plan, replanner.spec  # the spec with the costs the plan was made with
    return Answer(
        schedule=runtime_schedule(plan, replanner.problem, spec.schedule),
        layout=tuple((name, sub.cores, sub.shared) for name, sub in sorted(plan.subchains.items())),
        summary={
            "objective": round(plan.objective, 6),
            "cores": plan.cores,
            "switch_ms": spec.schedule.switch_ms,
            "slack": spec.schedule.slack,
            "subchains": {name: _subchain_summary(sub) for name, sub in sorted(plan.subchains.items())},
            "chains": _chain_summaries(plan, replanner.problem),
        },
        solve_ms=(time.perf_counter() - began) * 1000.0,
        error=error,
    )


def _subchain_summary(sub: Any) -> dict[str, Any]:
    summary = {"cores": list(sub.cores), "shared": sub.shared, "period_ms": round(sub.period_ms, 6)}
    if sub.period_as_run_ms is not None:  # what report holds the measured rate to
        summary["rate_as_run_hz"] = rate_as_run_hz(sub.period_as_run_ms)
    return summary


def _chain_summaries(plan: Any, problem: Any) -> list[dict[str, Any]]:
    """Each chain of the objective and constraints: its nodes, its last scheduled node (where ``catanc report``
    measures its response from origins), the plan's response and the spec's bound (None: unbounded)."""
    bounds: dict[int, float] = {}
    for bound in problem.response_bounds:
        bounds[bound.chain] = min(bound.max_response_ms, bounds.get(bound.chain, bound.max_response_ms))
    return [
        {
            "nodes": list(chain.nodes),
            "last_scheduled": problem.last_scheduled(chain.nodes),
            "response_ms": round(chain.response_ms, 3),
            "max_response_ms": bounds.get(index),
        }
        for index, chain in enumerate(plan.chains)
    ]


def serve_fd(fd: int) -> None:
    """The child's entry point: serve on the inherited socket ``fd``."""
    serve(Connection(fd))
