"""The enforcer's runs in flight as its nodes' rings report them (catanc.runtime.enforcer.runs), worked by hand.

Rings are real (a memfd written with the documented layout); the kernel's CPU count is a fake
the test sets, so the numbers are known.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from catanc.control.schedule import SubchainRun
from catanc.runtime.enforcer.runs import KERNEL_CHECK_EVERY, RunBook, Seen
from catanc.runtime.protocol import ring
from catanc.runtime.protocol.endpoints import Endpoint, Registry

MS = 1_000_000  # ns


Readers = list[tuple[int, Endpoint, ring.RingReader]]
TwoNodes = tuple[RunBook, SubchainRun, list[ring.RingWriter], Readers]


@pytest.fixture
def two_nodes() -> Iterator[TwoNodes]:
    """Subchain ``s`` of nodes a -> b (planned latency 10 ms), each with a ring; a kernel clock the test sets."""
    run = SubchainRun("s", ("a", "b"), (0,), True, 20.0, 10.0, 1, 1)
    fds = [ring.create(slots=8) for _ in run.nodes]
    writers = [ring.RingWriter(fd) for fd in fds]
    readers = []
    for index, (node, fd) in enumerate(zip(run.nodes, fds, strict=True)):
        endpoint = Endpoint(node, 1, 100 + index, None, reader=ring.RingReader(fd, 8), ring_fd=fd)
        assert endpoint.reader is not None
        readers.append((index, endpoint, endpoint.reader))
    kernel: dict[int, int] = {}
    book = RunBook(["s"], {"a": (1.0,), "b": (1.0, 1.5)}, lambda endpoint: kernel.get(endpoint.tid))
    book.kernel_counts = kernel  # type: ignore[attr-defined]
    yield book, run, writers, readers
    for writer in writers:
        writer.close()
    for _, endpoint, _ in readers:
        endpoint.close()


def read(book: RunBook, run: SubchainRun, readers: Readers, now: float) -> Seen:
    seen = Seen()
    book.read(run, readers, now, seen)
    return seen


def test_a_run_goes_node_by_node_and_its_latency_hops_and_computes_are_seen(two_nodes: TwoNodes) -> None:
    book, run, (a, b), readers = two_nodes
    started = book.trigger(run, 100.0, None, until_ms=110.0)
    assert started is not None
    seq = started.seq
    a.append(seq, 100_200 * 1000, 103_000 * 1000, 2_500_000, 1)  # starts 0.2 ms after the trigger, runs 2.8 ms
    seen = read(book, run, readers, 103.5)
    assert [(c.node, c.ms) for c in seen.computes] == [("a", 2.5)]
    assert [(h.node, round(h.delay_ms, 6), h.inside) for h in seen.hops] == [("a", 0.2, False)]  # the trigger's
    assert seen.runs == []
    assert book.first_index("s") == 1  # at b now
    b.append(seq, 103_100 * 1000, 106_000 * 1000, 2_000_000, 2)  # on 2 threads: 2 ms of wall is 3 ms on one
    seen = read(book, run, readers, 107.0)
    assert [(c.node, c.ms) for c in seen.computes] == [("b", 3.0)]
    assert [(h.node, round(h.delay_ms, 6), h.inside) for h in seen.hops] == [("b", 0.1, True)]  # a's end to b's start
    assert [h.edge for h in seen.hops] == [("a", "b")]
    assert [(r.seq, r.latency_ms) for r in seen.runs] == [(seq, 6.0)]  # trigger at 100 ms, b ended at 106 ms
    assert not book.busy("s")
    assert book.state("s").late == 0


def test_a_runs_age_is_its_end_minus_its_origin_or_a_heads_start(two_nodes: TwoNodes) -> None:
    """Worked by hand: the age a chain's response is measured from (``age_ms`` in the log)."""
    book, run, (a, b), readers = two_nodes
    ages = []
    for origin_a, origin_b in ((0, 0), (95 * MS, 0), (0, 97 * MS), (0, 200 * MS)):
        started = book.trigger(run, 100.0, None, until_ms=110.0)
        assert started is not None
        a.append(started.seq, 100_200 * 1000, 103_000 * 1000, 2 * MS, origin_ns=origin_a)
        b.append(started.seq, 103_100 * 1000, 106_000 * 1000, 2 * MS, origin_ns=origin_b)
        seen = read(book, run, readers, 107.0)
        ages.append([(c.node, None if c.age_ms is None else round(c.age_ms, 6)) for c in seen.computes])
    assert ages == [
        [("a", 2.8), ("b", None)],  # no origin: the head's start (100.2 ms) to its end; none for b
        [("a", 8.0), ("b", None)],  # sensed at 95 ms, a ended at 103 ms
        [("a", 2.8), ("b", 9.0)],  # b's own origin: 97 ms to its end at 106 ms
        [("a", 2.8), ("b", 0.0)],  # an origin after the run's end (a bad clock): never negative
    ]


