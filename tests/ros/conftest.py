"""Real ROS 2 (rclpy over Fast DDS) for the tests in this folder.

Every test here carries the ``ros`` marker and skips, with the reason, where rclpy cannot be imported
(``pip install "catanc[ros]"``).  A test session gets a ROS domain of its own and localhost-only discovery,
set in this process's environment so that every node process a test starts inherits it: two runs of the
suite on one machine (or a developer's ROS graph beside it) never meet.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

RCLPY_MISSING = importlib.util.find_spec("rclpy") is None
SKIP_REASON = 'needs rclpy (ROS 2 Jazzy): pip install "catanc[ros]"'


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.is_relative_to(Path(__file__).parent):
            item.add_marker(pytest.mark.ros)
            if RCLPY_MISSING:
                item.add_marker(pytest.mark.skip(reason=SKIP_REASON))


def session_domain_id(pid: int) -> int:
    """A ROS domain for this test session: 1..100 (within Fast DDS's port range on Linux), from the pid."""
    return 1 + pid % 100


@pytest.fixture(scope="session", autouse=True)
def isolated_ros_graph() -> Iterator[None]:
    """This session's own ROS domain, discovery on localhost only, for this process and its children."""
    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY")
    saved = {key: os.environ.get(key) for key in keys}
    os.environ["ROS_DOMAIN_ID"] = str(session_domain_id(os.getpid()))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy: rcl warns when it is set
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
