"""Which nodes share one executor thread: the spec's ``executors:`` and the processes that imply one.

A process (:func:`~catanc.spec.deploy_checks.process_keys`: what ``deploy.<node>.process`` names,
else the node's ROS node, else the node alone) runs its scheduled nodes in **one thread**, planned
as one executor (docs/explanation/executor-planning.md), when

- it is a Python process: the interpreter lock runs one callback at a time, whatever executor spins
  them (measured on the rclpy nav2d: a trigger waited p50 5.1 ms behind another thread of its
  process).  Python is read from the process's ``command``: its program (after ``env`` and its
  ``NAME=value`` settings, if any) is ``python``, ``python3``, ``python3.12``, ``pypy3``, ... (any
  folder), or a ``.py`` file.  A command that does not say it (``ros2 run pkg exe``) is not taken
  for Python;
- or none of its nodes names a callback group: a ROS process spins one single-threaded executor
  unless it runs a callback-isolated executor, one thread per callback group.

The nodes of any other process (a non-Python one whose nodes name callback groups) may run at once
and are planned as the spec's ``executors:`` say.  :func:`executor_groups` joins the two sources:
an ``executors:`` entry inside a one-thread process is that process's executor (named by the
entry when it lists all of the process's scheduled nodes).  :func:`catanc.model.build.build_problem`
rejects the specs where the two disagree (an entry joining two processes, or two entries splitting
one thread).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import PurePosixPath

from catanc.errors import FieldPath
from catanc.spec.deploy_checks import process_members, split_command
from catanc.spec.language import Spec

PYTHON_PROGRAM = re.compile(r"(python|pypy)[0-9.]*|.+\.py")
"""A program name (no folder) that runs Python."""

ENV_SETTING = re.compile(r"[A-Za-z_][A-Za-z0-9_]*=.*")
ENV_OPTIONS_WITH_ARGUMENT = frozenset({"-u", "--unset", "-C", "--chdir"})


def python_program(command: str | None) -> str | None:
    """The Python program ``command`` runs (``python3``, ``nav_mapper.py``), or None if it does not say so."""
    if command is None:
        return None
    try:
        argv = split_command(command)
    except ValueError:
        return None  # reported by the deploy checks
    program = PurePosixPath(argv[0]).name
    if program == "env":
        program = _env_program(argv[1:])
    return program if PYTHON_PROGRAM.fullmatch(program) else None


def _env_program(args: Sequence[str]) -> str:
    """The program ``env ARGS`` runs: past its options (``-u NAME`` and ``-C DIR`` take one) and settings."""
    rest = list(args)
    while rest and (rest[0].startswith("-") or ENV_SETTING.fullmatch(rest[0])):
        option = rest.pop(0)
        if option in ENV_OPTIONS_WITH_ARGUMENT and rest:
            rest.pop(0)
    return PurePosixPath(rest[0]).name if rest else ""


@dataclass(frozen=True)
class ProcessThreads:
    """One process of the deploy section, and whether its scheduled nodes share one thread."""

    key: str  # the process's name: what deploy.<node>.process names, else its ROS node, else its node
    nodes: tuple[str, ...]  # its DAG nodes, in spec order
    scheduled: tuple[str, ...]  # those the scheduler triggers
    python: str | None  # the Python program its command runs, if it does
    callback_groups: tuple[str, ...]  # its nodes that name a callback group
    origin: FieldPath  # the field that puts its first scheduled node in it (or its first node)

    @property
    def one_thread(self) -> bool:
        """Whether its scheduled nodes (two or more) run in one thread: one executor."""
        return len(self.scheduled) >= 2 and (self.python is not None or not self.callback_groups)

    @property
    def reason(self) -> str:
        """Why its nodes do or do not share one thread, in a clause."""
        if len(self.scheduled) < 2:
            return "one scheduled node" if self.scheduled else "no scheduled node"
        if self.python is not None:
            whatever = ", whatever its callback groups" if self.callback_groups else ""
            return f"a Python process ({self.python}): the interpreter lock runs one callback at a time{whatever}"
        if not self.callback_groups:
            return "no node names a callback group, so a single-threaded executor runs them"
        return (
            f"{', '.join(self.callback_groups)} name{'s' if len(self.callback_groups) == 1 else ''} callback groups: "
            "a callback-isolated executor runs each group in a thread of its own"
        )


def spec_processes(spec: Spec) -> tuple[ProcessThreads, ...]:
    """The processes of the deploy section (its nodes the spec knows), in spec order of their first node."""
    found = []
    for key, nodes in process_members(spec).items():
        scheduled = tuple(node for node in nodes if spec.nodes[node].scheduled)
        command = next((spec.deploy[node].command for node in nodes if spec.deploy[node].command is not None), None)
        first = spec.deploy[(scheduled or nodes)[0]]
        field = "process" if first.process is not None else "ros_node" if first.ros_node is not None else None
        origin: FieldPath = ("deploy", (scheduled or nodes)[0], *([field] if field else []))
        found.append(
            ProcessThreads(
                key=key,
                nodes=tuple(nodes),
                scheduled=scheduled,
                python=python_program(command),
                callback_groups=tuple(node for node in nodes if spec.deploy[node].callback_group is not None),
                origin=origin,
            )
        )
    return tuple(found)


@dataclass(frozen=True)
class ThreadGroup:
    """Scheduled nodes that share one executor thread, and where the spec says so."""

    name: str  # the executors: entry's name, else the process's
    nodes: tuple[str, ...]
    origin: FieldPath  # executors.<name>, or the field that puts the process together
    process: ProcessThreads | None = None  # the one-thread process it is, if it is one


def executor_groups(spec: Spec, explicit: Mapping[str, Sequence[str]] | None = None) -> tuple[ThreadGroup, ...]:
    """The spec's ``executors:`` (or ``explicit``, the entries already checked) joined with its one-thread processes.

    An entry whose nodes all run in one one-thread process is that process's group: it names it when it
    lists all of the process's scheduled nodes, else it is left out (the process's group holds it).  The
    rest keep their place; the processes' groups no entry names come after them, in spec order.  Where
    an entry reaches outside the process of one of its nodes the spec is wrong and the groups overlap:
    :func:`catanc.model.build.build_problem` reports it.
    """
    entries = spec.executors if explicit is None else explicit
    processes = [process for process in spec_processes(spec) if process.one_thread]
    home = {node: process for process in processes for node in process.scheduled}
    groups: list[ThreadGroup] = []
    named: set[str] = set()
    for name, nodes in entries.items():
        owners = {home[node].key if node in home else None for node in nodes}
        if len(owners) == 1 and None not in owners:
            process = home[nodes[0]]
            if set(nodes) == set(process.scheduled) and process.key not in named:
                named.add(process.key)
                groups.append(ThreadGroup(name, tuple(nodes), ("executors", name), process))
            continue
        groups.append(ThreadGroup(name, tuple(nodes), ("executors", name)))
    groups += [
        ThreadGroup(process.key, process.scheduled, process.origin, process)
        for process in processes
        if process.key not in named
    ]
    return tuple(groups)


def executor_nodes(spec: Spec) -> dict[str, tuple[str, ...]]:
    """Each executor's nodes by its name (:func:`executor_groups`): what the simulator and the workers serialise."""
    return {group.name: group.nodes for group in executor_groups(spec)}
