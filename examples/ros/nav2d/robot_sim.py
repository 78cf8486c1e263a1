"""The robot (not part of the app, not scheduled): odometry at 50 Hz and a base that records each command.

Each ``cmd_vel`` command the base receives is recorded with its origin, the stamp of the scan it
descends from (``$NAV2D_RECORD_DIR``/robot.jsonl, node ``base``), and the time it arrived.
"""

from __future__ import annotations

import time

from geometry_msgs.msg import TwistStamped
from nav2d_common import Records, period_s, spin, stamp_ns, stamp_of
from nav_msgs.msg import Odometry
from rclpy.node import Node

ODOM_HZ = 50.0


class Robot(Node):
    def __init__(self) -> None:
        super().__init__("robot")
        self.records = Records("robot")
        self.odom = self.create_publisher(Odometry, "odom", 10)
        self.create_subscription(TwistStamped, "cmd_vel", self.drive, 10)
        self.odom_timer = self.create_timer(period_s(ODOM_HZ), self.publish_odom)

    def publish_odom(self) -> None:
        odom = Odometry()
        odom.header.stamp = stamp_of(time.time_ns())
        odom.header.frame_id = "odom"
        self.odom.publish(odom)

    def drive(self, command: TwistStamped) -> None:
        received_ns = time.time_ns()
        self.records.run("base", received_ns, stamp_ns(command.header.stamp))


if __name__ == "__main__":
    spin(Robot)
