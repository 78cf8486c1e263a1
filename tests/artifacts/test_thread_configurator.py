"""``cie_thread_configurator.yaml``: the plan as callback_isolated_executor's thread settings.

The file is checked as the tool reads it (its configurator node: ``callback_groups`` entries with
``id``, ``affinity``, ``policy`` and, for every policy but SCHED_DEADLINE, ``priority``; its README:
``nice`` for the fair policies), against the plan it came from (each group's CPUs and policy from
its nodes' subchains), and the timer periods against a real C++ compiler's ``std::chrono``.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from catanc.artifacts.compile import Options, compile_spec
from catanc.artifacts.deploy import timer_ns
from catanc.artifacts.emit import FILES, THREAD_CONFIGURATOR
from catanc.cli.main import app
from catanc.errors import ExitCode, SpecError
from catanc.model.load import load_spec, parse_spec
from catanc.planning.planner import plan

runner = CliRunner()

ROBOT = """\
catan: 1
app: robot
nodes:
  cam: {compute_ms: 5}
  det: {compute_ms: 30}
  track: {compute_ms: 2}
  imu: {scheduled: false, rate_hz: 200}
  motor: {scheduled: false}
edges: [[cam, det], [det, track], [imu, track], [track, motor]]
subchains:
  cam: [cam]
  det: [det]
  track: [track]
objective:
  - {chain: [cam, det, track, motor], weight: 1.0}
constraints:
  - {node: cam, rate_hz: 40}
deploy:
  cam: {ros_node: /camera, rate_param: fps, callback_group: "/camera@Timer({period_ns})"}
  det: {ros_node: /detector, callback_group: "/detector@Subscription(/image)@Timer(1000000000)"}
  track: {ros_node: /tracker, callback_group: "/tracker@Subscription(/detections)@Waitable"}
  imu: {ros_node: /imu, callback_group: "/imu@Timer({period_ns})"}
