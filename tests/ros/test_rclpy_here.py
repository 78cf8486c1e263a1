"""rclpy itself, as the other tests here use it: a publisher and a subscription in one process meet on a topic."""

from __future__ import annotations

import os


def test_a_message_crosses_a_topic_in_this_sessions_domain() -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    assert os.environ["ROS_DOMAIN_ID"] != "0"
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("catanc_probe", context=context)
        got: list[str] = []
        node.create_subscription(String, "probe", lambda message: got.append(message.data), 10)
        publisher = node.create_publisher(String, "probe", 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        for _ in range(200):
            publisher.publish(String(data="hello"))
            executor.spin_once(timeout_sec=0.01)
            if got:
                break
        assert got[:1] == ["hello"]
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
