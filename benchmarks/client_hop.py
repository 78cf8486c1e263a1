"""A Python node's hop alone: one node's end to the next node's start, client to client (issue 31).

    python -m benchmarks.client_hop                                # this tree's client, 5 rounds
    python -m benchmarks.client_hop --tree /path/to/old --tree .   # two clients side by side
    python -m benchmarks.client_hop --tree A --tree B --evict-mb 8 # caches emptied between runs

Per tree, two node processes, A then B of one subchain, each a ``catanc.client.Node`` loaded from
the tree's ``catanc/client.py`` (the standalone client: it imports nothing else of catanc), all
pinned to one CPU at SCHED_FIFO :data:`~catanc.model.priorities.RUNNING_FIFO` as a raised subchain
runs (SCHED_OTHER without root).  This process plays the enforcer on another CPU: it welcomes
them, routes each A's runs to its B, triggers the trees' A in turn every few ms (A burns 0.3 ms
of CPU a run) and reads the rings.  The hop is B's start less A's end, as ``catanc run``
measures it, without the enforcer's own wake-ups on that CPU, so the client's path is what
moves it: the sender's work from its run's end until it yields or blocks, and the receiver's
from its wake-up until its run starts.  The trees take turns trigger by trigger, so the VM's
speed, which moves from minute to minute, moves them alike.  ``--evict-mb N``: a SCHED_OTHER
process on the nodes' CPU copies N MB over and over between their runs, so each hop starts with
caches that other work filled, as in an app (``catanc run``'s hops are cold: other processes
ran on the CPU since the node last did).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from catanc.model.priorities import RUNNING_FIFO
from catanc.runtime.protocol.endpoints import Endpoint, EnforcerSocket, open_endpoint
from catanc.runtime.protocol.messages import Hello, Route, Stop, decode, trigger_datagram

ROOT = Path(__file__).resolve().parent.parent
NODE_CPU, ENFORCER_CPU = 0, 1
BURN_MS = 0.3
TRIGGER_EVERY_S = 0.003

NODE = """
import importlib.util, os, sys, time
path, name, sock, cpu, level = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
spec = importlib.util.spec_from_file_location("client_under_test", path)
client = importlib.util.module_from_spec(spec)
spec.loader.exec_module(client)
os.sched_setaffinity(0, {cpu})
if level:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(level))
with client.Node(name, socket_path=sock) as node:
    for _ in node:
        end = time.thread_time() + BURN_MS / 1000.0
        while time.thread_time() < end:
            pass
        node.done()
""".replace("BURN_MS", repr(BURN_MS))


EVICTOR = """
import os, sys
os.sched_setaffinity(0, {int(sys.argv[1])})
buffer, zeros = bytearray(int(sys.argv[2]) << 20), bytes(int(sys.argv[2]) << 20)
while True:
    buffer[:] = zeros
