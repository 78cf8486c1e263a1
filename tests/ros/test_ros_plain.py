"""catanc.ros without an enforcer, and where it cannot be imported: plain rclpy, one log line, clear errors."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.timer import Timer

from catanc import ros as catanc_ros
from catanc.runtime.protocol.messages import SOCKET_ENV
from tests.support.ros_runs import ROOT, RosRun, exits_within, ros_run

PACKAGE = Path(catanc_ros.__file__).parent


@pytest.fixture
def node(monkeypatch: pytest.MonkeyPatch) -> Iterator[Node]:
    monkeypatch.delenv(SOCKET_ENV, raising=False)
    context = Context()
    rclpy.init(context=context)
    made = rclpy.create_node("catanc_plain", context=context)
    try:
        yield made
    finally:
        made.destroy_node()
        rclpy.shutdown(context=context)


def test_without_the_socket_it_is_rclpys_own_timer_and_callback(node: Node) -> None:
    ticks: list[int] = []
    timer = catanc_ros.create_timer(node, 0.01, lambda: ticks.append(1))
    assert isinstance(timer, Timer)
    assert timer.timer_period_ns == 10_000_000

    def callback(message: object) -> None:
        pass

    assert catanc_ros.reported(node, callback) is callback
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    for _ in range(100):
        executor.spin_once(timeout_sec=0.1)
        if len(ticks) >= 5:
            break
    executor.shutdown()
    assert len(ticks) >= 5
    assert not node.has_parameter(catanc_ros.NAME_PARAMETER)  # nothing of catanc's without catanc


def test_on_loss_is_checked(node: Node) -> None:
    with pytest.raises(ValueError, match="'timer' or 'exit'"):
        catanc_ros.create_timer(node, 0.01, lambda: None, on_loss="respawn")


@pytest.fixture
def run(tmp_path: Path) -> Iterator[RosRun]:
    with ros_run(tmp_path) as made:
        yield made


def test_an_enforcer_that_cannot_be_reached_is_one_log_line_then_the_timer(run: RosRun) -> None:
    cam = run.node("head", dag="cam")  # $CATANC_SOCKET names a path where no enforcer runs
    cam.wait_for("tick", 10)
    said = [line for line in cam.stderr().splitlines() if "enforcer" in line]
    assert len(said) == 1, cam.stderr()
    assert "no catanc enforcer" in said[0]
    os.kill(cam.proc.pid, 2)
    assert exits_within(cam.proc, 5.0) == 0, cam.stderr()


def test_a_node_without_a_name_says_so_and_runs_on_its_timer(run: RosRun) -> None:
    cam = run.node("head")  # no catan.node parameter, no name=
    cam.wait_for("tick", 10)
    assert "catan.node" in cam.stderr()


def _python(code: str, cwd: Path, *, isolated: bool = False) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, *(["-I"] if isolated else []), "-c", textwrap.dedent(code)]
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=60, check=False)


def test_without_rclpy_the_import_error_says_what_to_install(tmp_path: Path) -> None:
    done = _python(
        """
        import sys
        class NoRos:
            def find_spec(self, name, path=None, target=None):
                if name == "rclpy" or name.startswith("rclpy."):
                    raise ImportError(f"No module named {name!r}")
                return None
        sys.meta_path.insert(0, NoRos())
        try:
            import catanc.ros
        except ImportError as exc:
            print(exc)
        else:
            print("imported")
        """,
        tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert 'pip install "catanc[ros]"' in done.stdout


@pytest.mark.parametrize("client_name", ["catanc_client.py", "client.py"])
def test_the_copied_file_works_beside_a_copied_client(tmp_path: Path, client_name: str) -> None:
    shutil.copy(PACKAGE / "ros.py", tmp_path / "catanc_ros.py")
    shutil.copy(PACKAGE / "client.py", tmp_path / client_name)
    site = next(path for path in sys.path if path.endswith("site-packages"))
    done = _python(
        f"""
        import sys
        sys.path[:0] = [{str(tmp_path)!r}, {site!r}]
        sys.modules.pop("catanc", None)
        import catanc_ros
        print(catanc_ros.ClientError.__module__, "catanc" in sys.modules)
        """,
        tmp_path,
        isolated=True,  # no PYTHONPATH: the copies, rclpy, and nothing of the catanc checkout
    )
    assert done.returncode == 0, done.stderr
    module = client_name.removesuffix(".py")
    assert done.stdout.split() == [module, "False"]  # the copied client; catanc itself never imported


def test_the_cli_prints_where_catanc_ros_is(tmp_path: Path) -> None:
    def catanc(*args: str) -> subprocess.CompletedProcess[str]:
        argv = [sys.executable, "-m", "catanc", "client", *args]
        return subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False, cwd=tmp_path)

    printed = catanc("--ros")
    assert printed.returncode == 0, printed.stderr
    assert Path(printed.stdout.strip()).read_bytes() == (PACKAGE / "ros.py").read_bytes()
    both = catanc("--ros", "--python")
    assert both.returncode == 2
    assert "--ros" in both.stderr