def test_hops_after_the_slot_are_waits_not_costs(two_nodes: TwoNodes) -> None:
    book, run, (a, b), readers = two_nodes
    started = book.trigger(run, 0.0, None, until_ms=5.0)  # raised until 5 ms
    assert started is not None
    a.append(started.seq, 1 * MS, 4 * MS, 3 * MS)
    b.append(started.seq, 9 * MS, 10 * MS, 1 * MS)  # started after the slot: it waited for the CPU
    seen = read(book, run, readers, 12.0)
    assert [h.node for h in seen.hops] == ["a"]
    assert len(seen.runs) == 1


def test_a_run_started_behind_an_earlier_one_measures_no_hops(two_nodes: TwoNodes) -> None:
    # On one core the earlier run's b runs first, at the same level: the later head waits for the
    # CPU, which is no cost of the runtime's (counted, it raised switch_ms on every re-plan).
    book, run, (a, b), readers = two_nodes
    first = book.trigger(run, 0.0, None, until_ms=20.0)
    assert first is not None
    a.append(first.seq, 0, 2 * MS, 2 * MS)
    read(book, run, readers, 2.5)  # the first run is at b
    second = book.trigger(run, 3.0, None, until_ms=20.0)
    assert second is not None
    b.append(first.seq, 2 * MS, 7 * MS, 5 * MS)
    a.append(second.seq, 7 * MS, 9 * MS, 2 * MS)  # started when b was done: 4 ms after its trigger
    b.append(second.seq, 9 * MS, 10 * MS, 1 * MS)
    seen = read(book, run, readers, 11.0)
    assert [(r.seq, r.latency_ms) for r in seen.runs] == [(first.seq, 7.0), (second.seq, 7.0)]
    assert [h.node for h in seen.hops] == ["b"]  # the first run's hop only


def test_an_entry_of_a_run_not_at_that_node_is_dropped(two_nodes: TwoNodes) -> None:
    book, run, (a, b), readers = two_nodes
    started = book.trigger(run, 0.0, None)
    assert started is not None
    b.append(started.seq, 1 * MS, 2 * MS, 1 * MS)  # b reports a run that is still at a
    a.append(10**9, 1 * MS, 2 * MS, 10**17)  # a run never triggered
    a.append(started.seq + 1, 1 * MS, 2 * MS, 1 * MS)  # nor this one
    seen = read(book, run, readers, 3.0)
    assert seen.computes == []
    assert book.state("s").unmatched == 3
    assert book.first_index("s") == 0  # nothing moved


def test_a_run_nothing_triggered_is_the_oldest_waiting_at_its_node(two_nodes: TwoNodes) -> None:
    book, run, (a, b), readers = two_nodes
    first = book.trigger(run, 0.0, None)
    assert first is not None
    a.append(first.seq, 0, 1 * MS, 1 * MS)
    read(book, run, readers, 1.5)
    second = book.trigger(run, 2.0, None)
    assert second is not None
    a.append(second.seq, 2 * MS, 3 * MS, 1 * MS)
    read(book, run, readers, 3.5)  # both runs wait at b now
    b.append(0, 4 * MS, 5 * MS, 1 * MS)  # a subscription callback: it took the older one
    seen = read(book, run, readers, 5.5)
    assert [r.seq for r in seen.runs] == [first.seq]
    assert list(book.state("s").in_flight) == [second.seq]