"""


def measure(clients: list[Path], runs: int, evict_mb: int) -> list[dict[str, float]]:
    """One round: ``runs`` triggers of each client's A, the clients taking turns trigger by trigger,
    and each client's hops A -> B in microseconds (p50, p95) and how many were read."""
    level = RUNNING_FIFO if os.geteuid() == 0 else 0
    with tempfile.TemporaryDirectory(prefix="catanc-hop-") as folder:
        path = Path(folder) / "s.sock"
        enforcer = EnforcerSocket(path)
        pairs = [(f"A{i}", f"B{i}") for i in range(len(clients))]
        nodes = [
            subprocess.Popen(
                [sys.executable, "-c", NODE, str(client), name, str(path), str(NODE_CPU), str(level)],
                cwd=folder,
            )
            for client, pair in zip(clients, pairs, strict=True)
            for name in pair
        ]
        if evict_mb:  # SCHED_OTHER on the nodes' CPU: it runs between their runs, as other processes do
            nodes.append(subprocess.Popen([sys.executable, "-c", EVICTOR, str(NODE_CPU), str(evict_mb)], cwd=folder))
        endpoints: dict[str, Endpoint] = {}
        ends: list[dict[int, int]] = [{} for _ in clients]
        starts: list[dict[int, int]] = [{} for _ in clients]
        try:
            deadline = time.monotonic() + 10.0
            while len(endpoints) < 2 * len(clients):
                if time.monotonic() > deadline:
                    raise SystemExit("the nodes did not register within 10 s")
                for received in enforcer.receive(limit=8):
                    hello = decode(received.data)
                    if isinstance(hello, Hello) and received.sender is not None:
                        endpoints[hello.node] = open_endpoint(hello.node, hello.pid, hello.tid, received.sender)
                time.sleep(0.01)
            for a_name, b_name in pairs:
                a, b = endpoints[a_name], endpoints[b_name]
                assert isinstance(a.address, bytes)
                assert isinstance(b.address, bytes)
                a.send(Route(a_name, False, b_name, 1, b.address, None).encode())
                b.send(Route(b_name, False, None, 1, None, a.address).encode())
            time.sleep(0.2)

            def collect() -> None:
                for i, (a_name, b_name) in enumerate(pairs):
                    a_reader, b_reader = endpoints[a_name].reader, endpoints[b_name].reader
                    assert a_reader is not None
                    assert b_reader is not None
                    ends[i].update((entry.seq, entry.end_ns) for entry in a_reader.new())
                    starts[i].update((entry.seq, entry.start_ns) for entry in b_reader.new())

            for seq in range(1, runs + 1):
                for a_name, _ in pairs:
                    endpoints[a_name].send(trigger_datagram(a_name, seq, 1))
                    time.sleep(TRIGGER_EVERY_S)
                collect()
            time.sleep(0.05)
            collect()
            for endpoint in endpoints.values():
                endpoint.send(Stop().encode())
        finally:
            if evict_mb:
                nodes[-1].kill()
            for node in nodes:
                try:
                    node.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    node.kill()
                    node.wait()
            for endpoint in endpoints.values():
                endpoint.close()
            enforcer.close()
    results = []
    for client, tree_ends, tree_starts in zip(clients, ends, starts, strict=True):
        hops = sorted((tree_starts[seq] - tree_ends[seq]) / 1e3 for seq in tree_starts if seq in tree_ends)
        if not hops:
            raise SystemExit(f"{client}: no run reached B")
        results.append({"p50_us": statistics.median(hops), "p95_us": hops[int(0.95 * (len(hops) - 1))]})
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tree", action="append", type=Path, help="a catanc tree whose client to measure (repeat)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds, the trees alternating (default 5)")
    parser.add_argument("--runs", type=int, default=1500, help="runs of each tree's nodes a round (default 1500)")
    parser.add_argument(
        "--evict-mb", type=int, default=0, help="MB a process copies on the nodes' CPU between runs (0: none)"
    )
    options = parser.parse_args()
    if len(os.sched_getaffinity(0)) < 2:
        raise SystemExit("needs two CPUs: the nodes on one, this process (the enforcer's side) on another")
    os.sched_setaffinity(0, {ENFORCER_CPU})
    trees = options.tree or [ROOT]
    found: dict[Path, list[dict[str, float]]] = {tree: [] for tree in trees}
    clients = [tree.resolve() / "catanc" / "client.py" for tree in trees]
    for round_ in range(1, options.rounds + 1):
        for tree, result in zip(trees, measure(clients, options.runs, options.evict_mb), strict=True):
            found[tree].append(result)
            print(f"round {round_}, {tree}: hop p50 {result['p50_us']:.1f} us, p95 {result['p95_us']:.1f} us")
    for tree, results in found.items():
        p50s = sorted(r["p50_us"] for r in results)
        print(f"{tree}: hop p50 median {statistics.median(p50s):.1f} us (rounds {p50s[0]:.1f}-{p50s[-1]:.1f})")
    if len(trees) == 2:
        ratios = [new["p50_us"] / old["p50_us"] for old, new in zip(found[trees[0]], found[trees[1]], strict=True)]
        print(f"{trees[1]} / {trees[0]}, round by round: {', '.join(f'{r:.2f}' for r in ratios)}")


if __name__ == "__main__":
    main()
