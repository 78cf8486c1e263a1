"""Checking a spec's ``deploy`` section (run by ``catanc validate`` and every load).

What a process is, and what the launchers make of the section, is
:mod:`catanc.artifacts.deploy`'s; here is only what the section may say:
ROS node and parameter names, commands a POSIX shell can split, one
command, package and executable per ROS node, rate parameters that do not
clash, callback group IDs cie_thread_configurator can match.
:func:`deploy_problems` yields every problem as ``(field path, message)``;
:func:`catanc.model.problem.build_problem` reports them with the spec's other
problems.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterator

from catanc.errors import FieldPath
from catanc.spec.language import Deploy, Spec

RESERVED_PREFIX = "catan"  # params.yaml's own parameters live under ``catan.``

ROS_NAME_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
ROS_NODE_PATTERN = re.compile(rf"/?{ROS_NAME_TOKEN}(/{ROS_NAME_TOKEN})*")
PARAMETER_PATTERN = re.compile(rf"{ROS_NAME_TOKEN}(\.{ROS_NAME_TOKEN})*")

PERIOD_NS = "{period_ns}"
"""In a callback group ID, the timer period the plan gives the node, in nanoseconds."""
CALLBACK_PATTERN = re.compile(
    rf"(Agnocast)?(Subscription|Service|Client)\((/{ROS_NAME_TOKEN})+\)|Timer\(([0-9]+|\{{period_ns\}})\)|Waitable"
)
"""One callback of a cie_thread_configurator callback group ID (its README: "CallbackGroup ID format"), or
of Agnocast's (``AgnocastSubscription(/topic)``, ``AgnocastService(...)``, ``AgnocastClient(...)``)."""
CALLBACK_ORDER = ("Subscription", "Service", "Client", "Timer", "Agnocast", "Waitable")
"""The order of the callbacks in an ID: rclcpp's ``CallbackGroup::collect_all_ptrs`` visits a group's
subscriptions, services, clients, timers, then waitables, and cie_thread_configurator writes each as it
comes; Agnocast's callbacks follow rclcpp's.  A Waitable writes nothing in today's tool, and the
configurator drops ``@Waitable`` from the end of a configured ID (older tools wrote one per waitable)."""
CALLBACK_ID_EXAMPLE = "/local_mapper@Subscription(/scan)@Timer({period_ns})"


def qualified(ros_node: str) -> str:
    """``Operator`` -> ``/Operator``."""
    return ros_node if ros_node.startswith("/") else "/" + ros_node


def process_keys(spec: Spec) -> dict[str, str]:
    """The process each deployed node runs in: the ``process`` it or a node of its ROS node names (the first, in
    spec order), else its ROS node's (``/name``), else its own (its name)."""
    named: dict[str, str] = {}  # ROS node -> the process a node of it names
    for entry in spec.deploy.values():
        if entry.ros_node is not None and entry.process is not None:
            named.setdefault(qualified(entry.ros_node), entry.process)
    keys = {}
    for name, entry in spec.deploy.items():
        if entry.process is not None:
            keys[name] = entry.process
        elif entry.ros_node is not None:
            keys[name] = named.get(qualified(entry.ros_node), qualified(entry.ros_node))
        else:
            keys[name] = name
    return keys


def process_members(spec: Spec) -> dict[str, list[str]]:
    """Each process's deployed DAG nodes (:func:`process_keys`), processes and nodes in spec order of the nodes."""
    keys = process_keys(spec)
    members: dict[str, list[str]] = {}
    for name in spec.nodes:
        if name in spec.deploy:
            members.setdefault(keys[name], []).append(name)
    return members


def split_command(command: str) -> list[str]:
    """``command`` split into arguments as a POSIX shell would, without running a shell; ValueError if it cannot."""
    argv = shlex.split(command, comments=False, posix=True)
    if not argv:
        raise ValueError("the command is empty")
    return argv


