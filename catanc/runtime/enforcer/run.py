"""``catanc run``: apply a plan on a live Linux system and keep it right as compute times drift.

One event loop does everything time-critical (docs/explanation/model.md sections 5 and 6), in one thread
at SCHED_FIFO 4 pinned to one CPU, sleeping in ``select`` until the next thing to do:

- a shared core's **boundary** (:class:`~catanc.control.policy.CoreCursor`): the owner of each
  slot is raised from FIFO 1 to 2 for its slice (or a late subchain of higher priority steals
  it), slot-aligned heads are triggered every ``runs`` periods, everything is lowered at the
  end of the last slice.  The loop sleeps through boundaries where nothing can change (an idle
  core; :func:`~catanc.control.policy.needs_wake`);
- a **clock**: dedicated subchains (and batch ones) are triggered every period;
- a **datagram**: registrations, ``bye``, ``set_cores`` (:mod:`catanc.runtime.enforcer.nodes`);
- the **re-optimiser's answer**: the solvers run in a child process at SCHED_OTHER
  (:mod:`catanc.runtime.enforcer.reoptimiser`); the loop sends it a request when the cadence says
  (:class:`~catanc.control.policy.Cadence`) and swaps the new schedule in when it answers;
- the **watchdog's death**: every thread is put back and the run stops (exit 9, ``ExitCode.SAFETY``);
- **housekeeping** four times a second: the rings of runs in flight, lost runs, and once a
  second the status, the log, adopted threads and the CPU set.

Only heads are triggered by the enforcer; a finishing node wakes the next one itself and
reports its run in its ring (:mod:`catanc.runtime.enforcer.runs`), read when the loop is awake anyway.
The main thread only waits for the loop (its CPUs show the process's CPU set; it handles the
signals).  Every thread the enforcer changes, its own included, is remembered first and put
back on exit, and by the watchdog process if the enforcer is killed.
"""

from __future__ import annotations

import contextlib
import gc
import heapq
import math
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from catanc.artifacts.runtime_table import RuntimeTable
from catanc.control.measure import Measurements
from catanc.control.policy import next_clock_ms, replanned
from catanc.control.schedule import RuntimeSchedule, SubchainRun
from catanc.errors import CatancError, ExitCode, LoopError, PrivilegeError, SchedError
from catanc.extras import require
from catanc.runtime.compiled import ready as compiled_ready
from catanc.runtime.compiled.ready import BackgroundBuild, LoopChoice
from catanc.runtime.enforcer.cores import SharedCores
from catanc.runtime.enforcer.costs import Costs, planned_hops
from catanc.runtime.enforcer.nodes import NodeThreads, Wiring
from catanc.runtime.enforcer.reoptimiser import PlannerProcess
from catanc.runtime.enforcer.replanning import Replanning
from catanc.runtime.enforcer.runs import Reader, RunBook
from catanc.runtime.enforcer.status import status_rows
from catanc.runtime.linux.cpu_clocks import OpenCpuClocks
from catanc.runtime.linux.levels import Levels
from catanc.runtime.linux.own_threads import OwnThreads
from catanc.runtime.linux.sched import Restorer, allowed_cpus, at_sched_other, name_thread
from catanc.runtime.logs.writer import LOG_FORMAT, Notes, RunLog
from catanc.runtime.protocol import messages as protocol
from catanc.runtime.protocol.endpoints import Endpoint, EnforcerSocket, Received, Registry, decode_or_none
from catanc.runtime.protocol.ring import RingReader

if TYPE_CHECKING:
    from catanc.runtime.compiled.entry import WalkEntry
    from catanc.runtime.compiled.loop import CompiledLoop

Start = Literal["bootstrap", "spec"]

HOUSEKEEPING_MS = 250.0
"""Rings of runs in flight and lost runs are looked at this often; the status and the log once a second."""
STATUS_EVERY_MS = 1000.0
SWITCH_INTERVAL_S = 0.0002
"""Another thread holding the interpreter lock (the main thread handling a signal) gives it up within this."""
QUIET_S = 0.05
"""After a stop, runs still in flight are awaited until no ring moved for this (and twice their node's estimate)."""


