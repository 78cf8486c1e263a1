"""nav2d's Mapper process: global localization (GL) and the global mapper (GM), one executor thread.

GL is a batch node: it buffers every scan and, on each run (every ``map_scan_period`` s, or when
catanc triggers it), localizes on all of them and publishes a pose stamped with the newest one.
GM rebuilds the global map every ``map_update_rate`` s (a period, as upstream names it) from GL's
newest pose.  Both run on timers, with or without catanc.
"""

from __future__ import annotations

import time
from collections import deque

from geometry_msgs.msg import PoseStamped
from nav2d_common import Records, Work, period_s, spin, stamp_ns, stamp_of
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

from catanc import ros as catanc_ros

CELLS = 200  # a 200 x 200 global map
SCAN_BUFFER = 100  # scans GL keeps between two runs


class Mapper(Node):
    def __init__(self) -> None:
        super().__init__("Mapper")
        scan_period_s = float(self.declare_parameter("map_scan_period", period_s(50.0)).value)
        update_period_s = float(self.declare_parameter("map_update_rate", 5.0).value)
        self.work = Work(["GL", "GM"])
        self.records = Records("Mapper")
        self.scans: deque[LaserScan] = deque(maxlen=SCAN_BUFFER)
        self.pose_origin_ns: int | None = None
        self.pose = self.create_publisher(PoseStamped, "pose", 10)
        self.map = self.create_publisher(OccupancyGrid, "map", 1)
        self.create_subscription(LaserScan, "scan", self.keep_scan, SCAN_BUFFER)
        self.localize_timer = catanc_ros.create_timer(self, scan_period_s, self.localize, name="GL")
        self.update_timer = catanc_ros.create_timer(self, update_period_s, self.update_map, name="GM")

    def keep_scan(self, scan: LaserScan) -> None:
        self.scans.append(scan)

    def localize(self) -> None:
        """GL: one pose correction over every scan since the last run."""
        start_ns = time.time_ns()
        batch = list(self.scans)
        self.scans.clear()
        self.work.burn("GL")
        if batch:
            self.pose_origin_ns = stamp_ns(batch[-1].header.stamp)
            pose = PoseStamped()
            pose.header.stamp = batch[-1].header.stamp
            pose.header.frame_id = "map"
            self.pose.publish(pose)
        self.records.run("GL", start_ns, self.pose_origin_ns, batch=len(batch))

    def update_map(self) -> None:
        """GM: the global occupancy grid, from GL's newest pose."""
        start_ns = time.time_ns()
        self.work.burn("GM")
        if self.pose_origin_ns is not None:
            grid = OccupancyGrid(data=bytes(CELLS * CELLS))
            grid.header.stamp = stamp_of(self.pose_origin_ns)
            grid.header.frame_id = "map"
            grid.info.width = grid.info.height = CELLS
            grid.info.resolution = 0.1
            self.map.publish(grid)
        self.records.run("GM", start_ns, self.pose_origin_ns)


if __name__ == "__main__":
    spin(Mapper)
