"""Nodes that share one executor thread run one after the other (docs/explanation/model.md section 6).

A single-threaded executor (one ROS process spinning one thread) runs one
callback at a time: a node whose turn comes while another node of its
executor runs waits, in arrival order, as callbacks wait in the executor's
queue.  Both the reference engine's policies and the compiled kernel keep
this rule in the same place: a run is *started* (reads its inputs, draws its
compute time, becomes a job) only once its executor is free, and a node's
completion frees its executor before anything else it triggers.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from catanc.spec.executors import executor_nodes
from catanc.spec.language import Spec


class ExecutorGate:
    """Which node each executor runs now, and the starts waiting for it."""

    def __init__(self, spec: Spec) -> None:
        self.executor_of = {node: name for name, nodes in executor_nodes(spec).items() for node in nodes}
        self._running: dict[str, str] = {}
        self._waiting: dict[str, deque[tuple[str, Callable[[], None]]]] = {}

    def enter(self, node: str, start: Callable[[], None]) -> None:
        """Start ``node``'s run now if its executor is free (or it has none), else when its turn comes."""
        name = self.executor_of.get(node)
        if name is None:
            start()
            return
        if name in self._running:
            self._waiting.setdefault(name, deque()).append((node, start))
            return
        self._running[name] = node
        start()

    def leave(self, node: str) -> None:
        """``node``'s run finished: its executor starts the next waiting run, if any."""
        name = self.executor_of.get(node)
        if name is None:
            return
        queue = self._waiting.get(name)
        if queue:
            following, start = queue.popleft()
            self._running[name] = following
            start()
        else:
            del self._running[name]
