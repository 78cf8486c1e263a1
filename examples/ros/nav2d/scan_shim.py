"""nav2d's scan source (DAG node ``scan``): a LaserScan stamped when it is sensed, at ``publish_rate`` Hz."""

from __future__ import annotations

import math
import time

from nav2d_common import Records, Work, period_s, spin, stamp_of
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

from catanc import ros as catanc_ros

BEAMS = 360


class ScanShim(Node):
    def __init__(self) -> None:
        super().__init__("scan_shim")
        rate_hz = float(self.declare_parameter("publish_rate", 50.0).value)
        self.work = Work(["scan"])
        self.records = Records("scan_shim")
        self.publisher = self.create_publisher(LaserScan, "scan", 10)
        self.ranges = [2.0 + math.sin(beam / 7.0) for beam in range(BEAMS)]
        self.timer = catanc_ros.create_timer(self, period_s(rate_hz), self.tick, name="scan")

    def tick(self) -> None:
        sensed_ns = time.time_ns()
        self.work.burn("scan")
        scan = LaserScan(angle_min=-math.pi, angle_max=math.pi, angle_increment=2 * math.pi / BEAMS)
        scan.header.stamp = stamp_of(sensed_ns)
        scan.header.frame_id = "laser"
        scan.range_max = 10.0
        scan.ranges = self.ranges
        self.publisher.publish(scan)
        self.records.run("scan", sensed_ns, sensed_ns)


if __name__ == "__main__":
    spin(ScanShim)
