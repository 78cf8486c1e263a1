"""A ring's `written` counter as another process sees it: it never goes back while a node writes.

The Python writers stored it with ``struct.pack_into``, which zeroes its field and then writes it a
byte at a time: a reader between the two saw the counter at 0 (once every ~2,000 writes here),
took it for a node that rewound, and read old runs again (a flaky client test, 2026-11-28).  The
watcher is a C++ program spinning on the word, as the enforcer reads it.
"""

from __future__ import annotations

import itertools
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from catanc.client import Node
from catanc.runtime.protocol import ring
from tests.support.client_nodes import compiler
from tests.support.fake_enforcer import FakeEnforcer

CHANGES = 20_000  # changes the watcher must see; the old writers went back ~10 times in this many
BATCH = 1_000  # writes between looks at whether the watcher is done
DEADLINE_S = 60.0

WATCHER = r"""
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sys/mman.h>
// argv: a ring's descriptor, the changes to watch for. Prints how often `written` went back.
int main(int argc, char **argv) {
    int fd = std::atoi(argv[1]);
    unsigned long long need = std::strtoull(argv[2], nullptr, 10);
    void *map = mmap(nullptr, 64, PROT_READ, MAP_SHARED, fd, 0);
    if (map == MAP_FAILED) { std::perror("mmap"); return 2; }
    const volatile std::uint64_t *written = static_cast<const volatile std::uint64_t *>(map) + 2;
    unsigned long long last = *written, backs = 0, changes = 0;
    std::printf("ready\n");
    std::fflush(stdout);
    while (changes < need) {
        unsigned long long now = *written;
        if (now < last) backs++;
        if (now != last) changes++;
        last = now;
    }
    std::printf("%llu %llu\n", backs, changes);
    return 0;
}
"""


@pytest.fixture(scope="module")
def watcher(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("watcher")
    (folder / "watcher.cpp").write_text(WATCHER)
    binary = folder / "watcher"
    subprocess.run([compiler(), "-O2", "-o", str(binary), str(folder / "watcher.cpp")], check=True, timeout=120)
    return binary


def watch(watcher: Path, fd: int, write: Callable[[int], None]) -> tuple[int, int]:
    """Call ``write(BATCH)`` until the watcher, spinning on ring ``fd``'s counter, has seen CHANGES
    changes: (times it went back, changes seen).  Writing until it has seen them, not a fixed count,
    keeps the test meaningful when a loaded machine leaves the watcher off the CPU (CI, 2026-11-28)."""
    process = subprocess.Popen([str(watcher), str(fd), str(CHANGES)], pass_fds=[fd], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert process.stdout.readline() == "ready\n"
    deadline = time.monotonic() + DEADLINE_S
    try:
        while process.poll() is None and time.monotonic() < deadline:
            write(BATCH)
        out, _ = process.communicate(timeout=5)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    backs, changes = (int(word) for word in out.split())
    return backs, changes


def test_the_ring_writers_counter_never_goes_back(watcher: Path) -> None:
    fd = ring.create(slots=16)
    writer = ring.RingWriter(fd)
    try:
        seqs = itertools.count()

        def write(count: int) -> None:
            for _ in range(count):
                writer.append(next(seqs), 0, 0)

        backs, changes = watch(watcher, fd, write)
    finally:
        writer.close()
    assert changes == CHANGES  # it watched while the writes went on
    assert backs == 0


def test_the_clients_counter_never_goes_back(watcher: Path, tmp_path: Path) -> None:
    """The Python client's store, as its runs make it (the records themselves: tens of thousands of runs
    through the socket would take minutes)."""
    enforcer = FakeEnforcer(tmp_path / "catanc.sock")
    registered = threading.Event()
    go = threading.Event()
    stop = threading.Event()
    failures: list[BaseException] = []

    def client() -> None:
        try:
            with Node("LM", socket_path=enforcer.path) as node:
                trigger = next(iter(node))
                node.done()
                registered.set()
                assert go.wait(30)
                while not stop.is_set():
                    node._record(trigger, 0, 0)  # the store under test
        except BaseException as exc:  # the test re-raises it
            failures.append(exc)
            registered.set()

    thread = threading.Thread(target=client)
    try:
        thread.start()
        enforcer.welcome({"LM"})
        enforcer.trigger("LM", 1)
        assert [entry.seq for entry in enforcer.runs("LM")] == [1]
        assert registered.wait(30)
        fd = enforcer.endpoints["LM"].ring_fd
        assert fd is not None

        def let_the_client_write(_count: int) -> None:
            go.set()
            time.sleep(0.01)

        backs, changes = watch(watcher, fd, let_the_client_write)
    finally:
        stop.set()
        go.set()
        thread.join(30)
        enforcer.close()
    assert not failures, failures
    assert changes == CHANGES
    assert backs == 0