def test_a_compute_time_is_clamped_to_the_time_since_the_trigger(two_nodes: TwoNodes) -> None:
    book, run, (a, _b), readers = two_nodes
    started = book.trigger(run, 100.0, None)
    assert started is not None
    a.append(started.seq, 100 * MS, 104 * MS, 10**17)  # 1e8 ms claimed after 4.5 ms
    seen = read(book, run, readers, 104.5)
    assert [c.ms for c in seen.computes] == [4.5]


def test_a_report_far_above_the_estimate_is_held_to_the_kernels_count(two_nodes: TwoNodes) -> None:
    book, run, (a, _b), readers = two_nodes
    book.expected = {"a": 2.0}
    kernel: dict[int, int] = book.kernel_counts  # type: ignore[attr-defined]
    claims = []
    for i in range(3):
        started = book.trigger(run, 100.0 * i, None)
        assert started is not None
        kernel[100] = (i + 1) * 3 * MS  # the thread used 3 ms of CPU per run
        a.append(started.seq, int(100.0 * i * MS), int((100.0 * i + 50) * MS), 40 * MS)  # claims 40 ms each
        claims += [c.ms for c in read(book, run, readers, 100.0 * i + 60).computes]
        book.state("s").in_flight.clear()  # b never runs here: only a's reports matter
    # the first check marks where to count from (the elapsed bound holds, 40 ms); then the kernel's 3 ms
    assert claims == [40.0, pytest.approx(3.05), pytest.approx(3.05)]


def checked_run_of_2_ms_where_the_kernel_counts_5(two_nodes: TwoNodes) -> None:
    """Trigger the head up to the run the kernel checks, which reports 2 ms; its thread's count grows by 5 ms."""
    book, run, (a, _b), readers = two_nodes
    head = readers[0][1]
    kernel: dict[int, int] = book.kernel_counts  # type: ignore[attr-defined]
    for _ in range(KERNEL_CHECK_EVERY - 1):
        book.trigger(run, 0.0, head)
        book.state("s").in_flight.clear()
    kernel[100] = 0
    checked = book.trigger(run, 100.0, head)
    assert checked is not None
    assert checked.seq % KERNEL_CHECK_EVERY == 0
    a.append(checked.seq, 100 * MS, 102 * MS, 2 * MS)
    kernel[100] = 5 * MS


@pytest.mark.parametrize("again", [False, True])
def test_the_heads_kernel_check_spans_no_later_run_of_it(two_nodes: TwoNodes, again: bool) -> None:
    book, run, _, readers = two_nodes
    head = readers[0][1]
    checked_run_of_2_ms_where_the_kernel_counts_5(two_nodes)  # then 3 ms more: its next run, if triggered again
    if again:
        assert book.trigger(run, 102.5, head) is not None  # taken while the entry was unread
    computes = [c.ms for c in read(book, run, readers, 103.0).computes]
    # Not triggered again: the kernel's 5 ms stand (the client under-reported); triggered again,
    # the thread's CPU since spans the next run: the client's 2 ms.
    assert computes == ([2.0] if again else [5.0])


def test_a_head_whose_thread_hosts_another_node_keeps_its_own_figure(two_nodes: TwoNodes) -> None:
    # The same checked run as above, but the head's thread also hosts b (one executor thread): the
    # thread's 5 ms are the two nodes', so the head keeps its own 2 ms.
    book, run, _, readers = two_nodes
    head = readers[0][1]
    registry = Registry({"a", "b"})
    registry.add(head)
    other = Endpoint("b", 1, head.tid, None)
    registry.add(other)
    assert head.shares_thread
    checked_run_of_2_ms_where_the_kernel_counts_5(two_nodes)
    assert [c.ms for c in read(book, run, readers, 103.0).computes] == [2.0]
    assert registry.remove(other)  # b leaves the thread: the head is alone in it again
    assert not head.shares_thread


