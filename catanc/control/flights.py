"""Runs in flight: the triggering rules that ``catanc run`` enforces and the simulator models.

A run of a subchain is triggered at its head and handed from node to node;
it is *in flight* until its last node finishes.

- A head trigger while the head still runs an earlier run is deferred: the
  subchain is *pending* under the next seq, and that run starts the moment the
  head finishes (the enforcer sends its trigger at once, and the head takes it
  when it is done).  One trigger is deferred at most; those that come meanwhile
  count once as skipped.
- A run that ends later than the latency the plan gives it counts as late: its subchain's
  latency and its planned wait for an executor's thread
  (:attr:`~catanc.control.schedule.SubchainRun.late_after_ms`).
- A node never gets a second run while it runs (:class:`NodeQueues`): the
  runs of a pipelined subchain wait at each node, in order.

:mod:`catanc.runtime.enforcer.run` and :mod:`catanc.sim.policies` both keep
their subchains' runs here, so the simulation follows the enforcer's rules by
construction; the compiled simulator keeps the same rules in arrays and is
checked run for run against the Python one.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Generic, NamedTuple, TypeVar


@dataclass(slots=True)
class Flight:
    """One run of a subchain in flight."""

    index: int  # the node of the subchain running it now
    triggered_ms: float


FlightT = TypeVar("FlightT", bound=Flight)


class Handoff(NamedTuple, Generic[FlightT]):
    """What a node's finishing a run means for the run (a named tuple: the enforcer makes one per run and node)."""

    flight: FlightT
    next_index: int | None  # the subchain's node to run next, or None: the run is over (no longer in flight)
    head_done: bool  # the node was the head: a deferred head trigger may start the next run now


class Started(NamedTuple):
    """A head trigger taken: run ``seq`` starts now, or (``deferred``) once the head is done with its run."""

    seq: int
    deferred: bool = False


@dataclass
class Flights(Generic[FlightT]):
    """One subchain's runs in flight, by seq (1, 2, ... in trigger order), and what became of them."""

    seq: int = 0
    in_flight: dict[int, FlightT] = field(default_factory=dict)
    pending: int | None = None  # the seq of a head trigger that came while the head was busy: it starts when done
    late: int = 0
    skipped: int = 0  # head triggers not started (the owner counts its own reasons here too)

    def oldest_ms(self) -> float | None:
        """When the oldest run in flight was triggered (None: none is)."""
        return min((flight.triggered_ms for flight in self.in_flight.values()), default=None)

    def head_busy(self) -> bool:
        return any(other.index == 0 for other in self.in_flight.values())

    def start(self, flight: FlightT) -> Started | None:
        """A head trigger: ``flight`` in flight under a new seq; deferred (:attr:`pending`, the seq reserved) when
        the head still runs a run; None when one is deferred already (or a deferred one is taken as started)."""
        if self.head_busy():
            if self.pending is not None:
                return None
            self.skipped += 1
            self.seq += 1
            self.pending = self.seq
            return Started(self.seq, deferred=True)
        if self.pending is not None:  # its head run vanished (lost): the deferred trigger, sent already, starts it
            self.start_pending(flight)
            return None
        self.seq += 1
        self.in_flight[self.seq] = flight
        return Started(self.seq)

    def start_pending(self, flight: FlightT) -> int | None:
        """The head is done: the deferred run, if any, is in flight as ``flight`` now; its seq (None: none waited)."""
        seq = self.pending
        if seq is not None:
            self.pending = None
            self.in_flight[seq] = flight
        return seq

    def node_done(self, seq: int, length: int) -> Handoff[FlightT] | None:
        """Run ``seq``'s current node finished (the subchain has ``length`` nodes): its next node, or the run
        is over.  None for a run not in flight (given up as lost, or from before a re-plan)."""
        flight = self.in_flight.get(seq)
        if flight is None:
            return None
        head_done = flight.index == 0
        if flight.index + 1 < length:
            flight.index += 1
            return Handoff(flight, flight.index, head_done)
        del self.in_flight[seq]
        return Handoff(flight, None, head_done)

    def over(self, flight: FlightT, now_ms: float, latency_ms: float) -> float:
        """A run that is over (:meth:`node_done`): its latency, counted as late beyond ``latency_ms``."""
        took = now_ms - flight.triggered_ms
        if took > latency_ms:
            self.late += 1
        return took


class NodeQueues:
    """Which run each node is busy with, and the runs that reached it meanwhile, in order."""

    def __init__(self) -> None:
        self._busy: dict[str, int] = {}
        self._waiting: dict[str, deque[int]] = {}

    def busy_with(self, node: str) -> int | None:
        """The run ``node`` was triggered for and has not finished (None: it is free)."""
        return self._busy.get(node)

    def any_busy(self) -> bool:
        return bool(self._busy)

    def queued(self, node: str, seq: int) -> bool:
        """Whether run ``seq`` must wait for ``node``: queued behind the run it is busy with."""
        if node not in self._busy:
            return False
        self._waiting.setdefault(node, deque()).append(seq)
        return True

    def started(self, node: str, seq: int) -> None:
        """``node`` was triggered for run ``seq``."""
        self._busy[node] = seq

    def free(self, node: str) -> int | None:
        """``node`` finished its run: the next run waiting for it (to trigger now), if any."""
        self._busy.pop(node, None)
        queue = self._waiting.get(node)
        return queue.popleft() if queue else None
