"""The triggering rules shared by the enforcer and the simulator (catanc.control.flights), worked by hand,
and a random walk of triggers and completions against a plain list of runs."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from catanc.control.flights import Flight, Flights, NodeQueues, Started


def test_a_head_trigger_while_the_head_runs_is_deferred_once() -> None:
    runs: Flights[Flight] = Flights()
    assert runs.start(Flight(0, 10.0)) == Started(1)
    assert runs.start(Flight(0, 11.0)) == Started(2, deferred=True)  # the head still runs run 1: sent, queued
    assert runs.start(Flight(0, 12.0)) is None
    assert (runs.pending, runs.skipped) == (2, 1)  # two deferred triggers count once
    handoff = runs.node_done(1, length=2)
    assert handoff is not None
    assert (handoff.next_index, handoff.head_done) == (1, True)
    assert runs.start_pending(Flight(0, 13.0)) == 2  # what the owner does on head_done
    assert (runs.pending, runs.skipped) == (None, 1)
    assert runs.in_flight[2].triggered_ms == 13.0  # a deferred run counts from when it could start
    assert runs.start_pending(Flight(0, 14.0)) is None
    assert runs.oldest_ms() == 10.0


def test_a_deferred_run_whose_head_run_was_lost_starts_at_the_next_trigger() -> None:
    runs: Flights[Flight] = Flights()
    assert runs.start(Flight(0, 0.0)) == Started(1)
    assert runs.start(Flight(0, 1.0)) == Started(2, deferred=True)
    del runs.in_flight[1]  # given up as lost at the head
    assert runs.start(Flight(0, 5.0)) is None  # no new trigger: the deferred one was sent already
    assert (runs.pending, sorted(runs.in_flight)) == (None, [2])
    assert runs.start(Flight(0, 6.0)) == Started(3, deferred=True)


def test_a_run_over_its_latency_counts_as_late() -> None:
    runs: Flights[Flight] = Flights()
    for triggered, done in ((0.0, 4.0), (10.0, 15.0)):  # latencies 4 and 5 ms against 4.5 planned
        started = runs.start(Flight(0, triggered))
        assert started is not None
        seq = started.seq
        handoff = runs.node_done(seq, length=1)
        assert handoff is not None
        assert (handoff.next_index, handoff.head_done) == (None, True)
        assert runs.over(handoff.flight, done, latency_ms=4.5) == done - triggered
    assert runs.late == 1
    assert runs.in_flight == {}
    assert runs.oldest_ms() is None


def test_a_run_not_in_flight_is_ignored() -> None:
    runs: Flights[Flight] = Flights()
    assert runs.node_done(7, length=3) is None
    started = runs.start(Flight(0, 0.0))
    assert started is not None
    seq = started.seq
    del runs.in_flight[seq]  # given up as lost
    assert runs.node_done(seq, length=3) is None


def test_runs_wait_at_a_busy_node_in_order() -> None:
    nodes = NodeQueues()
    assert not nodes.queued("b", 1)
    nodes.started("b", 1)
    assert nodes.queued("b", 2)
    assert nodes.queued("b", 3)
    assert (nodes.busy_with("b"), nodes.busy_with("c"), nodes.any_busy()) == (1, None, True)
    assert nodes.free("b") == 2
    nodes.started("b", 2)
    assert nodes.free("b") == 3
    assert nodes.free("b") is None
    assert not nodes.any_busy()


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 5)), max_size=60), st.integers(1, 3))
def test_a_random_walk_keeps_one_run_at_the_head_and_every_run_once(steps: list[tuple[bool, int]], length: int) -> None:
    """Triggers and completions in any order: against a plain model (seq -> node index), no run is lost or
    doubled, at most one is at the head, and a deferred trigger starts a run as soon as the head is free."""
    runs: Flights[Flight] = Flights()
    model: dict[int, int] = {}
    started = over = 0
    pending: int | None = None
    for now, (trigger, pick) in enumerate(steps):
        if trigger or not model:
            got = runs.start(Flight(0, float(now)))
            if 0 in model.values():
                if pending is None:
                    assert got == Started(started + 1, deferred=True)
                    started += 1
                    pending = started
                else:
                    assert got is None
                assert runs.pending == pending
                continue
            assert got == Started(started + 1)
            assert runs.pending is None
            started += 1
            model[started] = 0
            continue
        seq = sorted(model)[pick % len(model)]
        handoff = runs.node_done(seq, length)
        assert handoff is not None
        assert handoff.head_done == (model[seq] == 0)
        if model[seq] + 1 < length:
            model[seq] += 1
            assert handoff.next_index == model[seq]
        else:
            del model[seq]
            over += 1
            assert handoff.next_index is None
        if handoff.head_done:
            assert runs.start_pending(Flight(0, float(now))) == pending
            if pending is not None:
                model[pending] = 0
                pending = None
        assert {seq: flight.index for seq, flight in runs.in_flight.items()} == model
        assert list(model.values()).count(0) <= 1
    assert started == over + len(model) + (pending is not None)
