"""What gets started, pinned and configured: the spec's ``deploy`` section applied to a plan.

A *process* is one ROS node (every DAG node naming the same ``ros_node``
runs in it, as nav2d's Mapper hosts GL and GM) or, for a DAG node without
``ros_node``, that node alone.  :func:`deploy_problems` checks the section
(run by ``catanc validate``); :func:`processes` turns a plan into the
processes the launchers start, each with the CPUs and the SCHED_FIFO
priority catan-model.md section 6 gives its nodes, and the ROS parameters
``params.yaml`` sets.

Launch priorities are the enforcer's resting levels: a shared subchain's
nodes sit at FIFO 1 (``catanc run`` raises the running slice to 2), a
dedicated subchain's at 2, unscheduled nodes at 3.  A process hosting
several nodes gets the union of their CPUs and the highest of their levels:
a process has one affinity and one policy; ``catanc run`` pins per thread.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from catanc.core.priorities import resting_fifo, static_policy
from catanc.errors import FieldPath
from catanc.spec.language import Deploy, Spec

if TYPE_CHECKING:
    from catanc.planning.planner import Plan

RESERVED_PREFIX = "catan"  # params.yaml's own parameters live under ``catan.``

ROS_NAME_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
ROS_NODE_PATTERN = re.compile(rf"/?{ROS_NAME_TOKEN}(/{ROS_NAME_TOKEN})*")
PARAMETER_PATTERN = re.compile(rf"{ROS_NAME_TOKEN}(\.{ROS_NAME_TOKEN})*")

PERIOD_NS = "{period_ns}"
"""In a callback group ID, the timer period the plan gives the node, in nanoseconds."""
CALLBACK_PATTERN = re.compile(
    rf"(Subscription|Service|Client)\((/{ROS_NAME_TOKEN})+\)|Timer\(([0-9]+|\{{period_ns\}})\)|Waitable"
)
"""One callback of a cie_thread_configurator callback group ID (its README: "CallbackGroup ID format")."""

ParamValue = bool | int | float | str | list[int] | list[float] | list[str]
ParamTree = dict[str, Any]  # nested: {"local_map": {"update_frequency": 135.0}}


@dataclass(frozen=True)
class Process:
    """One process the launchers start (when it has a command or a ROS executable)."""

    key: str  # the ROS node (``/Mapper``) or the DAG node's name
    ros_node: str | None  # fully qualified, with a leading ``/``
    nodes: tuple[str, ...]  # DAG nodes it hosts, in spec order
    argv: tuple[str, ...]  # the command, split as a shell would (empty: not started by launch.sh)
    package: str | None
    executable: str | None
    cpus: tuple[int, ...]
    priority: int  # SCHED_FIFO priority at launch
    params: ParamTree  # ROS parameters (empty without ros_node)

    @property
    def namespace(self) -> str:
        """``/ns`` of ``/ns/name`` (``/`` for a top-level node)."""
        assert self.ros_node is not None
        return self.ros_node.rsplit("/", 1)[0] or "/"

    @property
    def name(self) -> str:
        assert self.ros_node is not None
        return self.ros_node.rsplit("/", 1)[1]


# --------------------------------------------------------------------------- checking the spec


def qualified(ros_node: str) -> str:
    """``Operator`` -> ``/Operator``."""
    return ros_node if ros_node.startswith("/") else "/" + ros_node


def process_key(name: str, entry: Deploy) -> str:
    return qualified(entry.ros_node) if entry.ros_node is not None else name


def split_command(command: str) -> list[str]:
    """``command`` split into arguments as a POSIX shell would, without running a shell; ValueError if it cannot."""
    argv = shlex.split(command, comments=False, posix=True)
    if not argv:
        raise ValueError("the command is empty")
    return argv


def deploy_problems(spec: Spec) -> Iterator[tuple[FieldPath, str]]:
    """Every problem of the ``deploy`` section, as ``(field path, message)``; node names are checked elsewhere."""
    first_of: dict[str, dict[str, tuple[str, str]]] = {}  # process -> field -> (node, value)
    params_of: dict[str, dict[str, str]] = {}  # process -> parameter -> node
    for name, entry in spec.deploy.items():
        where: FieldPath = ("deploy", name)
        if entry.ros_node is not None and not ROS_NODE_PATTERN.fullmatch(entry.ros_node):
            yield (
                (*where, "ros_node"),
                f"{entry.ros_node!r} is not a ROS node name (letters, digits and '_' per part, "
                "parts separated by '/', e.g. /nav/local_mapper)",
            )
        if entry.command is not None:
            try:
                split_command(entry.command)
            except ValueError as exc:
                yield (*where, "command"), f"cannot split the command into arguments: {exc}"
        yield from _callback_group_problems(spec, name, entry)
        if (entry.package is None) != (entry.executable is None):
            missing = "executable" if entry.executable is None else "package"
            yield where, f"a ROS process needs both package and executable: {missing} is missing"
        if entry.ros_node is None and (entry.package is not None or entry.rate_param is not None):
            yield where, "package/executable and rate_param need ros_node (the ROS node they belong to)"
        key = process_key(name, entry)
        firsts = first_of.setdefault(key, {})
        for field in ("command", "package", "executable"):
            value = getattr(entry, field)
            if value is None:
                continue
            if field in firsts and firsts[field][1] != value:
                other = firsts[field][0]
                yield (
                    (*where, field),
                    f"{key} already has {field} {firsts[field][1]!r} (from {other}); the nodes of one "
                    f"ROS node share one process: give {field} once",
                )
            firsts.setdefault(field, (name, value))
        if entry.rate_param is not None:
            path = (*where, "rate_param")
            param = entry.rate_param
            node = spec.nodes.get(name)
            taken = params_of.setdefault(key, {})
            if not PARAMETER_PATTERN.fullmatch(param):
                yield path, f"{param!r} is not a ROS parameter name (e.g. local_map.update_frequency)"
            elif param.split(".")[0] == RESERVED_PREFIX:
                yield path, f"parameters under {RESERVED_PREFIX!r} are catanc's own; pick another name"
            elif (clash := _clash(param, taken)) is not None:
                yield path, f"{key} already sets {clash!r} (for {taken[clash]}): {clash_reason(param, clash)}"
            elif node is not None and not node.scheduled and node.rate_hz is None:
                yield path, f"node {name!r} is unscheduled and has no rate_hz: there is no rate to set"
            taken[param] = name


def _callback_group_problems(spec: Spec, name: str, entry: Deploy) -> Iterator[tuple[FieldPath, str]]:
    group = entry.callback_group
    if group is None:
        return
    path: FieldPath = ("deploy", name, "callback_group")
    node, *callbacks = group.split("@")
    if not callbacks or not node.startswith("/") or not ROS_NODE_PATTERN.fullmatch(node):
        yield (
            path,
            f"{group!r} is not a callback group ID: the node's full name, then each callback after '@' "
            "(e.g. /local_mapper@Timer({period_ns})@Subscription(/scan))",
        )
        return
    bad = next((callback for callback in callbacks if not CALLBACK_PATTERN.fullmatch(callback)), None)
    if bad is not None:
        yield (
            path,
            f"{bad!r} is not a callback: Subscription(/topic), Service(/name), Client(/name), "
            f"Timer(<period in ns>) or Timer({PERIOD_NS}), or Waitable",
        )
        return
    if entry.ros_node is None:
        yield path, "callback_group needs ros_node (the ROS node whose thread it is)"
        return
    if node != qualified(entry.ros_node):
        yield path, f"the callback group is {node}'s, but ros_node is {qualified(entry.ros_node)}"
    spec_node = spec.nodes.get(name)
    own_clock = spec_node is not None and not spec_node.scheduled and spec_node.rate_hz is not None
    if PERIOD_NS in group and entry.rate_param is None and not own_clock:
        yield (
            path,
            f"{PERIOD_NS} is the timer period the plan sets through rate_param, and node {name!r} has none "
            "(nor a clock of its own, rate_hz)",
        )


def _clash(param: str, taken: dict[str, str]) -> str | None:
    """A parameter of the same process that ``param`` equals or nests with (``a`` and ``a.b``)."""
    for other in sorted(taken):
        if other == param or other.startswith(param + ".") or param.startswith(other + "."):
            return other
    return None


def clash_reason(param: str, other: str) -> str:
    if param == other:
        return "one rate parameter per node"
    return "a parameter cannot also be a group of parameters"


# --------------------------------------------------------------------------- applying a plan


def processes(spec: Spec, plan: Plan) -> tuple[Process, ...]:
    """The plan's processes, sorted by key; the spec must have passed :func:`deploy_problems`."""
    grouped: dict[str, list[str]] = {}
    for name in spec.nodes:
        if name in spec.deploy:
            grouped.setdefault(process_key(name, spec.deploy[name]), []).append(name)
    membership = {node: sub.name for sub in plan.subchains.values() for node in sub.nodes}
    found = []
    for key in sorted(grouped):
        nodes = tuple(grouped[key])
        entries = [spec.deploy[n] for n in nodes]
        cpus: set[int] = set()
        priority = 0
        for node in nodes:
            node_cpus, level = _placement(plan, node, membership)
            cpus.update(node_cpus)
            priority = max(priority, level)
        command = _first(entry.command for entry in entries)
        ros_node = _first(entry.ros_node for entry in entries)
        process_cpus = tuple(sorted(cpus))
        found.append(
            Process(
                key=key,
                ros_node=qualified(ros_node) if ros_node is not None else None,
                nodes=nodes,
                argv=tuple(split_command(command)) if command is not None else (),
                package=_first(entry.package for entry in entries),
                executable=_first(entry.executable for entry in entries),
                cpus=process_cpus,
                priority=priority,
                params=(
                    _params(spec, plan, nodes, membership, cpus=process_cpus, priority=priority)
                    if ros_node is not None
                    else {}
                ),
            )
        )
    return tuple(found)