def now_ms() -> float:
    return time.monotonic_ns() / 1e6


class WatchdogLostError(CatancError):
    """The watchdog died: a SIGKILL of the enforcer would leave app threads raised, so the run stopped."""

    exit_code = ExitCode.SAFETY


class Enforcer:
    """One app's enforcer; :meth:`run` blocks until :meth:`stop`, a signal or the duration ends."""

    def __init__(
        self,
        table: RuntimeTable,
        *,
        socket_path: str,
        rt: bool = True,
        start: Start = "bootstrap",
        log_path: str | Path | None = None,
        cores: int | None = None,
        restorer: Restorer | None = None,
        clock: Callable[[], float] = now_ms,
        loop: LoopChoice = "python",
    ) -> None:
        self.table = table
        self.spec = table.spec
        self.rt = rt
        self.log_path = log_path
        self.clock = clock
        self.notes = Notes(clock, clock())  # log opened once the socket is ours: never truncate another run's log
        self.socket_path = socket_path
        self.restorer = restorer if restorer is not None else Restorer()
        self.measurements = Measurements.for_spec(self.spec)
        self.cpu_clocks = OpenCpuClocks()
        cpus = self._usable_cpus()
        if not cpus:
            raise PrivilegeError(
                f"may not run on any of the table's CPUs {sorted(table.cpus or ())} (allowed here: "
                f"{sorted(allowed_cpus())}): recompile with `catanc compile --cpus` naming allowed ones"
            )
        if table.cpus is not None and len(cpus) < len(table.cpus):
            self.notes.note(f"the table's CPUs {list(table.cpus)}: only {sorted(cpus)} allowed here")
        wanted = cores or table.cores
        planned_cores = min(wanted, len(cpus))  # two plan cores never share one CPU
        if planned_cores < wanted:
            self.notes.note(f"planning for {planned_cores} core(s), not {wanted}: CPUs {sorted(cpus)} only")
        bootstrap = self.spec.runtime.bootstrap_ms if start == "bootstrap" else None
        self.background_build: BackgroundBuild | None = None
        self.loop_why = "asked for"  # why the loop is the one it is (the status and the log's start say)
        entry = self._compiled_entry(loop)
        self.planner = PlannerProcess(
            table.spec.model_dump(mode="json", by_alias=True), planned_cores, bootstrap_ms=bootstrap
        )
        self.replanning = Replanning(self.planner, self.spec.runtime, cpus, self.notes.note)
        self.own = OwnThreads(self.restorer, rt=rt, cpu_ids=lambda: self.replanning.cpu_ids)
        self.schedule: RuntimeSchedule = self.replanning.answer.schedule
        self.registry = Registry(set(self.spec.nodes))
        self.levels = Levels(rt=rt)
        speedups = {name: tuple(node.threads.speedups) for name, node in self.spec.nodes.items()}
        self.book = RunBook(self.schedule.subchains, speedups, self._kernel_ns)
        self.book.expected = self.measurements.estimates()
        self.nodes = NodeThreads(
            self.registry,
            self.levels,
            self.restorer,
            self.schedule,
            rt=rt,
            cpus_of=self.own.cpus_of,
            note=self.notes.throttled,
            log=self.notes.write,
        )
        self.costs = Costs(planned=planned_hops(self.spec))
        self.reader = Reader(
            self.book,
            readers=self._readers,
            record=self.measurements.record,
            measured=self.measurements.nodes,
            hop=self.costs.hop,
            sample=self.notes.sample,
        )
        self.cores = SharedCores(
            self.book,
            self.levels,
            self.costs,
            trigger=self._trigger_head,
            seen=self.reader.seen,
            gone=self.nodes.gone_tids,
        )
        self.compiled = self._compiled_loop(entry)
        self.wiring: Wiring | None = None
        self.clocks: list[tuple[float, str]] = []
        self.stopping = False
        self.failure: CatancError | None = None
        # The run starts once its first plan is in (the planner's start-up is not the app's time): log times,
        # the status's elapsed time and the first housekeeping count from here.
        self.started_ms = self.notes.started_ms = clock()
        self.deadline_ms: float | None = None  # the end of a run of a given duration (set once the app is up)
        self.next_housekeeping_ms = self.started_ms
        self.next_status_ms = self.started_ms + STATUS_EVERY_MS
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._loop_done = threading.Event()
        self.attaching: list[tuple[str, int, list[int]]] = []  # from --attach, for the loop to place
        self.final: dict[str, Any] | None = None  # the status as the run ended

    # ------------------------------------------------------------------ lifecycle

    def run(
        self,
        duration_s: float | None = None,
        *,
        on_start: Callable[[Enforcer], None] | None = None,
        on_tick: Callable[[Enforcer], None] | None = None,
    ) -> None:
        """Enforce until :meth:`stop`, SIGINT/SIGTERM or ``duration_s``; call from the main thread.

        ``on_start`` runs once the socket is bound (start the app's processes there; ``duration_s``
        counts from its return); ``on_tick``
        once a second, from the loop (a live status).  The main thread runs at FIFO 4 too (a
        restore on a signal is never starved) but only waits; it keeps the process's CPU set.
        """
        previous_term = signal.signal(signal.SIGTERM, self._on_sigterm)
        previous_interval = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)  # the loop gets the interpreter lock at once when it wakes
        try:
            with EnforcerSocket(self.socket_path) as sock, self.restorer:
                self.sock = sock
                self.restorer.before_restore = self.stop
                if self.log_path is not None:
                    self.notes.log = RunLog(self.log_path)
                self.own.raise_self(pin=None)
                self.notes.write(
                    "start",
                    format=LOG_FORMAT,
                    cores=self.schedule.cores,
                    plan=self.replanning.answer.summary,
                    loop="python" if self.compiled is None else "compiled",
                    loop_why=self.loop_why,
                )
                failure: list[BaseException] = []
                loop = threading.Thread(
                    target=self._loop_thread, args=(on_tick, failure), name="catanc-loop", daemon=True
                )
                loop.start()
                try:
                    if on_start is not None:
                        on_start(self)
                    gc.freeze()  # start-up's objects never need collecting: later collections stay short
                    if duration_s is not None:  # counted from here: the app is up
                        self.deadline_ms = self.clock() + duration_s * 1000.0
                        self._wake_loop()
                    self._loop_done.wait()
                finally:
                    self.stop()
                    self._await_loop()
                    loop.join()
                    self._finish()
                if failure:
                    raise failure[0]
                if self.failure is not None:
                    raise self.failure
        finally:
            signal.signal(signal.SIGTERM, previous_term)
            sys.setswitchinterval(previous_interval)
            for fd in (self._wake_r, self._wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def _await_loop(self) -> None:
        """Wait until the loop thread has ended, whatever signals come meanwhile.

        Not ``Thread.join``: in Python 3.11 a KeyboardInterrupt in ``join`` can mark a thread that
        still runs as stopped (bpo-45274's fix releases the lock the running thread holds), and the
        end of the run would then close sockets the loop still sends on.
        """
        while not self._loop_done.is_set():
            try:
                self._loop_done.wait(0.1)
            except KeyboardInterrupt:  # a second Ctrl-C: stopping already
                self.stop()

    def stop(self) -> None:
        """End the run (from any thread or a signal handler)."""
        self.stopping = True
        self._wake_loop()

    def _wake_loop(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"!")

    def _on_sigterm(self, signum: int, frame: object) -> None:  # noqa: ARG002 - a signal handler's signature
        self.stop()

    def _loop_thread(self, on_tick: Callable[[Enforcer], None] | None, failure: list[BaseException]) -> None:
        try:
            name_thread("catanc-loop")
            self.own.start_loop(self.schedule)
            self._install(self.clock())
            self._loop(on_tick)
        except BaseException as exc:  # re-raised by run(), in the main thread
            failure.append(exc)
        finally:
            self.stopping = True
            self._loop_done.set()

    def _finish(self) -> None:
        """After the loop: stop the nodes, wait for their last runs, close everything, log the end."""
        self.final = self.status()  # as the run ended: rates and registrations before the nodes leave
        self.nodes.stop_all()
        self._await_last_runs(protocol.STOP_GRACE_S)
        self.registry.close()
        self.cpu_clocks.close()
        self.planner.close()
        if self.background_build is not None:
            self.background_build.stop()
        self._flush_samples()
        self.notes.flush()
        self.notes.write("stop", summary=self.final)
        self.notes.close()

    def _await_last_runs(self, grace_s: float) -> None:
        """At most ``grace_s``, until every run in flight has been reported (nothing new is triggered).

        Or until the rings go quiet for twice the longest estimate of the nodes those runs are at
        (and :data:`QUIET_S`): a node told to stop before its trigger arrived never runs.
        """
        deadline = time.monotonic() + grace_s
        quiet_until, progress = 0.0, -1
        while (now := time.monotonic()) < deadline:
            self._read_all(self.clock())
            at = self.book.nodes_in_flight(self.schedule.subchains)
            if not at:
                return
            readers = self.wiring.readers if self.wiring is not None else {}
            read = sum(reader.last for ring in readers.values() for _, _, reader in ring)
            if read != progress:
                progress = read
                longest = max(self.book.expected.get(node, 0.0) for node in at)
                quiet_until = now + QUIET_S + 2.0 * longest / 1000.0
            elif now >= quiet_until:
                return
            time.sleep(0.01)

    # ------------------------------------------------------------------ the loop

    def _loop(self, on_tick: Callable[[Enforcer], None] | None) -> None:
        sock = self.sock.fileno()
        planner = self.planner.fileno()
        watchdog = self._watchdog_fd()
        fds = [sock, planner, self._wake_r] + ([watchdog] if watchdog is not None else [])
        wait = select.select
        clock = self.clock
        costs = self.costs
        compiled = self.compiled
        while not self.stopping:
            now = clock()
            until = self.next_housekeeping_ms  # Python's own next time; the cores' and clocks' are added below
            deadline = self.deadline_ms
            if deadline is not None:
                if now >= deadline:
                    return
                until = min(until, deadline)
            if compiled is not None:
                # A bye or a re-plan handled since the last pass may have closed a ring the walk reads: the walk
                # must be laid out again, from fresh wiring, before it runs on.
                self._fresh_wiring()
            if compiled is not None and compiled.load(now, self.clocks):
                ready = compiled.wait(fds, until)
                compiled.store(self.clocks)
            else:
                until = min(until, self.cores.wake_ms)
                if self.clocks and self.clocks[0][0] < until:
                    until = self.clocks[0][0]
                timeout = until - now
                ready = wait(fds, (), (), timeout / 1000.0 if timeout > 0 else 0)[0]
                costs.wakes += 1
            now = clock()
            self._on_time(now)
            if ready:
                if sock in ready:
                    self._on_datagrams()
                if planner in ready:
                    self._on_answer()
                if self._wake_r in ready:
                    with contextlib.suppress(BlockingIOError):
                        while os.read(self._wake_r, 64):
                            pass
                    while self.attaching:
                        node, pid, tids = self.attaching.pop(0)
                        with at_sched_other():
                            self.nodes.attach(node, pid, tids)
                            for tid in tids:
                                self.cpu_clocks.open(pid, tid)
                if watchdog is not None and watchdog in ready:
                    self._watchdog_died()
            if now >= self.next_housekeeping_ms:
                self._housekeep(now, on_tick)

    def _on_time(self, now: float) -> None:
        self._fresh_wiring()
        cores = self.cores
        cores.run_due(now)
        clocks = self.clocks
        if clocks and clocks[0][0] <= now:
            shared = False
            while clocks and clocks[0][0] <= now:
                due, name = heapq.heappop(clocks)
                run = self.schedule.subchains.get(name)
                if run is None or not run.on_clock:
                    continue
                self._trigger_head(run, now, None if run.shared else math.inf)  # a dedicated one runs raised
                shared = shared or run.shared
                heapq.heappush(clocks, (next_clock_ms(due, run.period_ms, now), name))
            if shared:  # a core with a run in flight needs its boundaries again
                cores.rewake()

    def _trigger_head(
        self, run: SubchainRun, now: float, raised_until: float | None = None, *, at_slot: bool = False
    ) -> None:
        head = self.wiring.heads.get(run.name) if self.wiring is not None else None
        if head is None:
            self.book.state(run.name).skipped += 1
            return
        if not at_slot:  # at its slot the rings were just read and its threads raised
            self._read(run, now)  # is the head still busy?
            if run.shared and self.cores.raised_on(run):
                self.cores.raise_owner(run.cores[0], run.name, triggered=True)
        started = self.book.trigger(run, now, head, raised_until)
        if started is None:
            return
        if not head.send(protocol.trigger_datagram(head.node, started.seq, run.threads_of(0)[0])):
            self.nodes.gone(head, f"takes no triggers ({head.error})")

    # ------------------------------------------------------------------ what the nodes report

    def _read(self, run: SubchainRun, now: float) -> None:
        self.reader.read(run, now)

    def _readers(self, name: str) -> tuple[tuple[int, Endpoint, RingReader], ...]:
        return self._fresh_wiring().readers.get(name, ())

    def _fresh_wiring(self) -> Wiring:
        """The node threads as the hot path needs them, made again when a thread came or went or the plan changed."""
        wiring = self.wiring
        if wiring is None or wiring.version != self.nodes.version or wiring.schedule is not self.schedule:
            self.wiring = wiring = self.nodes.wiring(self.schedule)
            self.cores.rewire(wiring)
        return wiring

    def _compiled_entry(self, choice: LoopChoice) -> WalkEntry | None:
        """The compiled walk's entry linked into this process, or None: Python's loop.

        ``auto`` takes the compiled loop where it is built on this machine (linked in ~0.03 s); elsewhere it
        runs Python's and builds it in a child at nice 19 for the next run.  ``compiled`` builds it here
        if it must (about a minute, before the socket is bound).  Called before the re-optimiser is forked,
        which then inherits numpy instead of importing it."""
        if choice == "python":
            return None
        found = compiled_ready.find()  # the stamp and the object file read and checked once
        if choice == "auto":
            if found is None and compiled_ready.version_of("numba") is None:
                self.loop_why = "numba is not installed (the compiled loop needs it)"
                self.notes.note(f"the Python loop: {self.loop_why}")
                return None
            if found is None:
                try:
                    self.background_build = BackgroundBuild()
                except OSError as exc:
                    self.loop_why = (
                        f"the compiled loop is not built on this machine, and its build did not start: {exc}"
                    )
                else:
                    self.loop_why = (
                        "the compiled loop is not built on this machine yet: building it for the next run "
                        f"(pid {self.background_build.pid}, nice 19, about a minute of one CPU)"
                    )
                self.notes.note(f"the Python loop: {self.loop_why}")
                return None
            self.loop_why = "built on this machine"
        # numpy's BLAS would start a thread per CPU at import (and the re-optimiser would not be forked): the
        # enforcer multiplies no matrices.
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        try:
            if found is None:  # --loop compiled, not built here
                require("numba", "catanc run --loop compiled")
                entry, _ = compiled_ready.build()  # here, at SCHED_OTHER, before the loop thread is raised
            else:
                entry = compiled_ready.load(found)
        except LoopError as exc:
            if choice == "compiled":
                raise LoopError(f"catanc run --loop compiled: {exc}") from None
            self.loop_why = f"the compiled loop does not load here: {exc}"
            self.notes.note(f"the Python loop: {self.loop_why}")
            return None
        return entry

    def _compiled_loop(self, entry: WalkEntry | None) -> CompiledLoop | None:
        """The shared cores walked by ``entry`` between the loop's visits to Python, or None: Python's loop."""
        if entry is None:
            return None
        from catanc.runtime.compiled.loop import CompiledLoop  # noqa: PLC0415 - numpy only when asked for

        def untaken(name: str) -> None:
            head = self.wiring.heads.get(name) if self.wiring is not None else None
            if head is not None:
                self.nodes.gone(head, "takes no triggers (a send failed)")

        return CompiledLoop(
            self.cores,
            self.costs,
            self.reader.seen,
            entry=entry,
            kernel_fd=lambda endpoint: self.cpu_clocks.opened_fd(endpoint.tid),
            gone=self.nodes.gone_tids,
            untaken=untaken,
            fds_generation=lambda: self.cpu_clocks.generation,
        )

    def _read_name(self, name: str, now: float) -> None:
        run = self.schedule.subchains.get(name)
        if run is not None:
            self._read(run, now)

    def _read_all(self, now: float) -> None:
        for name, run in self.schedule.subchains.items():
            if self.book.busy(name):
                self._read(run, now)

    def _flush_samples(self) -> None:
        self._read_all(self.clock())
        self.reader.flush()

    def _kernel_ns(self, endpoint: Endpoint) -> int | None:
        """``endpoint``'s thread CPU time so far (ns), from the kernel; None if unreadable."""
        try:  # opened at registration, at SCHED_OTHER: the loop looks nothing up in /proc
            return self.cpu_clocks.read_opened_ns(endpoint.tid)
        except (OSError, ValueError):
            return None

    # ------------------------------------------------------------------ datagrams

    def _on_datagrams(self) -> None:
        for received in self.sock.receive():
            message, why = decode_or_none(received.data)
            if message is None:
                self.notes.throttled("datagram", f"dropped a datagram: {why}")
            elif isinstance(message, protocol.Hello):
                self._hello(message, received)
            elif isinstance(message, protocol.Bye):
                self.nodes.bye(message, received.sender)
            elif isinstance(message, protocol.SetCores):
                self._set_cores(message, received)
            elif not isinstance(message, protocol.Done):  # runs are read from the rings; a done is only a hint
                self.notes.throttled("datagram", f"dropped a {message.TYPE} message: not one a node sends")

    def _hello(self, hello: protocol.Hello, received: Received) -> None:
        try:
            with at_sched_other():  # it looks the peer's pid up in /proc
                registered = self.nodes.hello(hello, received, self.sock)
                if registered is not None:
                    self.cpu_clocks.open(hello.pid, hello.tid)
        except SchedError as exc:  # the watchdog's pipe broke: it is gone
            self._watchdog_died(str(exc))

    def _set_cores(self, message: protocol.SetCores, received: Received) -> None:
        credentials = received.credentials
        if credentials is None or credentials.uid not in (0, os.geteuid()):
            uid = "unknown" if credentials is None else credentials.uid
            self.notes.throttled("set_cores", f"ignored set_cores from uid {uid}: only root or this user may")
            return
        self.replanning.requested_cores = message.cores

    # ------------------------------------------------------------------ plans

    def _install(self, now: float) -> None:
        """Start the schedule in force from ``now``: every core's period and every clock (a new allocation too)."""
        self.cores.install(self.schedule, now)
        self.clocks = [(now, run.name) for run in self.schedule.clocked]
        heapq.heapify(self.clocks)
        self.costs.core = self.own.loop_core(self.schedule)

    def _on_answer(self) -> None:
        try:
            request, answer = self.replanning.answered(self.elapsed_s())
        except (EOFError, OSError):
            self.failure = CatancError("the re-optimiser process ended; the run stops")
            self.stop()
            return
        if request is None:  # pragma: no cover - the planner answers only what it is asked
            return
        changed = False
        if answer.error is not None:  # keep the last good plan and its slots
            self.notes.note(f"re-plan failed, keeping the last plan: {answer.error}")
        else:
            before = self.schedule
            self.schedule = answer.schedule
            self.nodes.schedule = answer.schedule
            replan = replanned(before, answer.schedule)
            changed = replan.moved
            if replan.reinstall:  # every thread re-pinned, every core and clock restarted
                self.nodes.place_all()
                self.own.pin_loop(self.schedule)
                self._install(self.clock())
            else:
                self.cores.update(answer.schedule)
                if before.cores != answer.schedule.cores:  # the same placement on other CPUs (fewer were left)
                    self.nodes.place_all()
                    self.cores.forget_raised()
                    self.own.pin_loop(self.schedule)
            self.nodes.routes()
        self.notes.write(
            "resolve",
            reason=request.reason,
            stage1=request.kind != "resolve",
            allocation_changed=changed,
            solve_ms=round(answer.solve_ms, 3),
            error=answer.error,
            compute_ms={k: round(v, 3) for k, v in sorted(request.compute_ms.items())},
            plan=answer.summary,
        )

    # ------------------------------------------------------------------ housekeeping

    def _housekeep(self, now: float, on_tick: Callable[[Enforcer], None] | None) -> None:
        self.next_housekeeping_ms = now + HOUSEKEEPING_MS
        self._read_all(now)
        self.reader.flush()
        self.cores.rewake()  # runs that ended may leave a core idle
        for name, seq, node in self.book.lost(self.schedule.subchains, now):
            self.notes.note(f"{name}: run {seq} lost at {node} (no answer in time)")
            self.notes.write("lost", subchain=name, seq=seq, node=node)
        self._cores_and_cadence(now)
        if now < self.next_status_ms:
            return
        self.next_status_ms = now + STATUS_EVERY_MS
        self.nodes.adopt_spawned()
        self.book.expected = self.measurements.estimates()
        if self.own.loop_tid is not None:
            self.costs.cpu(time.monotonic_ns(), time.thread_time_ns())
        self.notes.write("status", **self.status())
        self.notes.flush()
        if on_tick is not None:
            on_tick(self)

    def _usable_cpus(self) -> frozenset[int]:
        """The CPUs plan cores run on: those of the table's (``compile --cpus``) this process may use, else all
        it may use."""
        allowed = allowed_cpus()
        return allowed & frozenset(self.table.cpus) if self.table.cpus is not None else allowed

    def _cores_and_cadence(self, now: float) -> None:
        if self.replanning.asked is not None:
            return  # one request at a time
        cpus = self._usable_cpus()
        if self.stopping:  # read after the CPUs: a signal's restore (main thread back to its first CPUs) stops first
            return
        step = self.replanning.step(
            now - self.started_ms,
            cpus,
            self.schedule.cores,
            lambda: self.measurements.estimates(measured_only=True),
            lambda: self.replanning.measured_costs(self.costs.summary(self.schedule.cores), self.spec.schedule),
        )
        if step.repin:  # as many CPUs, but others: the same plan, pinned to them
            self.nodes.place_all()
            self.cores.forget_raised()
            self.own.pin_loop(self.schedule)
            self.notes.write("repin", cpus=self.own.cpu_ids)

    # ------------------------------------------------------------------ the watchdog

    def _watchdog_fd(self) -> int | None:
        watchdog = self.restorer.watchdog
        if watchdog is None or watchdog.pid is None:
            return None
        try:
            return os.pidfd_open(watchdog.pid)
        except OSError:
            self._watchdog_died()
            return None

    def _watchdog_died(self, why: str = "") -> None:
        """The watchdog is gone: put every thread back now and stop (a SIGKILL would leave them raised)."""
        report = self.restorer.restore_all()
        message = "the watchdog process died: every thread was put back and the run stopped"
        self.notes.note(message)
        self.notes.write("watchdog", restored=len(report.restored), why=why or "exited")
        self.failure = WatchdogLostError(message + (f" ({why})" if why else ""))
        self.stop()

    # ------------------------------------------------------------------ observing

    def elapsed_s(self) -> float:
        return (self.clock() - self.started_ms) / 1000.0

    def status(self) -> dict[str, Any]:
        """Per subchain: planned and measured rate, p95 compute, late, lost, steals; the enforcer's costs."""
        last = self.replanning.last_resolve_s
        since = None if last is None else self.elapsed_s() - last
        costs = self.costs.summary(self.schedule.cores)
        return {
            "subchains": status_rows(self.schedule, self.book, self.measurements, self.registry, self.clock()),
            "last_resolve_s": last,
            "since_resolve_s": since,
            "switches": costs["switch_by_core"],
            "costs": costs,
        }

    @property
    def events(self) -> list[str]:
        """Short notes for the live status (node crashed, ...), the last ten."""
        return self.notes.texts

    def attach(self, node: str, pid: int, tids: list[int]) -> None:
        """Pin and prioritise the threads of a process that does not speak the protocol, as ``node``'s (the loop
        does it, at once)."""
        self.attaching.append((node, pid, list(tids)))
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"a")