def deploy_problems(spec: Spec) -> Iterator[tuple[FieldPath, str]]:
    """Every problem of the ``deploy`` section, as ``(field path, message)``; node names are checked elsewhere."""
    first_of: dict[str, dict[str, tuple[str, str]]] = {}  # process -> field -> (node, value)
    params_of: dict[str, dict[str, str]] = {}  # ROS node (or process) -> parameter -> node
    keys = process_keys(spec)
    process_of_ros: dict[str, tuple[str, str]] = {}  # ROS node -> (node, the process it names)
    for name, entry in spec.deploy.items():
        where: FieldPath = ("deploy", name)
        if entry.ros_node is not None and entry.process is not None:
            ros = qualified(entry.ros_node)
            other, process = process_of_ros.setdefault(ros, (name, entry.process))
            if process != entry.process:
                yield (
                    (*where, "process"),
                    f"{ros} runs in process {process!r} (from {other}): a ROS node runs in one process; "
                    f"give {name} process {process!r}, or another ros_node",
                )
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
        if entry.ros_node is None and entry.any_namespace:
            yield (*where, "any_namespace"), "any_namespace needs ros_node (the ROS node whose parameters it keys)"
        if entry.rate_type != "float" and entry.rate_param is None:
            yield (*where, "rate_type"), "rate_type is the type of rate_param's value, and there is no rate_param"
        key = keys[name]
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
                    f"process share one {field}: give it once, or put {name} in a process of its own",
                )
            firsts.setdefault(field, (name, value))
        own = qualified(entry.ros_node) if entry.ros_node is not None else key
        if entry.rate_param is not None:
            path = (*where, "rate_param")
            param = entry.rate_param
            node = spec.nodes.get(name)
            taken = params_of.setdefault(own, {})
            if not PARAMETER_PATTERN.fullmatch(param):
                yield path, f"{param!r} is not a ROS parameter name (e.g. local_map.update_frequency)"
            elif param.split(".")[0] == RESERVED_PREFIX:
                yield path, f"parameters under {RESERVED_PREFIX!r} are catanc's own; pick another name"
            elif (clash := _clash(param, taken)) is not None:
                yield path, f"{own} already sets {clash!r} (for {taken[clash]}): {clash_reason(param, clash)}"
            elif node is not None and not node.scheduled and node.rate_hz is None:
                yield path, f"node {name!r} is unscheduled and has no rate_hz: there is no rate to set"
            taken[param] = name
    yield from _wildcard_problems(spec)


def _wildcard_problems(spec: Spec) -> Iterator[tuple[FieldPath, str]]:
    """A ``/**/a/b`` key (any_namespace) that would also match another process's node, ``/x/a/b``."""
    ros_nodes = {qualified(entry.ros_node): name for name, entry in spec.deploy.items() if entry.ros_node is not None}
    for name, entry in spec.deploy.items():
        if entry.ros_node is None or not entry.any_namespace:
            continue
        own = qualified(entry.ros_node)
        other = next((node for node in sorted(ros_nodes) if node != own and node.endswith(own)), None)
        if other is not None:
            yield (
                ("deploy", name, "any_namespace"),
                f"/**{own} would also match {other} (node {ros_nodes[other]}): params.yaml would set both "
                "nodes' parameters from either's",
            )


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
            f"(e.g. {CALLBACK_ID_EXAMPLE})",
        )
        return
    bad = next((callback for callback in callbacks if not CALLBACK_PATTERN.fullmatch(callback)), None)
    if bad is not None:
        yield (
            path,
            f"{bad!r} is not a callback: Subscription(/topic), Service(/name), Client(/name), "
            f"Timer(<period in ns>) or Timer({PERIOD_NS}), Agnocast's AgnocastSubscription(/topic), "
            "AgnocastService(/name) or AgnocastClient(/name), or Waitable",
        )
        return
    ordered = sorted(callbacks, key=_callback_rank)  # stable: callbacks of one kind keep their order
    if ordered != callbacks:
        yield (
            path,
            "callbacks out of order: cie_thread_configurator writes a group's Subscriptions, then Services, "
            "Clients, Timers, then Agnocast's callbacks, Waitables last; this ID would never match "
            f"(did you mean {'@'.join([node, *ordered])!r}?)",
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


def _callback_rank(callback: str) -> int:
    """Where a callback (one that :data:`CALLBACK_PATTERN` matches) goes in an ID: its kind's place in
    :data:`CALLBACK_ORDER`."""
    return next(rank for rank, kind in enumerate(CALLBACK_ORDER) if callback.startswith(kind))


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