def _first(values: Iterable[str | None]) -> str | None:
    return next((value for value in values if value is not None), None)


def node_period_ms(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> float | None:
    """The period the plan gives ``node``: its subchain's, or its own clock's; None for a rate-less sink."""
    # Imported here: at the top it would be circular (problem -> deploy -> table -> problem).
    from catanc.artifacts.runtime_table import ms  # noqa: PLC0415

    if node in membership:
        return ms(plan.subchains[membership[node]].period_ms)
    rate = spec.nodes[node].rate_hz
    return ms(1000.0 / rate) if rate is not None else None


def rate_value(period_ms: float, unit: str) -> float:
    """A node's rate parameter: in hertz, or its period in seconds or milliseconds."""
    from catanc.artifacts.runtime_table import RATE_DIGITS, ms  # noqa: PLC0415

    if unit == "hz":
        return round(1000.0 / period_ms, RATE_DIGITS)
    if unit == "s":
        return round(period_ms / 1000.0, RATE_DIGITS + 3)
    return ms(period_ms)


def _params(
    spec: Spec,
    plan: Plan,
    nodes: tuple[str, ...],
    membership: dict[str, str],
    *,
    cpus: tuple[int, ...],
    priority: int,
) -> ParamTree:
    """The ROS parameters of one process: each node's rate parameter, then ``catan.*``.

    ``catan.cpus`` and ``catan.priority`` are the process's (what the launcher
    applied).  ``catan.subchain`` and ``catan.period_ms`` describe its nodes
    when they run as one subchain (or one clock); a process hosting nodes of
    several puts them per node, as ``catan.nodes.<node>.subchain`` and so on.
    """
    flat: dict[str, ParamValue] = {}
    for node in nodes:
        entry = spec.deploy[node]
        period = node_period_ms(spec, plan, node, membership)
        if entry.rate_param is not None and period is not None:
            flat[entry.rate_param] = rate_value(period, entry.rate_unit)
    groups = {membership.get(node, node) for node in nodes}
    catan: dict[str, ParamValue] = {"cpus": list(cpus), "priority": priority}
    if len(groups) == 1:
        catan.update(_node_params(spec, plan, nodes[0], membership))
    else:
        for node in nodes:
            for field, value in _node_params(spec, plan, node, membership).items():
                catan[f"nodes.{node}.{field}"] = value
    flat.update({f"{RESERVED_PREFIX}.{field}": value for field, value in catan.items()})
    return nest(flat)


def _placement(plan: Plan, node: str, membership: dict[str, str]) -> tuple[tuple[int, ...], int]:
    """A node's CPUs and resting SCHED_FIFO priority: its subchain's cores, or every core when unscheduled."""
    if node in membership:
        sub = plan.subchains[membership[node]]
        return sub.cores, resting_fifo(sub.shared)
    return tuple(range(plan.cores)), resting_fifo(None)


def _node_params(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> dict[str, ParamValue]:
    found: dict[str, ParamValue] = {}
    if node in membership:
        found["subchain"] = membership[node]
    cpus, priority = _placement(plan, node, membership)
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
    policy: str  # SCHED_FIFO or SCHED_OTHER (catanc.core.priorities.static_policy)
    priority: int  # SCHED_FIFO priority; 0 under SCHED_OTHER


def callback_groups(spec: Spec, plan: Plan) -> tuple[CallbackGroup, ...]:
    """The callback groups the spec names, sorted by ID; the spec must have passed :func:`deploy_problems`.

    Nodes sharing one ID share one thread: it gets the union of their CPUs and the strongest of
    their policies (a node on its own clock over a dedicated subchain over a shared core).
    """
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
        cpus: set[int] = set()
        policies = []
        for node in nodes:
            node_cpus, _ = _placement(plan, node, membership)
            cpus.update(node_cpus)
            shared = plan.subchains[membership[node]].shared if node in membership else None
            policies.append(static_policy(shared))
        policy, priority = max(policies, key=lambda pair: (pair[0] == "SCHED_FIFO", pair[1]))
        found.append(CallbackGroup(group_id, nodes, tuple(sorted(cpus)), policy, priority))
    return tuple(found)


def timer_period_ns(spec: Spec, plan: Plan, node: str, membership: dict[str, str]) -> int | None:
    """The period, in whole nanoseconds, of the timer a node makes from its rate parameter (or its own rate_hz).

    As rclcpp code does it in double precision: ``1.0 / rate`` seconds for a rate in hertz, the
    period as given in seconds or milliseconds, truncated to nanoseconds
    (``std::chrono::duration_cast``, ``rclcpp::Duration::from_seconds``).
    """
    entry = spec.deploy[node]
    period = node_period_ms(spec, plan, node, membership)
    if entry.rate_param is not None and period is not None:
        return timer_ns(rate_value(period, entry.rate_unit), entry.rate_unit)
    rate = spec.nodes[node].rate_hz
    return timer_ns(rate, "hz") if rate is not None else None


def timer_ns(value: float, unit: str) -> int:
    """A timer's period in whole nanoseconds from a rate in hertz or a period in seconds or milliseconds."""
    if unit == "hz":
        return int((1.0 / value) * 1e9)
    if unit == "s":
        return int(value * 1e9)
    return int(value * 1e6)
