"""nav2d's Navigator process: the global planner (GP) and the navigation command (NC), one executor thread.

GP plans a path on the newest global map every ``replanning_period`` s; NC turns the plan and GL's
newest pose into a command for the local planner at ``frequency`` Hz, stamped with that pose's
origin.  Both run on timers, with or without catanc.
"""

from __future__ import annotations

import time
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped
from nav2d_common import NEWEST, Records, Work, latest, period_s, spin, stamp_ns
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node

from catanc import ros as catanc_ros


class Navigator(Node):
    def __init__(self) -> None:
        super().__init__("Navigator")
        replan_period_s = float(self.declare_parameter("replanning_period", 1.0).value)
        command_hz = float(self.declare_parameter("frequency", 10.0).value)
        self.work = Work(["GP", "NC"])
        self.records = Records("Navigator")
        self.newest: dict[str, Any] = {}
        self.plan_origin_ns: int | None = None
        self.nav_cmd = self.create_publisher(TwistStamped, "nav_cmd", 10)
        self.create_subscription(OccupancyGrid, "map", latest(self.newest, "map"), NEWEST)
        self.create_subscription(PoseStamped, "pose", latest(self.newest, "pose"), NEWEST)
        self.create_subscription(Odometry, "odom", latest(self.newest, "odom"), NEWEST)
        self.plan_timer = catanc_ros.create_timer(self, replan_period_s, self.plan_path, name="GP")
        self.command_timer = catanc_ros.create_timer(self, period_s(command_hz), self.command, name="NC")

    def plan_path(self) -> None:
        """GP: a path to the goal on the newest global map."""
        start_ns = time.time_ns()
        self.work.burn("GP")
        grid = self.newest.get("map")
        if grid is not None:
            self.plan_origin_ns = stamp_ns(grid.header.stamp)
        self.records.run("GP", start_ns, self.plan_origin_ns)

    def command(self) -> None:
        """NC: where to drive next along the path, from GL's newest pose."""
        start_ns = time.time_ns()
        self.work.burn("NC")
        pose = self.newest.get("pose")
        origin_ns = None if pose is None else stamp_ns(pose.header.stamp)
        if pose is not None:
            twist = TwistStamped()
            twist.header.stamp = pose.header.stamp
            twist.twist.linear.x = 0.3
            self.nav_cmd.publish(twist)
        self.records.run("NC", start_ns, origin_ns, plan_origin_ns=self.plan_origin_ns)


if __name__ == "__main__":
    spin(Navigator)
