"""Which processes run their nodes in one thread, and the executors they make (catanc.spec.executors).

Worked by hand: the programs taken for Python, each kind of process, and how an ``executors:`` entry
and a process's executor meet.
"""

from __future__ import annotations

from typing import Any

import pytest

from catanc.errors import SpecError
from catanc.model.build import build_problem
from catanc.spec.executors import executor_groups, python_program, spec_processes
from tests.support.strategies import spec_of


@pytest.mark.parametrize(
    ("command", "program"),
    [
        ("python3 nav_mapper.py", "python3"),
        ("python nav_mapper.py", "python"),
        ("/usr/bin/python3.12 -m worker --rate 5", "python3.12"),
        ("pypy3 app.py", "pypy3"),
        ("./nav_mapper.py --ros-args", "nav_mapper.py"),
        ("env PYTHONPATH=/opt/app python3 app.py", "python3"),
        ("/usr/bin/env -u DISPLAY python3 app.py", "python3"),
        ("'/opt/my app/python3' x.py", "python3"),
        # What a command does not say is not guessed: a ROS executable may be Python or not.
        ("ros2 run nav2d_karto mapper", None),
        ("python3-config --includes", None),
        ("bash -c 'python3 app.py'", None),
        ("env", None),
        (None, None),
    ],
)
def test_the_program_says_whether_a_process_is_python(command: str | None, program: str | None) -> None:
    assert python_program(command) == program


def app(deploy: dict[str, Any], **more: Any) -> dict[str, Any]:
    """Four scheduled nodes on subchains of their own, a clock, and ``deploy``."""
    return {
        "catan": 1,
        "app": "four",
        "nodes": {
            "a": {"compute_ms": 1},
            "b": {"compute_ms": 2},
            "c": {"compute_ms": 3},
            "d": {"compute_ms": 4},
            "clock": {"scheduled": False, "rate_hz": 10},
        },
        "subchains": {"A": ["a"], "B": ["b"], "C": ["c"], "D": ["d"]},
        "objective": [{"node": "a", "weight": 1.0}],
        "deploy": deploy,
        **more,
    }


def test_each_kind_of_process() -> None:
    spec = spec_of(
        app(
            {
                # A Python process: one thread, whatever its callback groups.
                "a": {
                    "ros_node": "/py_a",
                    "process": "py",
                    "command": "python3 py.py",
                    "callback_group": "/py_a@Timer(1000)",
                },
                "b": {"ros_node": "/py_b", "process": "py"},
                # A ROS process without callback groups: one single-threaded executor.
                "c": {"ros_node": "/plain", "command": "ros2 run demo plain"},
                "clock": {"ros_node": "/plain"},
                # A process of one scheduled node, and one naming callback groups (not Python).
                "d": {"ros_node": "/iso", "command": "ros2 run demo iso", "callback_group": "/iso@Timer(1000)"},
            }
        )
    )
    found = {process.key: process for process in spec_processes(spec)}
    assert list(found) == ["py", "/plain", "/iso"]  # by their first node, in spec order
    py, plain, iso = found["py"], found["/plain"], found["/iso"]
    assert (py.nodes, py.scheduled, py.python, py.one_thread) == (("a", "b"), ("a", "b"), "python3", True)
    assert py.origin == ("deploy", "a", "process")
    assert "interpreter lock" in py.reason
    assert "whatever its callback groups" in py.reason
    # The clock runs on its own: one scheduled node, nothing to serialise.
    assert (plain.nodes, plain.scheduled, plain.one_thread) == (("c", "clock"), ("c",), False)
    assert plain.origin == ("deploy", "c", "ros_node")
    assert (iso.callback_groups, iso.one_thread, iso.reason) == (("d",), False, "one scheduled node")
    problem = build_problem(spec)
    assert [(e.name, e.nodes, e.subchains, e.process, e.declared) for e in problem.executors] == [
        ("py", ("a", "b"), ("A", "B"), "py", "deploy.a.process")
    ]
    assert problem.together == (("A", "B"),)


def test_nodes_naming_callback_groups_in_a_ros_process_may_run_at_once() -> None:
    deploy = {
        "a": {"ros_node": "/a", "process": "iso", "command": "ros2 run demo iso", "callback_group": "/a@Timer(1000)"},
        "b": {"ros_node": "/b", "process": "iso", "callback_group": "/b@Timer(1000)"},
    }
    spec = spec_of(app(deploy))
    (iso,) = spec_processes(spec)
    assert not iso.one_thread
    assert (
        iso.reason == "a, b name callback groups: a callback-isolated executor runs each group in a thread of its own"
    )
    assert build_problem(spec).executors == ()
    # Without the groups, one executor; as a Python process, one executor too.
    bare = {name: {k: v for k, v in entry.items() if k != "callback_group"} for name, entry in deploy.items()}
    assert build_problem(spec_of(app(bare))).together == (("A", "B"),)
    python = deploy | {"a": deploy["a"] | {"command": "python3 iso.py"}}
    assert build_problem(spec_of(app(python))).together == (("A", "B"),)
    # In such a process an executors: entry still says which nodes share a thread.
    assert build_problem(spec_of(app(deploy, executors={"pair": ["a", "b"]}))).together == (("A", "B"),)


def test_an_entry_listing_a_process_names_its_executor_and_one_inside_it_is_held() -> None:
    worker = {name: {"process": "worker"} for name in "bc"} | {"a": {"process": "worker", "command": "ros2 run w"}}
    # An entry listing all of worker's nodes is worker's executor, under its name and in its order.
    (group,) = executor_groups(spec_of(app(worker, executors={"all": ["c", "b", "a"]})))
    assert (group.name, group.nodes, group.origin) == ("all", ("c", "b", "a"), ("executors", "all"))
    assert group.process is not None
    assert group.process.key == "worker"
    # An entry inside it is held by worker's executor, declared where worker is.
    (group,) = executor_groups(spec_of(app(worker, executors={"pair": ["b", "a"]})))
    assert (group.name, group.nodes, group.origin) == ("worker", ("a", "b", "c"), ("deploy", "a", "process"))
    # Entries outside any one-thread process keep their place, before the processes' executors.
    groups = executor_groups(spec_of(app({"a": worker["a"], "b": worker["b"]}, executors={"cd": ["c", "d"]})))
    assert [(group.name, group.nodes) for group in groups] == [("cd", ("c", "d")), ("worker", ("a", "b"))]


def test_an_entry_reaching_outside_a_one_thread_process_is_an_error() -> None:
    worker = {name: {"process": "worker"} for name in "bc"} | {"a": {"process": "worker", "command": "ros2 run w"}}
    with pytest.raises(SpecError, match=r"executors\.mine\[0\]: node 'd' has no deploy entry, but 'c' runs in"):
        build_problem(spec_of(app(worker, executors={"mine": ["d", "c"]})))