@pytest.mark.parametrize(
    ("kernel_ms", "recorded"),
    [
        (0.5, 0.2),  # 0.3 ms more: the client's own work around its callback, which the kernel counts too
        (0.1, 0.1),  # 0.1 ms less than claimed: the thread cannot have used more than the kernel counted
        (1.0, 1.0),  # 0.8 ms more: more than the client's work explains, CPU it did not report
    ],
)
def test_a_checked_head_run_keeps_the_clients_figure_where_the_kernel_makes_it_plausible(
    two_nodes: TwoNodes, kernel_ms: float, recorded: float
) -> None:
    book, run, (a, _b), readers = two_nodes
    head = readers[0][1]
    kernel: dict[int, int] = book.kernel_counts  # type: ignore[attr-defined]
    for _ in range(KERNEL_CHECK_EVERY - 1):  # up to the run the kernel checks
        book.trigger(run, 0.0, head)
        book.state("s").in_flight.clear()
    kernel[100] = 7 * MS
    checked = book.trigger(run, 100.0, head)
    assert checked is not None
    a.append(checked.seq, 100 * MS, int(100.2 * MS), int(0.2 * MS))  # the client: 0.2 ms
    kernel[100] = 7 * MS + int(kernel_ms * MS)
    computes = read(book, run, readers, 101.0).computes
    assert len(computes) == 1
    assert (computes[0].ms, computes[0].reported_ms, computes[0].kernel_ms) == pytest.approx((recorded, 0.2, kernel_ms))


def test_a_trigger_while_the_head_runs_is_sent_and_starts_when_the_head_is_done(two_nodes: TwoNodes) -> None:
    book, run, (a, _b), readers = two_nodes
    first = book.trigger(run, 0.0, None)
    second = book.trigger(run, 1.0, None)
    assert first is not None
    assert second is not None
    assert second.deferred
    assert book.trigger(run, 2.0, None) is None  # one deferred at most
    a.append(first.seq, 0, 3 * MS, 3 * MS)
    read(book, run, readers, 3.5)
    deferred = book.state("s").in_flight[second.seq]
    assert (deferred.index, deferred.triggered_ms) == (0, 3.0)  # in flight since the head was done


def test_the_measured_rate_counts_completed_runs_and_decays_to_zero(two_nodes: TwoNodes) -> None:
    book, run, (a, b), readers = two_nodes
    assert book.measured_hz("s", 20.0, 0.0) is None  # nothing completed yet
    for i in range(50):  # 50 runs, one every 20 ms, each 2 ms at a then 2 ms at b
        started = book.trigger(run, 20.0 * i, None)
        assert started is not None
        at = int(20.0 * i * MS)
        a.append(started.seq, at, at + 2 * MS, 2 * MS)
        b.append(started.seq, at + 2 * MS, at + 4 * MS, 2 * MS)
        read(book, run, readers, 20.0 * i + 5.0)
    assert book.measured_hz("s", 20.0, 1000.0) == pytest.approx(50.0, rel=0.05)
    for i in range(50, 150):  # for 2 s still triggered, but b hangs: every run is lost, none completes
        assert book.trigger(run, 20.0 * i, None) is not None
        book.lost({"s": run}, 20.0 * i + 10_000.0)
    assert book.measured_hz("s", 20.0, 3000.0) == 0.0


def test_lost_runs_are_given_up_after_20_latencies_and_a_second(two_nodes: TwoNodes) -> None:
    book, run, _, _ = two_nodes
    started = book.trigger(run, 0.0, None)
    assert started is not None
    assert book.lost({"s": run}, 999.0) == []
    assert book.lost({"s": run}, 1000.5) == [("s", started.seq, "a")]
    assert book.state("s").lost == 1


