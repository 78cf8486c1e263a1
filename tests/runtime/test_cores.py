"""The enforcer's hot path (catanc.runtime.enforcer.cores) without a kernel: which threads it raises at each boundary,
which heads it triggers, and when it asks to be woken, against the schedule worked by hand."""

from __future__ import annotations

import math

from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun
from catanc.runtime.enforcer.cores import SharedCores
from catanc.runtime.enforcer.costs import Costs
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook, Seen
from catanc.runtime.linux.levels import Levels

# T = 10 ms: a (2 ms, triggered every period, priority 2) then b (3 ms, every 2 periods); threads a: 11, b: 12.
CORE = CoreSchedule(0, 10.0, 0.5, (Slot("a", 0.5, 2.0), Slot("b", 3.0, 3.0)))
RUNS = {
    "a": SubchainRun("a", ("a",), (0,), True, 10.0, 10.0, 1, 2),
    "b": SubchainRun("b", ("b",), (0,), True, 20.0, 20.0, 2, 1),
}
SCHEDULE = RuntimeSchedule(1, RUNS, (CORE,))


def made() -> tuple[SharedCores, RunBook, Levels, list[tuple[float, str]]]:
    book = RunBook(RUNS, {}, lambda _endpoint: None)
    levels = Levels(rt=False)
    triggered: list[tuple[float, str]] = []

    def trigger(run: SubchainRun, now: float, raised_until: float | None = None, *, at_slot: bool = False) -> None:
        book.trigger(run, now, None, raised_until)
        triggered.append((now, run.name))

    cores = SharedCores(book, levels, Costs(), trigger=trigger, seen=Seen(), gone=lambda _tids: None)
    cores.rewire(Wiring(0, SCHEDULE, {"a": (), "b": ()}, {"a": ((11,),), "b": ((12,),)}, {}))
    cores.install(SCHEDULE, 0.0)
    return cores, book, levels, triggered


def test_each_slot_raises_its_owner_and_triggers_its_head_on_its_cycle() -> None:
    cores, book, levels, triggered = made()
    seen = []
    for now in (0.0, 2.5, 6.0, 10.0, 12.5, 16.0, 20.0, 22.5):
        cores.run_due(now)
        seen.append((now, cores.raised[0], sorted(levels.raised.get(0, ()))))
        book.states["a"].in_flight.clear()  # a's runs end within its slice
    assert triggered == [(0.0, "a"), (2.5, "b"), (10.0, "a"), (20.0, "a"), (22.5, "b")]
    assert seen == [
        (0.0, "a", [11]),
        (2.5, "b", [12]),
        (6.0, None, []),  # the end of the last slice: everything lowered
        (10.0, "a", [11]),
        (12.5, "b", [12]),  # b has a run in flight (triggered at 2.5, never done here): raised
        (16.0, None, []),
        (20.0, "a", [11]),
        (22.5, "b", [12]),
    ]


def test_an_idle_core_sleeps_until_the_next_head_it_triggers() -> None:
    cores, book, _levels, triggered = made()
    cores.run_due(0.0)  # a triggered and raised: awake at b's switch
    assert cores.wake_ms == 2.5
    book.states["a"].in_flight.clear()  # a's run ended
    cores.run_due(2.5)  # b's trigger
    assert cores.wake_ms == 6.0
    book.states["b"].in_flight.clear()
    cores.run_due(6.0)  # all lowered, nothing in flight: the next boundary that does anything is a's at 10
    assert cores.wake_ms == 10.0
    cores.run_due(10.0)
    book.states["a"].in_flight.clear()
    cores.run_due(12.5)  # b is not triggered in period 1 and nothing runs: skip to its end, then to 20
    cores.run_due(16.0)
    assert cores.wake_ms == 20.0
    assert triggered == [(0.0, "a"), (2.5, "b"), (10.0, "a")]


def test_a_late_subchain_of_higher_priority_takes_the_slot() -> None:
    cores, book, levels, _triggered = made()
    cores.run_due(0.0)  # a triggered at 0, latency 10: late from 10 ms on
    cores.run_due(2.5)
    cores.run_due(6.0)
    cores.run_due(10.0)  # a's own slot: a second trigger is deferred while the first runs
    cores.run_due(12.5)  # b's slot, a late: a keeps the core
    assert cores.raised[0] == "a"
    assert sorted(levels.raised[0]) == [11]
    assert book.state("a").steals == 1
    assert math.isfinite(cores.wake_ms)


def test_threads_raised_for_a_run_that_ended_are_lowered_at_once_and_the_core_sleeps() -> None:
    cores, book, levels, triggered = made()
    cores.run_due(0.0)
    book.states["a"].in_flight.clear()
    cores.run_due(2.5)
    book.states["b"].in_flight.clear()
    cores.run_due(6.0)
    cores.run_due(10.0)  # period 1: a triggered and raised, b not due
    assert cores.wake_ms == 12.5
    book.states["a"].in_flight.clear()  # a's run ended (its ring read by the housekeeping)
    cores.rewake()
    assert cores.wake_ms == 20.0  # nothing changes on the core until a's next trigger
    assert not levels.raised.get(0)  # a's thread, asleep, is put back at once, not at b's switch
    samples = len(cores.costs.switches[0])
    cores.run_due(20.0)  # b's switch and the period's end caught up in order, then a's switch
    assert triggered[-1] == (20.0, "a")
    assert cores.raised[0] == "a"
    assert sorted(levels.raised[0]) == [11]
    assert len(cores.costs.switches[0]) == samples + 1  # the caught-up boundaries are not switch latencies