"""

POLICIES = {"SCHED_OTHER", "SCHED_BATCH", "SCHED_IDLE", "SCHED_FIFO", "SCHED_RR", "SCHED_DEADLINE"}


@pytest.fixture
def robot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "robot.yaml"
    path.write_text(ROBOT)
    return path


def read_as_the_tool_does(text: str, cores: int, section: str = "callback_groups") -> dict[str, dict[str, Any]]:
    """``{id: entry}`` of one list, failing wherever cie_thread_configurator would refuse or misread the file."""
    data = yaml.safe_load(text)
    assert "callback_groups" in data
    assert set(data) <= {"callback_groups", "non_ros_threads", "hardware_info", "rt_throttling"}
    found = {}
    for entry in data.get(section, []):
        assert isinstance(entry["id"], str)
        assert entry["id"] not in found
        assert all(isinstance(cpu, int) and 0 <= cpu < cores for cpu in entry["affinity"])
        assert entry["policy"] in POLICIES
        if entry["policy"] in ("SCHED_FIFO", "SCHED_RR"):
            assert 1 <= entry["priority"] <= 99
            assert "nice" not in entry
        elif entry["policy"] != "SCHED_DEADLINE":
            assert -20 <= entry["nice"] <= 19
            assert entry["priority"] == entry["nice"]  # the node reads priority as the nice value
        found[entry["id"]] = entry
    return found


def test_each_callback_group_gets_its_subchains_cpus_and_the_static_policy(robot: Path) -> None:
    target = compile_spec(robot, 2)
    assert sorted(target.files) == sorted([*FILES, THREAD_CONFIGURATOR])
    groups = read_as_the_tool_does(target.files[THREAD_CONFIGURATOR], cores=2)
    planned = plan(load_spec(robot), 2)
    sub = {node: planned.subchains[name] for name in planned.subchains for node in planned.subchains[name].nodes}

    def expected(node: str) -> dict[str, Any]:
        if sub[node].shared:
            return {"affinity": list(sub[node].cores), "policy": "SCHED_OTHER", "nice": 0, "priority": 0}
        return {"affinity": list(sub[node].cores), "policy": "SCHED_FIFO", "priority": 2}

    assert {key: value for key, value in groups["/camera@Timer(25000000)"].items() if key != "id"} == expected("cam")
    assert {k: v for k, v in groups["/detector@Subscription(/image)@Timer(1000000000)"].items() if k != "id"} == (
        expected("det")
    )
    assert {k: v for k, v in groups["/tracker@Subscription(/detections)@Waitable"].items() if k != "id"} == (
        expected("track")
    )
    # imu is on its own clock (200 Hz: 5 ms): every core, above the subchains
    assert groups["/imu@Timer(5000000)"] == {
        "id": "/imu@Timer(5000000)",
        "affinity": [0, 1],
        "policy": "SCHED_FIFO",
        "priority": 3,
    }
    assert len(groups) == 4
    assert {s.shared for s in planned.subchains.values()} == {True, False}  # both kinds really are covered


def test_nodes_outside_ros_are_non_ros_threads_under_their_dag_names(robot: Path) -> None:
    # track is no ROS node now (a process of its own), fus a scheduled node without a deploy entry;
    # motor, unscheduled without a rate, passes data on: no thread to place.
    robot.write_text(
        ROBOT.replace("  track: {compute_ms: 2}\n", "  track: {compute_ms: 2}\n  fus: {compute_ms: 1}\n")
        .replace("[track, motor]]", "[track, fus], [fus, motor]]")
        .replace("  track: [track]\n", "  track: [track, fus]\n")
        .replace("track, motor], weight", "track, fus, motor], weight")
        .replace(
            '  track: {ros_node: /tracker, callback_group: "/tracker@Subscription(/detections)@Waitable"}\n',
            "  track: {command: tracker --fast}\n",
        )
    )
    text = compile_spec(robot, 2).files[THREAD_CONFIGURATOR]
    threads = read_as_the_tool_does(text, cores=2, section="non_ros_threads")
    planned = plan(load_spec(robot), 2)
    (track,) = (sub for sub in planned.subchains.values() if "track" in sub.nodes)
    if track.shared:
        placed = {"affinity": list(track.cores), "policy": "SCHED_OTHER", "nice": 0, "priority": 0}
    else:
        placed = {"affinity": list(track.cores), "policy": "SCHED_FIFO", "priority": 2}
    assert threads == {"fus": {"id": "fus", **placed}, "track": {"id": "track", **placed}}
    assert len(read_as_the_tool_does(text, cores=2)) == 3  # the ROS nodes' groups as before


PROFILE = """format: catanc-machine/1
machine: {host: rig-7, cpu: "Intel(R) Xeon(R) Silver 4216 CPU @ 2.10GHz: #1", kernel: 6.8.0, cpus: 8}
switch_ms: 0.05
hop_ms: 0.06
overhead: [0.01, 0.01]
rt: {runtime_us: 950000, period_us: 1000000}
"""


@pytest.mark.parametrize(
    ("profile", "hardware", "throttling"),
    [
        (PROFILE, {"model_name": "Intel(R) Xeon(R) Silver 4216 CPU @ 2.10GHz: #1"}, (950000, 1000000)),
        (  # no CPU model measured: nothing for the configurator to compare
            PROFILE.replace(' cpu: "Intel(R) Xeon(R) Silver 4216 CPU @ 2.10GHz: #1",', "").replace(
                "runtime_us: 950000", "runtime_us: -1"
            ),
            None,
            (-1, 1000000),
        ),
    ],
)
def test_hardware_info_and_rt_throttling_come_from_the_machine_profile(
    robot: Path, profile: str, hardware: dict[str, str] | None, throttling: tuple[int, int]
) -> None:
    (robot.parent / "rig.yaml").write_text(profile)
    text = compile_spec(robot, 2, options=Options(machine=robot.parent / "rig.yaml")).files[THREAD_CONFIGURATOR]
    data = yaml.safe_load(text)
    assert data.get("hardware_info") == hardware
    runtime_us, period_us = throttling
    assert data["rt_throttling"] == {"sched_rt_runtime_us": runtime_us, "sched_rt_period_us": period_us}
    assert len(read_as_the_tool_does(text, cores=2)) == 4
    # Without a profile there is nothing measured to write.
    assert set(yaml.safe_load(compile_spec(robot, 2).files[THREAD_CONFIGURATOR])) == {"callback_groups"}


def test_nodes_sharing_a_callback_group_share_one_thread(robot: Path) -> None:
    robot.write_text(
        ROBOT.replace('"/detector@Subscription(/image)@Timer(1000000000)"', '"/perception@Subscription(/image)"')
        .replace('"/tracker@Subscription(/detections)@Waitable"', '"/perception@Subscription(/image)"')
        .replace("ros_node: /detector", "ros_node: /perception")
        .replace("ros_node: /tracker", "ros_node: /perception")
    )
    groups = read_as_the_tool_does(compile_spec(robot, 2).files[THREAD_CONFIGURATOR], cores=2)
    planned = plan(load_spec(robot), 2)
    det, track = (next(s for s in planned.subchains.values() if node in s.nodes) for node in ("det", "track"))
    merged = groups["/perception@Subscription(/image)"]
    assert merged["affinity"] == sorted({*det.cores, *track.cores})
    strongest = "SCHED_FIFO" if not (det.shared and track.shared) else "SCHED_OTHER"
    assert merged["policy"] == strongest
    assert len(groups) == 3


@pytest.mark.parametrize(
    ("rate_hz", "unit", "timer"),
    [
        (40, "hz", "25000000"),  # 1/40 s
        (40, "s", "25000000"),  # 0.025 s given as a period
        (40, "ms", "25000000"),
        (30, "hz", "33333333"),  # 1e9/30 = 33333333.3..., truncated as duration_cast does
        (30, "ms", "33333333"),  # the table's 33.333333 ms
    ],
)
def test_period_ns_is_the_timer_the_rate_parameter_makes(robot: Path, rate_hz: int, unit: str, timer: str) -> None:
    robot.write_text(
        ROBOT.replace("{node: cam, rate_hz: 40}", f"{{node: cam, rate_hz: {rate_hz}}}").replace(
            "rate_param: fps,", f"rate_param: fps, rate_unit: {unit},"
        )
    )
    groups = read_as_the_tool_does(compile_spec(robot, 2).files[THREAD_CONFIGURATOR], cores=2)
    assert f"/camera@Timer({timer})" in groups


def test_no_callback_groups_no_file(robot: Path) -> None:
    robot.write_text(
        "\n".join(
            line.split(", callback_group")[0] + "}" if "callback_group" in line else line for line in ROBOT.splitlines()
        )
        + "\n"
    )
    assert sorted(compile_spec(robot, 2).files) == sorted(FILES)


def test_check_covers_the_file_and_a_spec_that_drops_it_replaces_the_folder(robot: Path) -> None:
    assert runner.invoke(app, ["compile", "robot.yaml", "-k", "2"]).exit_code == ExitCode.OK
    folder = Path("out/robot/cores-2")
    written = folder / THREAD_CONFIGURATOR
    first = written.read_bytes()
    assert runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check"]).exit_code == ExitCode.OK
    written.write_text(first.decode().replace("priority: 3", "priority: 9"))
    stale = runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check"])
    assert stale.exit_code == ExitCode.DRIFT
    assert f"stale: changed {THREAD_CONFIGURATOR}" in stale.stdout
    assert runner.invoke(app, ["compile", "robot.yaml", "-k", "2"]).exit_code == ExitCode.OK
    assert written.read_bytes() == first  # same spec, same bytes
    robot.write_text(ROBOT.split("deploy:", maxsplit=1)[0])
    dropped = runner.invoke(app, ["compile", "robot.yaml", "-k", "2", "--check"])
    assert dropped.exit_code == ExitCode.DRIFT
    assert f"extra {THREAD_CONFIGURATOR}" in dropped.stdout
    rewritten = runner.invoke(app, ["compile", "robot.yaml", "-k", "2"])
    assert rewritten.exit_code == ExitCode.OK, rewritten.output  # catanc's own file, not a user's
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ('callback_group: "camera@Timer(1)"', "is not a callback group ID"),
        ('callback_group: "/camera"', "is not a callback group ID"),
        ('callback_group: "/camera@Timer(1.5)"', "'Timer(1.5)' is not a callback"),
        ('callback_group: "/camera@Subscription(image)"', "'Subscription(image)' is not a callback"),
        ('callback_group: "/other@Timer(1)"', "the callback group is /other's, but ros_node is /camera"),
        ('callback_group: "/camera@Agnocast(/image)"', "'Agnocast(/image)' is not a callback"),
        # Autoware's tool writes Subscriptions, Services, Clients, Timers (collect_all_ptrs), then Agnocast's
        (
            'callback_group: "/camera@Timer({period_ns})@Subscription(/image)"',
            "did you mean '/camera@Subscription(/image)@Timer({period_ns})'?",
        ),
        (
            'callback_group: "/camera@Client(/b)@Subscription(/x)@Service(/a)@Subscription(/y)"',
            "did you mean '/camera@Subscription(/x)@Subscription(/y)@Service(/a)@Client(/b)'?",
        ),
        (
            'callback_group: "/camera@AgnocastSubscription(/image)@Timer(5)@Waitable"',
            "did you mean '/camera@Timer(5)@AgnocastSubscription(/image)@Waitable'?",
        ),
        ('callback_group: "/camera@Waitable@Timer(5)"', "did you mean '/camera@Timer(5)@Waitable'?"),
    ],
)
def test_bad_callback_group_ids_are_spec_errors(robot: Path, entry: str, message: str) -> None:
    robot.write_text(ROBOT.replace('callback_group: "/camera@Timer({period_ns})"', entry))
    with pytest.raises(SpecError) as caught:
        load_spec(robot)
    (diagnostic,) = caught.value.diagnostics
    assert diagnostic.field == "deploy.cam.callback_group"
    assert message in diagnostic.message
    assert diagnostic.location is not None
    assert (
        diagnostic.location.line
        == ROBOT.splitlines().index(next(line for line in ROBOT.splitlines() if line.startswith("  cam: {ros_node")))
        + 1
    )


CALLBACKS = [
    "Subscription(/scan)",
    "Subscription(/odom)",
    "Service(/reset)",
    "Client(/map)",
    "Timer(5000000)",
    "Timer(1000000000)",
    "AgnocastSubscription(/points)",
    "AgnocastService(/AGNOCAST_SRV_REQUEST/get)",
    "AgnocastClient(/AGNOCAST_SRV_RESPONSE/get_SEP_mapper)",
]


def tool_order(callbacks: list[str]) -> list[str]:
    """The order Autoware's create_callback_group_id writes a group's callbacks in: collect_all_ptrs visits
    subscriptions, services, clients, timers (each kind in the group's own order), Agnocast's follow."""
    kinds = ("Subscription(", "Service(", "Client(", "Timer(", "Agnocast")
    return [callback for kind in kinds for callback in callbacks if callback.startswith(kind)]


@settings(deadline=None)  # loading a spec is not what is timed here
@given(st.lists(st.sampled_from(CALLBACKS), min_size=1, max_size=6, unique=True))
def test_an_id_passes_exactly_when_its_callbacks_are_in_the_tools_order(callbacks: list[str]) -> None:
    spec_text = ROBOT.replace(
        '"/detector@Subscription(/image)@Timer(1000000000)"', f'"/detector@{"@".join(callbacks)}"'
    )
    expected = tool_order(callbacks)
    if callbacks == expected:
        parse_spec(spec_text, "robot.yaml")
        return
    with pytest.raises(SpecError) as caught:
        parse_spec(spec_text, "robot.yaml")
    (diagnostic,) = caught.value.diagnostics
    assert diagnostic.field == "deploy.det.callback_group"
    assert f"did you mean '/detector@{'@'.join(expected)}'?" in diagnostic.message


def test_agnocast_callbacks_are_accepted(robot: Path) -> None:
    group = (
        "/detector@Subscription(/image)@AgnocastSubscription(/points)@AgnocastClient(/AGNOCAST_SRV_RESPONSE/a_SEP_b)"
    )
    robot.write_text(ROBOT.replace('"/detector@Subscription(/image)@Timer(1000000000)"', f'"{group}"'))
    assert group in read_as_the_tool_does(compile_spec(robot, 2).files[THREAD_CONFIGURATOR], cores=2)


# --------------------------------------------------------------------------- the timer, against C++


CHRONO = r"""
#include <chrono>
#include <cstdio>
using std::chrono::duration;
using std::chrono::duration_cast;
using std::chrono::nanoseconds;
int main() {
  char unit[8];
  double value;
  while (std::scanf("%7s %lf", unit, &value) == 2) {
    nanoseconds ns;
    if (unit[0] == 'h') ns = duration_cast<nanoseconds>(duration<double>(1.0 / value));  // a rate in hertz
    else if (unit[0] == 's') ns = duration_cast<nanoseconds>(duration<double>(value));
    else ns = duration_cast<nanoseconds>(duration<double, std::milli>(value));
    std::printf("%lld\n", static_cast<long long>(ns.count()));
  }
}
"""


@pytest.fixture(scope="module")
def chrono(tmp_path_factory: pytest.TempPathFactory) -> Path:
    compiler = shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    if compiler is None:
        pytest.skip("no C++ compiler")
    folder = tmp_path_factory.mktemp("chrono")
    (folder / "chrono.cpp").write_text(CHRONO)
    subprocess.run(
        [compiler, "-std=c++17", "-O0", "-o", str(folder / "chrono"), str(folder / "chrono.cpp")],
        check=True,
        capture_output=True,
        timeout=120,
    )
    return folder / "chrono"


VALUES = st.floats(min_value=1e-3, max_value=1e4, allow_nan=False, allow_infinity=False)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["hz", "s", "ms"]), VALUES), min_size=50, max_size=200))
def test_timer_ns_is_what_std_chrono_makes_of_the_parameter(chrono: Path, cases: list[tuple[str, float]]) -> None:
    rounded = [(unit, float(f"{value:.6f}")) for unit, value in cases]  # params.yaml's fixed precision
    text = "".join(f"{unit} {value!r}\n" for unit, value in rounded if value > 0)
    done = subprocess.run([str(chrono)], input=text, capture_output=True, text=True, check=True, timeout=30)
    expected = [int(line) for line in done.stdout.split()]
    got = [timer_ns(value, unit) for unit, value in rounded if value > 0]
    assert got == expected
