"""What gets started, pinned and configured: the spec's ``deploy`` section applied to a plan.

A *process* is what ``deploy.<node>.process`` names (several ROS nodes,
as in a component container), else one ROS node (every DAG node naming the
same ``ros_node`` runs in it, as nav2d's Mapper hosts GL and GM) or, for a
DAG node without either, that node alone.  :mod:`catanc.spec.deploy_checks` checks the
section when the spec loads; :func:`processes` turns a plan into the
processes the launchers start, each with the CPUs and the SCHED_FIFO
priority docs/explanation/model.md section 6 gives its nodes, and the ROS parameters
``params.yaml`` sets.

Launch priorities are the enforcer's resting levels: a shared subchain's
nodes sit at FIFO 1 (``catanc run`` raises the running slice to 2), a
dedicated subchain's at 2, unscheduled nodes at 3.  A process hosting
several nodes gets the union of their CPUs and the highest of their levels:
a process has one affinity and one policy; ``catanc run`` pins per thread.

Without the enforcer (``launch.sh --static``) no one switches a shared core's
slices, and equal SCHED_FIFO levels do not time-slice: a process with a node
of a shared subchain runs under SCHED_OTHER at its planned rate instead
(:attr:`Process.static_priority`), the others at their level.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from catanc.artifacts.runtime_table import PARAMS_FILE, RATE_DIGITS, ProcessEntry, ms
from catanc.errors import Diagnostic, SpecError
from catanc.model.priorities import static_policy
from catanc.spec.deploy_checks import PERIOD_NS, RESERVED_PREFIX, process_members, qualified, split_command
from catanc.spec.language import Spec

if TYPE_CHECKING:
    from catanc.planning.types import Plan

ParamValue = bool | int | float | str | list[int] | list[float] | list[str]
ParamTree = dict[str, Any]  # nested: {"local_map": {"update_frequency": 135.0}}


@dataclass(frozen=True)
class RosNode:
    """One ROS node of a process, and its parameters in params.yaml."""

    name: str  # fully qualified, with a leading ``/``
    nodes: tuple[str, ...]  # DAG nodes it hosts, in spec order
    params: ParamTree
    any_namespace: bool = False  # params.yaml keys it /**/<name>: under any namespace the launch adds

    @property
    def params_key(self) -> str:
        """Its key in params.yaml: ``/ns/name``, or ``/**/ns/name`` (rcl's wildcard for any namespace before it)."""
        return "/**" + self.name if self.any_namespace else self.name

    @property
    def namespace(self) -> str:
        """``/ns`` of ``/ns/name`` (``/`` for a top-level node)."""
        return self.name.rsplit("/", 1)[0] or "/"

    @property
    def base_name(self) -> str:
        return self.name.rsplit("/", 1)[1]


@dataclass(frozen=True)
class Process:
    """One process the launchers start (when it has a command or a ROS executable)."""

    key: str  # the ``process`` the spec names, else its ROS node (``/Mapper``), else the DAG node's name
    ros_nodes: tuple[RosNode, ...]  # in spec order of their first DAG node
    nodes: tuple[str, ...]  # DAG nodes it hosts, in spec order
    argv: tuple[str, ...]  # the command, split as a shell would (empty: not started by launch.sh)
    package: str | None
    executable: str | None
    cpus: tuple[int, ...]
    priority: int  # SCHED_FIFO priority at launch
    shared: bool = False  # hosts a node of a shared core's subchain

    @property
    def ros_node(self) -> str | None:
        """Its one ROS node's name; None without a ROS node or with several (each keeps its code's name)."""
        return self.ros_nodes[0].name if len(self.ros_nodes) == 1 else None

    @property
    def static_priority(self) -> int:
        """Its SCHED_FIFO priority without the enforcer; 0: SCHED_OTHER (it has a node on a shared core).

        One thread of a shared core at SCHED_FIFO would keep the core's other subchains off it for as
        long as it runs; under SCHED_OTHER the fair scheduler shares the core while each node runs at
        the rate params.yaml plans.  A process has one policy, so one shared node puts all of it there.
        """
        return 0 if self.shared else self.priority

    def table_entry(self) -> ProcessEntry:
        """The process as the runtime table lists it (its ROS parameters are params.yaml's)."""
        entry: ProcessEntry = {
            "key": self.key,
            "ros_node": self.ros_node,
            "nodes": list(self.nodes),
            "argv": list(self.argv),
            "params_file": PARAMS_FILE if self.ros_nodes else None,
            "package": self.package,
            "executable": self.executable,
            "cpus": list(self.cpus),
            "priority": self.priority,
        }
        if len(self.ros_nodes) > 1:
            entry["ros_nodes"] = {ros.name: list(ros.nodes) for ros in self.ros_nodes}
        return entry


# --------------------------------------------------------------------------- applying a plan


def machine_cpus(plan: Plan, cpus: Sequence[int] | None) -> tuple[int, ...]:
    """The CPU each plan core runs on: ``cpus`` (``compile --cpus``, ascending), else CPU ``i`` for core ``i``."""
    return tuple(cpus[: plan.cores]) if cpus is not None else tuple(range(plan.cores))


def processes(spec: Spec, plan: Plan, cpus: Sequence[int] | None = None) -> tuple[Process, ...]:
    """The plan's processes, sorted by key; the spec must have passed :func:`deploy_problems`.

    ``cpus``: the CPUs plan cores run on (core ``i`` on ``cpus[i]``); default CPU ``i``.
    """
    on = machine_cpus(plan, cpus)
    grouped = process_members(spec)
    membership = {node: sub.name for sub in plan.subchains.values() for node in sub.nodes}
    found = []
    for key in sorted(grouped):
        nodes = tuple(grouped[key])
        entries = [spec.deploy[n] for n in nodes]
        cores, priority = plan.process_placement(nodes)
        shared = any(node in membership and plan.subchains[membership[node]].shared for node in nodes)
        command = _first(entry.command for entry in entries)
        process_cpus = tuple(sorted(on[core] for core in cores))
        by_ros: dict[str, list[str]] = {}
        for node in nodes:
            ros_node = spec.deploy[node].ros_node
            if ros_node is not None:
                by_ros.setdefault(qualified(ros_node), []).append(node)
        ros_nodes = tuple(
            RosNode(
                name=ros_name,
                nodes=tuple(hosted),
                params=_params(spec, plan, tuple(hosted), membership, on, cpus=process_cpus, priority=priority),
                any_namespace=any(spec.deploy[node].any_namespace for node in hosted),
            )
            for ros_name, hosted in by_ros.items()
        )
        found.append(
            Process(
                key=key,
                ros_nodes=ros_nodes,
                nodes=nodes,
                argv=tuple(split_command(command)) if command is not None else (),
                package=_first(entry.package for entry in entries),
                executable=_first(entry.executable for entry in entries),
                cpus=process_cpus,
                priority=priority,
                shared=shared,
            )
        )
    return tuple(found)


def _first(values: Iterable[str | None]) -> str | None:
    return next((value for value in values if value is not None), None)


def node_period_ms(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> float | None:
    """The period the plan gives ``node``: its subchain's, or its own clock's; None for a rate-less sink."""
    if node in membership:
        return ms(plan.subchains[membership[node]].period_ms)
    rate = spec.nodes[node].rate_hz
    return ms(1000.0 / rate) if rate is not None else None


def rate_period_ms(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> float | None:
    """The period ``node``'s rate parameter says: the offered rate the plan picked where its driver offers
    rates (one of them, even where none fits and its subchain runs slower: the driver takes no other),
    else :func:`node_period_ms`."""
    picked = next((choice.picked_hz for choice in plan.offered if choice.node == node), None)
    return ms(1000.0 / picked) if picked is not None else node_period_ms(spec, plan, node, membership)


def rate_value(period_ms: float, unit: str, kind: str = "float") -> float:
    """A node's rate parameter: in hertz, or its period in seconds or milliseconds.

    ``kind`` ``int``: a whole number, rounded towards the slower rate (a rate down, a period up) from
    the value as written with ``float`` (so 45.0000001 Hz, float noise, is 45), so the node never runs
    faster than planned and never takes more of its core than the plan gives it.  Rounding may at most
    halve the rate: a rate below 1 Hz, or a period below half a unit, is a :class:`ValueError`.
    """
    if unit == "hz":
        value = round(1000.0 / period_ms, RATE_DIGITS)
    elif unit == "s":
        value = round(period_ms / 1000.0, RATE_DIGITS + 3)
    else:
        value = ms(period_ms)
    if kind != "int":
        return value
    whole = math.floor(value) if unit == "hz" else math.ceil(value)
    if unit == "hz" and whole < 1:
        raise ValueError(f"{value:g} hz rounds down to 0")
    if unit != "hz" and whole > 2 * value:
        raise ValueError(f"a period of {value:g} {unit} rounds up to {whole}, less than half the rate")
    return whole


def _params(
    spec: Spec,
    plan: Plan,
    nodes: tuple[str, ...],
    membership: dict[str, str],
    on: tuple[int, ...],
    *,
    cpus: tuple[int, ...],
    priority: int,
) -> ParamTree:
    """The ROS parameters of one ROS node of a process: each node's rate parameter, then ``catan.*``.

    ``catan.cpus`` and ``catan.priority`` are the process's (what the launcher
    applied).  ``catan.subchain`` and ``catan.period_ms`` describe its nodes
    when they run as one subchain (or one clock); a process hosting nodes of
    several puts them per node, as ``catan.nodes.<node>.subchain`` and so on.
    ``catan.node`` names the DAG node of a ROS node hosting one: the ROS client's
    default name for its runs (docs/guide/ros2.md).
    """
    flat: dict[str, ParamValue] = {}
    for node in nodes:
        entry = spec.deploy[node]
        period = rate_period_ms(spec, plan, node, membership)
        if entry.rate_param is not None and period is not None:
            flat[entry.rate_param] = _rate_parameter(spec, node, period)
    groups = {membership.get(node, node) for node in nodes}
    catan: dict[str, ParamValue] = {"cpus": list(cpus), "priority": priority}
    if len(nodes) == 1:
        catan["node"] = nodes[0]
    if len(groups) == 1:
        catan.update(_node_params(spec, plan, nodes[0], membership, on))
    else:
        for node in nodes:
            for field, value in _node_params(spec, plan, node, membership, on).items():
                catan[f"nodes.{node}.{field}"] = value
    flat.update({f"{RESERVED_PREFIX}.{field}": value for field, value in catan.items()})
    return nest(flat)


def _rate_parameter(spec: Spec, node: str, period_ms: float) -> float:
    """``node``'s rate_param value; a :class:`SpecError` at its ``rate_type`` if no integer can say it."""
    entry = spec.deploy[node]
    try:
        return rate_value(period_ms, entry.rate_unit, entry.rate_type)
    except ValueError as exc:
        path = ("deploy", node, "rate_type")
        where = spec.source.locate(path) if spec.source is not None else None
        message = (
            f"the plan runs {node} at {1000.0 / period_ms:.6g} Hz, and as an integer {exc}: give another "
            "rate_unit (hz, s, ms), or rate_type float"
        )
        raise SpecError([Diagnostic(where, ".".join(path), message)]) from None


def _placement(plan: Plan, node: str, on: tuple[int, ...]) -> tuple[tuple[int, ...], int]:
    """A node's CPUs (``on[core]`` of its plan cores) and resting SCHED_FIFO priority (:meth:`Plan.placement`)."""
    cores, level = plan.placement(node)
    return tuple(sorted(on[core] for core in cores)), level


def _node_params(
    spec: Spec, plan: Plan, node: str, membership: dict[str, str], on: tuple[int, ...]
) -> dict[str, ParamValue]:
    found: dict[str, ParamValue] = {}
    if node in membership:
        found["subchain"] = membership[node]
    cpus, priority = _placement(plan, node, on)
    found["cpus"] = list(cpus)
    found["priority"] = priority
    period = node_period_ms(spec, plan, node, membership)
    if period is not None:
        found["period_ms"] = period
    return found


def nest(flat: dict[str, ParamValue]) -> ParamTree:
    """``{"a.b": 1, "a.c": 2}`` -> ``{"a": {"b": 1, "c": 2}}``, keys sorted.

    ValueError if a name is both a value and a group (:func:`deploy_problems` rules it out).
    """
    tree: ParamTree = {}
    for name in sorted(flat):
        *parents, leaf = name.split(".")
        level = tree
        for part in parents:
            child = level.setdefault(part, {})
            if not isinstance(child, dict):
                raise ValueError(f"parameter {name!r} sits under {part!r}, which is itself a parameter")
            level = child
        if leaf in level:
            raise ValueError(f"parameter {name!r} is also a group of parameters")
        level[leaf] = flat[name]
    return tree


# --------------------------------------------------------------------------- callback groups (cie_thread_configurator)


@dataclass(frozen=True)
class CallbackGroup:
    """One thread of a callback-isolated executor, as the plan places it without the enforcer."""

    id: str  # with the timer period filled in
    nodes: tuple[str, ...]  # DAG nodes whose callbacks it runs, in spec order
    cpus: tuple[int, ...]
    policy: str  # SCHED_FIFO or SCHED_OTHER (catanc.model.priorities.static_policy)
    priority: int  # SCHED_FIFO priority; 0 under SCHED_OTHER


def callback_groups(spec: Spec, plan: Plan, cpus: Sequence[int] | None = None) -> tuple[CallbackGroup, ...]:
    """The callback groups the spec names, sorted by ID; the spec must have passed :func:`deploy_problems`.

    ``cpus``: the CPUs plan cores run on, as for :func:`processes`.

    Nodes sharing one ID share one thread: it gets the union of their CPUs and the strongest of
    their policies (a node on its own clock over a dedicated subchain over a shared core).
    """
    on = machine_cpus(plan, cpus)
    membership = {node: sub.name for sub in plan.subchains.values() for node in sub.nodes}
    grouped: dict[str, list[str]] = {}
    for name in spec.nodes:
        entry = spec.deploy.get(name)
        if entry is None or entry.callback_group is None:
            continue
        group = entry.callback_group
        if PERIOD_NS in group:
            period_ns = timer_period_ns(spec, plan, name, membership)
            assert period_ns is not None  # deploy_problems: rate_param or a clock of its own
            group = group.replace(PERIOD_NS, str(period_ns))
        grouped.setdefault(group, []).append(name)
    found = []
    for group_id in sorted(grouped):
        nodes = tuple(grouped[group_id])
        used: set[int] = set()
        policies = []
        for node in nodes:
            node_cpus, policy, priority = _static_placement(plan, node, membership, on)
            used.update(node_cpus)
            policies.append((policy, priority))
        policy, priority = max(policies, key=lambda pair: (pair[0] == "SCHED_FIFO", pair[1]))
        found.append(CallbackGroup(group_id, nodes, tuple(sorted(used)), policy, priority))
    return tuple(found)


@dataclass(frozen=True)
class NonRosThread:
    """A node thread outside any ROS callback, as cie_thread_configurator's ``non_ros_threads`` names it."""

    id: str  # the DAG node's name: the name its catanc client registers, and spawn_non_ros2_thread's
    cpus: tuple[int, ...]
    policy: str  # SCHED_FIFO or SCHED_OTHER (catanc.model.priorities.static_policy)
    priority: int  # SCHED_FIFO priority; 0 under SCHED_OTHER


def non_ros_threads(spec: Spec, plan: Plan, cpus: Sequence[int] | None = None) -> tuple[NonRosThread, ...]:
    """The threads catanc's clients register outside ROS callbacks, sorted by name: every DAG node that is no
    ROS node (no ``deploy.<node>.ros_node``) and runs when triggered or on a clock of its own (an unscheduled
    node without ``rate_hz`` only passes data on).  Placed as :func:`callback_groups` places a group."""
    on = machine_cpus(plan, cpus)
    membership = {node: sub.name for sub in plan.subchains.values() for node in sub.nodes}
    found = []
    for name in sorted(spec.nodes):
        entry = spec.deploy.get(name)
        node = spec.nodes[name]
        if (entry is not None and entry.ros_node is not None) or (not node.scheduled and node.rate_hz is None):
            continue
        found.append(NonRosThread(name, *_static_placement(plan, name, membership, on)))
    return tuple(found)


def _static_placement(
    plan: Plan, node: str, membership: dict[str, str], on: tuple[int, ...]
) -> tuple[tuple[int, ...], str, int]:
    """A node thread's CPUs, policy and priority without the enforcer (:func:`static_policy`)."""
    node_cpus, _ = _placement(plan, node, on)
    shared = plan.subchains[membership[node]].shared if node in membership else None
    policy, priority = static_policy(shared)
    return node_cpus, policy, priority


def timer_period_ns(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> int | None:
    """The period, in whole nanoseconds, of the timer a node makes from its rate parameter (or its own rate_hz).

    As rclcpp code does it in double precision: ``1.0 / rate`` seconds for a rate in hertz, the
    period as given in seconds or milliseconds, truncated to nanoseconds
    (``std::chrono::duration_cast``, ``rclcpp::Duration::from_seconds``).
    """
    entry = spec.deploy[node]
    period = rate_period_ms(spec, plan, node, membership)
    if entry.rate_param is not None and period is not None:
        return timer_ns(_rate_parameter(spec, node, period), entry.rate_unit)
    rate = spec.nodes[node].rate_hz
    return timer_ns(rate, "hz") if rate is not None else None


def timer_ns(value: float, unit: str) -> int:
    """A timer's period in whole nanoseconds from a rate in hertz or a period in seconds or milliseconds."""
    if unit == "hz":
        return int((1.0 / value) * 1e9)
    if unit == "s":
        return int(value * 1e9)
    return int(value * 1e6)
