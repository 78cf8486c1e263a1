"""A tiny rclpy process for the deployment tests: one or more ROS nodes that declare their rate parameters.

Usage: ``python rate_node.py /ns/name=param[,param...] [/other=param ...] [--ros-args ...]``

Each argument before ``--ros-args`` makes one node (in this one process) that declares each named
parameter with the code's default, :data:`CODE_DEFAULT` (typed dynamically, as a node reading an
int or a float would), and ``catan.node``.  Once made, the process writes what every node got, under
its own fully qualified name, to ``$RATE_NODE_RECORDS/<pid>.json``: ``{"pid", "argv", "nodes":
{name: {param: value}}}``, then spins until SIGINT or SIGTERM.  It never speaks to the enforcer: a
deployed node that does not register.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

CODE_DEFAULT = 20.0  # what a node runs at when the plan's parameters do not reach it
RECORDS_ENV = "RATE_NODE_RECORDS"


def make_node(spec: str) -> tuple[Node, list[str]]:
    name, _, params = spec.partition("=")
    namespace, _, base = name.rpartition("/")
    node = Node(base, namespace=namespace or "/")
    wanted = [param for param in params.split(",") if param]
    for param in [*wanted, "catan.node"]:
        default = "" if param == "catan.node" else CODE_DEFAULT
        node.declare_parameter(param, default, ParameterDescriptor(dynamic_typing=True))
    return node, [*wanted, "catan.node"]


def main() -> None:
    rclpy.init(args=sys.argv)
    specs = rclpy.utilities.remove_ros_args(sys.argv)[1:]
    made = [make_node(spec) for spec in specs]
    record = {
        "pid": os.getpid(),
        "argv": sys.argv,
        "nodes": {
            node.get_fully_qualified_name(): {param: node.get_parameter(param).value for param in params}
            for node, params in made
        },
    }
    folder = Path(os.environ[RECORDS_ENV])
    partial = folder / f"{os.getpid()}.tmp"
    partial.write_text(json.dumps(record))
    partial.rename(folder / f"{os.getpid()}.json")
    executor = SingleThreadedExecutor()
    for node, _ in made:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node, _ in made:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
