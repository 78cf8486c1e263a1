"""A recording stand-in of the parts of ROS 2's ``launch`` and ``launch_ros`` APIs that launch.py uses.

``launch``/``launch_ros`` are not on the package index, so tests load an emitted launch.py against
these modules: every action it makes is an :class:`Action` holding its keyword arguments.
:func:`describe` runs ``generate_launch_description`` for given launch arguments (as ``ros2 launch
... static:=true`` would) and runs its ``OpaqueFunction`` with a context holding them.
:func:`command_line` is the command a launch would run for an ``ExecuteProcess`` (its ``prefix``
split as a shell would, then ``cmd``) or a ``Node`` (launch_ros puts the executable and its
``arguments`` first, then a ``--ros-args`` section with ``ros_arguments``, then one with the
node's ``-r __node:=``, ``-r __ns:=`` and a ``--params-file`` per parameter file).
"""

from __future__ import annotations

import shlex
import sys
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

MODULES = ("launch", "launch.actions", "launch.event_handlers", "launch_ros", "launch_ros.actions")


@dataclass
class Action:
    kind: str
    kwargs: dict[str, Any]


@dataclass
class StandInContext:
    launch_configurations: dict[str, str] = field(default_factory=dict)


def _recorder(kind: str) -> Callable[..., Action]:
    def make(*args: Any, **kwargs: Any) -> Action:
        if args:  # DeclareLaunchArgument(name, ...), RegisterEventHandler(handler), LaunchDescription(actions)
            kwargs = {"positional": list(args), **kwargs}
        return Action(kind, kwargs)

    return make


def stand_in_modules() -> dict[str, types.ModuleType]:
    modules = {name: types.ModuleType(name) for name in MODULES}
    modules["launch"].LaunchDescription = _recorder("LaunchDescription")  # type: ignore[attr-defined]
    modules["launch"].LaunchContext = StandInContext  # type: ignore[attr-defined]
    for kind in ("DeclareLaunchArgument", "ExecuteProcess", "OpaqueFunction", "RegisterEventHandler", "Shutdown"):
        setattr(modules["launch.actions"], kind, _recorder(kind))
    for kind in ("OnProcessExit", "OnShutdown"):
        setattr(modules["launch.event_handlers"], kind, _recorder(kind))
    modules["launch_ros.actions"].Node = _recorder("Node")  # type: ignore[attr-defined]
    return modules


@dataclass
class Description:
    declared: dict[str, str]  # launch argument -> default
    actions: list[Action]  # with each OpaqueFunction replaced by what it returned


def describe(launch_file: Path, monkeypatch: pytest.MonkeyPatch, **arguments: str) -> Description:
    """``launch_file``'s actions for ``arguments`` (``static="true"``), with the stand-ins."""
    for name, module in stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    namespace: dict[str, Any] = {"__file__": str(launch_file), "__name__": "launch_file"}
    exec(compile(launch_file.read_text(), str(launch_file), "exec"), namespace)
    description = namespace["generate_launch_description"]()
    assert description.kind == "LaunchDescription"
    declared: dict[str, str] = {}
    actions: list[Action] = []
    for action in description.kwargs["positional"][0]:
        if action.kind == "DeclareLaunchArgument":
            declared[action.kwargs["positional"][0]] = action.kwargs["default_value"]
        else:
            actions.append(action)
    assert set(arguments) <= set(declared), (arguments, declared)
    context = StandInContext({**declared, **arguments})
    flat: list[Action] = []
    for action in actions:
        if action.kind == "OpaqueFunction":
            flat.extend(action.kwargs["function"](context) or [])
        else:
            flat.append(action)
    return Description(declared, flat)


def command_line(action: Action, executables: Callable[[str, str], Sequence[str]]) -> list[str]:
    """What a launch runs for ``action``; ``executables(package, executable)``: the program's own words."""
    prefix = shlex.split(action.kwargs.get("prefix", ""))
    if action.kind == "ExecuteProcess":
        return [*prefix, *action.kwargs["cmd"]]
    assert action.kind == "Node", action.kind
    words = [*prefix, *executables(action.kwargs["package"], action.kwargs["executable"])]
    words += action.kwargs.get("arguments", [])
    if action.kwargs.get("ros_arguments"):
        words += ["--ros-args", *action.kwargs["ros_arguments"]]
    words.append("--ros-args")
    if "name" in action.kwargs:
        words += ["-r", f"__node:={action.kwargs['name']}"]
    if "namespace" in action.kwargs:
        words += ["-r", f"__ns:={action.kwargs['namespace']}"]
    for params in action.kwargs.get("parameters", []):
        words += ["--params-file", params]
    return words


def environment_of(action: Action) -> dict[str, str]:
    """The variables a launch adds to the process's environment."""
    return dict(action.kwargs.get("additional_env", {}))
