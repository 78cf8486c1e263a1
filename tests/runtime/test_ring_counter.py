"""A ring's `written` counter as another process sees it: it never goes back while a node writes.

The Python writers stored it with ``struct.pack_into``, which zeroes its field and then writes it a
byte at a time: a reader between the two saw the counter at 0 (once every ~2,000 writes here),
took it for a node that rewound, and read old runs again (a flaky client test, 2026-11-28).  The
watcher is a C++ program spinning on the word, as the enforcer reads it.
"""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from catanc.client import Node
from catanc.runtime import ring
from tests.support.client_nodes import compiler
from tests.support.fake_enforcer import FakeEnforcer

WRITES = 200_000  # the old writers went back ~100 times in this many

WATCHER = r"""
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sys/mman.h>
// argv: a ring's descriptor, the value to watch until. Prints how often `written` went back.
int main(int argc, char **argv) {
    int fd = std::atoi(argv[1]);
    unsigned long long until = std::strtoull(argv[2], nullptr, 10);
    void *map = mmap(nullptr, 64, PROT_READ, MAP_SHARED, fd, 0);
    if (map == MAP_FAILED) { std::perror("mmap"); return 2; }
    const volatile std::uint64_t *written = static_cast<const volatile std::uint64_t *>(map) + 2;
    unsigned long long last = *written, backs = 0, changes = 0;
    std::printf("ready\n");
    std::fflush(stdout);
    while (last < until) {
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


def watch(watcher: Path, fd: int, until: int, write: Callable[[], None]) -> tuple[int, int]:
    """Run ``write`` while the watcher spins on ring ``fd``'s counter: (times it went back, changes seen)."""
    process = subprocess.Popen([str(watcher), str(fd), str(until)], pass_fds=[fd], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert process.stdout.readline() == "ready\n"
    write()
    out, _ = process.communicate(timeout=60)
    backs, changes = (int(word) for word in out.split())
    return backs, changes


def test_the_ring_writers_counter_never_goes_back(watcher: Path) -> None:
    fd = ring.create(slots=16)
    writer = ring.RingWriter(fd)
    try:

        def write() -> None:
            for seq in range(WRITES):
                writer.append(seq, 0, 0)

        backs, changes = watch(watcher, fd, WRITES, write)
    finally:
        writer.close()
    assert changes >= 100  # it watched while the writes went on
    assert backs == 0


def test_the_clients_counter_never_goes_back(watcher: Path, tmp_path: Path) -> None:
    """The Python client's store, as its runs make it (the records themselves: 200,000 runs through the
    socket would take minutes)."""
    enforcer = FakeEnforcer(tmp_path / "catanc.sock")
    registered = threading.Event()
    go = threading.Event()
    failures: list[BaseException] = []

    def client() -> None:
        try:
            with Node("LM", socket_path=enforcer.path) as node:
                trigger = next(iter(node))
                node.done()
                registered.set()
                assert go.wait(30)
                for _ in range(WRITES):
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
        backs, changes = watch(watcher, fd, 1 + WRITES, go.set)
        thread.join(30)
    finally:
        go.set()
        thread.join(30)
        enforcer.close()
    assert not failures, failures
    assert changes >= 100
    assert backs == 0
