"""The app processes ``catanc run`` starts or attaches to.

- ``--demo``: one synthetic worker per scheduled node (:mod:`catanc.runtime.worker`),
  burning CPU as the node's compute profile says and talking to the
  enforcer through :mod:`catanc.client`: catanc at work without a robot;
- ``--launch``: the spec's deploy commands, as the runtime table lists them (with the
  table's ``params.yaml`` for a process hosting a ROS node);
- ``--attach NODE=PID``: a running process that does not speak the protocol:
  its threads are pinned and prioritised as NODE's, and it keeps its own timer.

With ``--observe`` nothing is pinned or triggered: launched processes get no
``CATANC_SOCKET`` and keep their own timers (:mod:`catanc.runtime.enforcer.observe`).

Started processes get ``CATANC_SOCKET`` in their environment, their own
process group (so a Ctrl-C reaches the enforcer, which stops them), and
are stopped with SIGTERM, then SIGKILL, when the run ends.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from catanc.artifacts.runtime_table import ros_arguments
from catanc.errors import UsageError
from catanc.runtime.linux.sched import MIDDLEWARE_THREADS, format_cpus, threads_of
from catanc.runtime.protocol.messages import SOCKET_ENV
from catanc.runtime.worker.command import worker_command, worker_groups
from catanc.runtime.worker.draws import Profile
from catanc.spec.executors import executor_nodes
from catanc.spec.language import ModalCompute, Spec
from catanc.text import plural

STOP_GRACE_S = 2.0
MIDDLEWARE_CHECK_S = 30.0
"""How long into a run :class:`MiddlewareWatch` looks for new middleware threads (made at a node's init)."""


@dataclass
class Children:
    """Processes this run started; :meth:`stop` ends them all."""

    processes: list[tuple[str, subprocess.Popen[bytes]]] = field(default_factory=list)

    def start(
        self, name: str, argv: Sequence[str], socket_path: str | None, cpus: Collection[int] | None = None
    ) -> None:
        """Start ``argv``; ``socket_path`` None: without ``CATANC_SOCKET`` (no enforcer: ``--observe``).

        ``cpus``: the process may run only there from its first instruction, as under ``taskset``.
        """
        env = {key: value for key, value in os.environ.items() if key != SOCKET_ENV}
        if socket_path is not None:
            env[SOCKET_ENV] = socket_path
        try:
            with _forking_on(name, cpus):
                process = subprocess.Popen(list(argv), env=env, start_new_session=True)
        except OSError as exc:
            self.stop()
            raise UsageError(f"cannot start {name} ({argv[0]}): {exc.strerror or exc}") from None
        except UsageError:
            self.stop()
            raise
        self.processes.append((name, process))

    def stop(self) -> list[str]:
        """SIGTERM for every process group, SIGKILL for what is left :data:`STOP_GRACE_S` later; what did not stop
        cleanly, one line each (killed, or an exit status but 0), as launch.sh says it."""
        stopping = [process.poll() is None for _, process in self.processes]
        for (_, process), running in zip(self.processes, stopping, strict=True):
            if running:
                _signal_group(process, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        problems = []
        for (name, process), running in zip(self.processes, stopping, strict=True):
            try:
                code = process.wait(timeout=max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                problems.append(f"{name} (pid {process.pid}) still ran {STOP_GRACE_S:g} s after SIGTERM: SIGKILL")
                _signal_group(process, signal.SIGKILL)
                process.wait()
                continue
            if running and code != 0:
                problems.append(f"{name} (pid {process.pid}) exited with status {code} on SIGTERM")
        self.processes.clear()
        return problems

    def exited(self) -> list[tuple[str, int]]:
        """Started processes that have ended, with their status."""
        return [(name, code) for name, process in self.processes if (code := process.poll()) is not None]


@contextlib.contextmanager
def _forking_on(name: str, cpus: Collection[int] | None) -> Iterator[None]:
    """The calling thread on ``cpus`` meanwhile: a child inherits the affinity of the thread that forks it.

    So the child is pinned before it runs anything (every thread it makes inherits it too), without a
    ``preexec_fn`` (unsafe in a process with threads) or a ``taskset`` in between.
    """
    if cpus is None:
        yield
        return
    before = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, cpus)
    except OSError as exc:
        raise UsageError(
            f"cannot pin {name} to CPUs {format_cpus(cpus)} (this thread may use {format_cpus(before)}): {exc.strerror}"
        ) from None
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def _signal_group(process: subprocess.Popen[bytes], signum: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signum)


def demo_profiles(spec: Spec) -> dict[str, Profile]:
    """Each scheduled node's compute profile, as a worker burns it."""
    profiles: dict[str, Profile] = {}
    for name, node in spec.nodes.items():
        if not node.scheduled or node.compute_ms is None:
            continue
        compute = node.compute_ms
        if isinstance(compute, ModalCompute):
            profiles[name] = [(mode.share, mode.ms) for mode in compute.modes]
        else:
            profiles[name] = float(compute)
    return profiles


def start_demo(children: Children, spec: Spec, socket_path: str, *, seed: int = 0) -> None:
    """One worker process per scheduled node (Python threads of one process would share one interpreter lock),
    except that the nodes of one executor share a worker whose runs take turns: the spec's ``executors`` and those
    its processes imply (:func:`~catanc.spec.executors.executor_nodes`), as the plan assumed."""
    profiles = demo_profiles(spec)
    for group in worker_groups(list(profiles), executor_nodes(spec)):
        speedups = {name: spec.nodes[name].threads.speedups for name in group}  # burns on the threads given
        executors = [group] if len(group) > 1 else []
        argv = worker_command(
            {name: profiles[name] for name in group},
            seed=seed,
            socket_path=socket_path,
            speedups=speedups,
            executors=executors,
        )
        children.start(", ".join(group), argv, socket_path)


def start_launch(
    children: Children,
    processes: Sequence[Mapping[str, object]],
    socket_path: str | None,
    folder: Path,
    on: Mapping[int, int] | None = None,
) -> None:
    """The runtime table's processes that have a command; ``folder``: the table's, which holds their parameters.

    As launch.sh starts them: a process hosting a ROS node gets the folder's parameters file, and each
    runs only on its planned CPUs, ``on[cpu]`` for each CPU of the table's (the CPU this run put that
    plan core on; every one of them for a process none of whose CPUs it has).  ``on`` None: no pinning
    (``--observe`` changes nothing).
    """
    for process in processes:
        argv = process.get("argv")
        if isinstance(argv, list) and argv:
            words = [str(word) for word in argv]
            params_file = process.get("params_file")
            if isinstance(params_file, str):
                words += ros_arguments(str(folder.absolute() / params_file))
            cpus = process.get("cpus")
            pinned = None
            if on is not None and isinstance(cpus, list):
                pinned = sorted({on[cpu] for cpu in cpus if cpu in on}) or sorted(set(on.values()))
            children.start(str(process.get("key")), words, socket_path, pinned)


def middleware_on(pid: int, cpus: Collection[int]) -> list[str]:
    """Names of process ``pid``'s middleware threads that may run on any of ``cpus``."""
    found = []
    for tid in threads_of(pid):
        try:
            comm = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
            allowed = os.sched_getaffinity(tid)
        except OSError:  # gone meanwhile
            continue
        if comm.startswith(MIDDLEWARE_THREADS) and allowed & set(cpus):
            found.append(comm)
    return sorted(found)


@dataclass
class MiddlewareWatch:
    """Says once per started process that middleware threads of it may run on CPUs the plan schedules.

    They run under SCHED_OTHER until a node thread of their process registers (then the enforcer places
    them, :mod:`catanc.runtime.enforcer.nodes`): on a scheduled CPU they take what the subchains leave, and what
    they take there a subchain may miss when it is not raised.  Checked again as processes make them.
    """

    reported: set[str] = field(default_factory=set)

    def check(self, children: Children, scheduled_cpus: Collection[int]) -> list[str]:
        lines = []
        for name, process in children.processes:
            if name in self.reported or process.poll() is not None:
                continue
            threads = middleware_on(process.pid, scheduled_cpus)
            if threads:
                self.reported.add(name)
                named = ", ".join(sorted(set(threads))[:3]) + (", ..." if len(set(threads)) > 3 else "")
                lines.append(
                    f"{name} (pid {process.pid}): {plural(len(threads), 'middleware thread')} ({named}) may run on "
                    f"scheduled CPUs {format_cpus(scheduled_cpus)}, under SCHED_OTHER beside the subchains "
                    "until a node of it registers"
                )
        return lines


def parse_attach(items: Sequence[str], spec: Spec) -> dict[str, int]:
    """``NODE=PID`` pairs, checked against the spec and /proc."""
    found: dict[str, int] = {}
    for item in items:
        node, sep, pid_text = item.partition("=")
        if not sep or not pid_text.isdigit():
            raise UsageError(f"--attach {item!r}: expected NODE=PID, e.g. LM=4242")
        if node not in spec.nodes:
            raise UsageError(f"--attach {item!r}: no node {node!r} in app {spec.app}")
        if not Path(f"/proc/{pid_text}").is_dir():
            raise UsageError(f"--attach {item!r}: no process {pid_text}")
        found[node] = int(pid_text)
    return found
