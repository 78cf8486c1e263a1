"""The enforcer's log: sampled events are written in batches and read back one by one."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catanc.runtime.logs.writer import RunLog, read_log

Sample = tuple[str, str, tuple[float | int | None, ...]]
NAMES = st.sampled_from(["LM", "LP", "scan", "local", "GL"])
MS = st.one_of(st.none(), st.floats(min_value=0, max_value=1e4, allow_nan=False))
SAMPLE = st.one_of(
    st.tuples(st.just("compute"), NAMES, st.tuples(MS, MS, MS, st.integers(1, 8), MS)),
    st.tuples(st.just("run"), NAMES, st.tuples(st.integers(0, 10**6), st.floats(0, 1e4, allow_nan=False))),
)


def expected(event: str, t: float, key: str, values: tuple[float | int | None, ...]) -> dict[str, object]:
    """The single event a sample stands for, worked by hand from the documented rounding."""

    def rounded(value: float | int | None, digits: int) -> float | int | None:
        return None if value is None else round(value, digits)

    if event == "compute":
        ms, reported, kernel, threads, age = values
        return {"t": round(t, 6), "event": "compute", "node": key, "ms": rounded(ms, 4), "reported_ms": reported,
                "kernel_ms": rounded(kernel, 4), "threads": threads, "age_ms": rounded(age, 3)}  # fmt: skip
    seq, latency = values
    return {"t": round(t, 6), "event": "run", "subchain": key, "seq": seq, "latency_ms": rounded(latency, 3)}


@settings(max_examples=60, deadline=None)
@given(
    samples=st.lists(st.tuples(SAMPLE, st.floats(0, 1e5, allow_nan=False)), max_size=40),
    flush_every=st.integers(1, 50),
)
def test_every_sample_comes_back_once(
    tmp_path_factory: pytest.TempPathFactory, samples: list[tuple[Sample, float]], flush_every: int
) -> None:
    path = tmp_path_factory.mktemp("log") / "run.jsonl"
    with RunLog(path) as log:
        log.write("start", 0.0, {"cores": 1})
        for index, ((event, key, values), t) in enumerate(samples):
            log.sample(event, t, key, values)
            if (index + 1) % flush_every == 0:
                log.flush()
    events = read_log(path)
    assert events[0] == {"t": 0.0, "event": "start", "cores": 1}
    got = sorted(events[1:], key=lambda e: json.dumps(e, sort_keys=True))
    want = sorted((expected(e, t, k, v) for (e, k, v), t in samples), key=lambda e: json.dumps(e, sort_keys=True))
    assert got == want
    lines = path.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 1 + len(samples)  # batched: never more lines than samples


def test_a_batch_is_one_line_per_key_and_flush(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    with RunLog(path) as log:
        for i in range(100):
            log.sample("compute", i / 100, "LM" if i % 2 else "LP", (1.0, 1.0, None, 1, None))
    lines = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    assert [(line["event"], line["node"], len(line["at"])) for line in lines] == [
        ("compute_batch", "LP", 50),
        ("compute_batch", "LM", 50),
    ]


def test_samples_from_many_threads_are_all_written(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    per_thread = 2000
    with RunLog(path) as log:

        def produce(name: str) -> None:
            for seq in range(per_thread):
                log.sample("run", seq / 1000, name, (seq, 1.0))

        threads = [threading.Thread(target=produce, args=(f"s{i}",)) for i in range(4)]
        for thread in threads:
            thread.start()
        while any(thread.is_alive() for thread in threads):
            log.flush()  # flushing while samples arrive loses none and repeats none
        for thread in threads:
            thread.join()
    runs = read_log(path)
    assert sorted((e["subchain"], e["seq"]) for e in runs) == sorted(
        (f"s{i}", seq) for i in range(4) for seq in range(per_thread)
    )


def test_a_batch_without_a_later_column_reads_it_as_unknown(tmp_path: Path) -> None:
    """A log of a catanc that wrote no ``threads`` or ``age_ms`` column: its samples come back, those None."""
    path = tmp_path / "run.jsonl"
    old = {"t": 2.0, "event": "compute_batch", "node": "n", "at": [1.0, 2.0], "ms": [1.5, 2.5],
           "reported_ms": [1.5, None], "kernel_ms": [None, None]}  # fmt: skip
    path.write_text(json.dumps(old) + "\n", encoding="utf-8")
    assert read_log(path) == [
        {
            "t": 1.0,
            "event": "compute",
            "node": "n",
            "ms": 1.5,
            "reported_ms": 1.5,
            "kernel_ms": None,
            "threads": None,
            "age_ms": None,
        },
        {
            "t": 2.0,
            "event": "compute",
            "node": "n",
            "ms": 2.5,
            "reported_ms": None,
            "kernel_ms": None,
            "threads": None,
            "age_ms": None,
        },
    ]


def test_a_malformed_batch_is_kept_as_it_is(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    bad = [
        {"t": 1.0, "event": "run_batch", "subchain": "a", "at": [1.0, 2.0], "seq": [1], "latency_ms": [1.0, 2.0]},
        {"t": 1.0, "event": "compute_batch", "node": "n", "at": "soon"},
        {"t": 1.0, "event": "other_batch", "at": [1.0]},
    ]
    path.write_text("".join(json.dumps(line) + "\n" for line in bad), encoding="utf-8")
    assert read_log(path) == bad
