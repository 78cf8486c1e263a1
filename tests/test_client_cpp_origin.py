"""The C++ client's run origin, ``done(catanc::Origin{...})``, and its nodes on their input (``catanc::OnInput``).

A small node compiled with the header as a user would (``catanc client --cflags``, warnings as
errors) registers on its input, reports three runs nothing triggered (with an origin, with a
compute time and an origin, without one) and leaves; :class:`FakeEnforcer` reads its hello and
its ring.  The origins are
checked against the clocks this test reads itself.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest

from tests.support.client_nodes import CXX_FLAGS, cflags, compiler, without_enforcer
from tests.support.fake_enforcer import TIMEOUT_S, FakeEnforcer

NODE = r"""
#include <catanc/client.hpp>
#include <cstdlib>

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  const std::int64_t sensed = std::strtoll(argv[1], nullptr, 10);
  catanc::Node node("LP", catanc::OnInput{});
  node.begin();
  node.done(catanc::Origin{sensed});
  node.begin();
  node.done(1.5, catanc::Origin{sensed + 1000000});
  node.begin();
  node.done();
  return node.wait(0.0) ? 1 : 0;  // a node on its input is never triggered
}
"""


@pytest.fixture(scope="module")
def binary(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("cpp-origin")
    source, binary = folder / "origin.cpp", folder / "origin"
    source.write_text(NODE)
    argv = [compiler(), *CXX_FLAGS, *cflags(), str(source), "-o", str(binary)]
    built = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    assert built.returncode == 0, built.stderr
    return binary


def test_done_with_an_origin_writes_it_on_the_monotonic_clock(tmp_path: Path, binary: Path) -> None:
    enforcer = FakeEnforcer(tmp_path / "catanc.sock")
    try:
        sensed = time.time_ns() - 7_000_000  # 7 ms ago, on the clock of a ROS header.stamp
        offset_before = time.time_ns() - time.monotonic_ns()
        env = {**without_enforcer(), "CATANC_SOCKET": str(enforcer.path)}
        proc = subprocess.Popen([str(binary), str(sensed)], env=env, stderr=subprocess.PIPE, text=True)
        assert enforcer.welcome({"LP"})["LP"].on_input  # its hello said so
        first, second, third = enforcer.runs("LP", 3)
        _, err = proc.communicate(timeout=TIMEOUT_S)
        offset_after = time.time_ns() - time.monotonic_ns()
        assert proc.returncode == 0, err
    finally:
        enforcer.close()
    low, high = sorted((offset_before, offset_after))
    assert sensed - high - 1_000_000 <= first.origin_ns <= sensed - low + 1_000_000
    assert first.end_ns - first.origin_ns >= 6_000_000
    assert second.compute_ms == 1.5
    assert second.origin_ns - first.origin_ns == pytest.approx(1_000_000, abs=1_000_000)
    assert third.origin_ns == 0  # none


def test_a_node_on_its_input_without_an_enforcer_just_runs(binary: Path) -> None:
    done = subprocess.run(
        [str(binary), str(time.time_ns())],
        env=without_enforcer(),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # no error, and not the "runs on its own timer" warning