def test_a_messages_hop_into_an_input_node_counts_after_the_slot_too(two_nodes: TwoNodes) -> None:
    """b runs on its input (seq 0): the middleware's delivery is its hop, inside the slot or not; with two runs
    waiting at b its pairing is a guess, and no hop is measured."""
    book, run, (a, b), readers = two_nodes
    started = book.trigger(run, 0.0, None, until_ms=5.0)
    assert started is not None
    a.append(started.seq, 1 * MS, 4 * MS, 3 * MS)
    b.append(0, 9 * MS, 10 * MS, 1 * MS)  # delivered 5 ms after a's end, past the slot
    seen = read(book, run, readers, 12.0)
    assert [(h.edge, round(h.delay_ms, 6)) for h in seen.hops] == [(None, 1.0), (("a", "b"), 5.0)]
    first = book.trigger(run, 20.0, None, until_ms=25.0)
    assert first is not None
    a.append(first.seq, 20 * MS, 21 * MS, 1 * MS)
    read(book, run, readers, 21.5)
    second = book.trigger(run, 22.0, None, until_ms=25.0)  # behind the first: no hop of its own either way
    assert second is not None
    a.append(second.seq, 22 * MS, 23 * MS, 1 * MS)
    read(book, run, readers, 23.5)  # two runs wait at b
    b.append(0, 26 * MS, 27 * MS, 1 * MS)  # past the slot, and which scan it took is a guess
    seen = read(book, run, readers, 28.0)
    assert seen.hops == []
    assert [r.seq for r in seen.runs] == [first.seq]


def test_a_run_nothing_triggered_goes_with_the_run_its_data_came_from(two_nodes: TwoNodes) -> None:
    """Two runs wait at b; b's message carries the second head run's data (its origin is after the second
    trigger): it ends the second run, in time, and the first (whose message was dropped) waits on, to be given up
    as lost.  Paired oldest-first, b's run would end the first run, one period late."""
    book, run, (a, b), readers = two_nodes
    first = book.trigger(run, 0.0, None, until_ms=5.0)
    assert first is not None
    a.append(first.seq, 0, 1 * MS, 1 * MS)
    read(book, run, readers, 1.5)
    second = book.trigger(run, 20.0, None, until_ms=25.0)
    assert second is not None
    a.append(second.seq, 20 * MS, 21 * MS, 1 * MS)
    read(book, run, readers, 21.5)  # both wait at b
    b.append(0, 23 * MS, 24 * MS, 1 * MS, origin_ns=20_500_000)  # sensed at 20.5 ms: the second run's
    seen = read(book, run, readers, 24.5)
    assert [(r.seq, r.latency_ms) for r in seen.runs] == [(second.seq, 4.0)]  # 20 -> 24 ms, within 10
    assert seen.hops == []  # triggered behind the first run: no hop of its own
    assert list(book.state("s").in_flight) == [first.seq]
    assert book.state("s").late == 0


def test_a_run_is_counted_late_only_past_its_planned_wait_for_an_executors_thread(two_nodes: TwoNodes) -> None:
    """Latency 10 ms and a planned wait of 30 ms behind another subchain's node in the thread: a run that ends 35 ms
    after its trigger is on time, one that ends 45 ms after is late; both steal once past the 10 ms."""
    book, plain, (a, b), readers = two_nodes
    run = SubchainRun("s", ("a", "b"), (0,), True, 20.0, 10.0, 1, 1, wait_ms=30.0)
    assert run.late_after_ms == 40.0
    for trigger, end in ((100.0, 135.0), (200.0, 245.0)):
        started = book.trigger(run, trigger, None)
        assert started is not None
        assert not book.late("s", trigger + 9.0, run)
        assert book.late("s", trigger + 11.0, run)  # it steals from its planned latency on
        a.append(started.seq, int((end - 2.0) * MS), int((end - 1.0) * MS), MS)
        b.append(started.seq, int((end - 1.0) * MS), int(end * MS), MS)
        seen = read(book, run, readers, end + 0.5)
        assert [round(r.latency_ms, 6) for r in seen.runs] == [end - trigger]
        assert book.state("s").late == (0 if end - trigger < 40.0 else 1)
    book.trigger(plain, 300.0, None)  # without a wait: late past its latency
    a.append(3, 303 * MS, 309 * MS, MS)
    b.append(3, 309 * MS, 312 * MS, MS)
    read(book, plain, readers, 313.0)
    assert book.state("s").late == 2
