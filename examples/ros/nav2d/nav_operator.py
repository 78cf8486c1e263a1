"""nav2d's Operator process: the local mapper (LM) and local planner (LP), one ROS node, one executor thread.

``on_input`` (default true) runs them as catanc's ``local`` subchain: LM on each scan, LP on each
local map, each run reported with its message's stamp.  ``on_input: false`` runs each on its own
timer at ``local_map.update_frequency`` and ``frequency`` Hz, reading the newest input, as upstream
nav2d does (the spec's baseline).  LP's velocity command carries the scan stamp it descends from.
"""

from __future__ import annotations

import time
from typing import Any

from geometry_msgs.msg import TwistStamped
from nav2d_common import NEWEST, Records, Work, latest, period_s, spin, stamp_ns
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

from catanc import ros as catanc_ros

CELLS = 60  # a 60 x 60 rolling local costmap


class Operator(Node):
    def __init__(self) -> None:
        super().__init__("Operator")
        map_hz = float(self.declare_parameter("local_map.update_frequency", 5.0).value)
        plan_hz = float(self.declare_parameter("frequency", 10.0).value)
        on_input = bool(self.declare_parameter("on_input", True).value)
        self.work = Work(["LM", "LP"])
        self.records = Records("Operator")
        self.newest: dict[str, Any] = {}
        self.local_map = self.create_publisher(OccupancyGrid, "local_map", 10)
        self.cmd_vel = self.create_publisher(TwistStamped, "cmd_vel", 10)
        self.create_subscription(Odometry, "odom", latest(self.newest, "odom"), NEWEST)
        self.create_subscription(TwistStamped, "nav_cmd", latest(self.newest, "nav_cmd"), NEWEST)
        if on_input:
            self.create_subscription(LaserScan, "scan", catanc_ros.reported(self, self.map_scan, name="LM"), NEWEST)
            self.create_subscription(
                OccupancyGrid, "local_map", catanc_ros.reported(self, self.steer, name="LP"), NEWEST
            )
        else:
            self.create_subscription(LaserScan, "scan", latest(self.newest, "scan"), NEWEST)
            self.create_subscription(OccupancyGrid, "local_map", latest(self.newest, "local_map"), NEWEST)
            self.map_timer = self.create_timer(period_s(map_hz), lambda: self.map_scan(self.newest.get("scan")))
            self.plan_timer = self.create_timer(period_s(plan_hz), lambda: self.steer(self.newest.get("local_map")))

    def map_scan(self, scan: LaserScan | None) -> None:
        """LM: the local costmap around the robot from the newest scan."""
        start_ns = time.time_ns()
        self.work.burn("LM")
        origin_ns = None if scan is None else stamp_ns(scan.header.stamp)
        if scan is not None:
            grid = OccupancyGrid(data=bytes(CELLS * CELLS))
            grid.header.stamp = scan.header.stamp
            grid.header.frame_id = "odom"
            grid.info.width = grid.info.height = CELLS
            grid.info.resolution = 0.05
            self.local_map.publish(grid)
        self.records.run("LM", start_ns, origin_ns)

    def steer(self, grid: OccupancyGrid | None) -> None:
        """LP: a velocity for the base from the local costmap and the navigator's command."""
        start_ns = time.time_ns()
        self.work.burn("LP")
        command = self.newest.get("nav_cmd")
        nav_origin_ns = None if command is None else stamp_ns(command.header.stamp)
        origin_ns = None if grid is None else stamp_ns(grid.header.stamp)
        if grid is not None:
            twist = TwistStamped()
            twist.header.stamp = grid.header.stamp
            twist.header.frame_id = "base_link"
            twist.twist.linear.x = 0.3 if command is None else command.twist.linear.x
            self.cmd_vel.publish(twist)
        self.records.run("LP", start_ns, origin_ns, nav_origin_ns=nav_origin_ns)


if __name__ == "__main__":
    spin(Operator)
