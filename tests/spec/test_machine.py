"""The machine profile (catanc.spec.machine): its format, its bad inputs, and the costs a plan takes from it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from catanc.artifacts.output import replace_file
from catanc.cli import app
from catanc.errors import ExitCode
from catanc.model.load import load_spec
from catanc.planning.planner import plan
from catanc.spec.language import Schedule
from catanc.spec.machine import (
    MACHINE_FORMAT,
    MachineFile,
    MachineProfile,
    ProfileError,
    apply_machine,
    costs,
    profile_text,
    read_machine,
)

GOOD = """format: catanc-machine/1
machine: {host: rig-7, cpu: "Intel i7-8650U", kernel: 6.8.0-45-generic, cpus: 8}
switch_ms: 0.2
hop_ms: 0.45
overhead: [0.011, 0.03]
rt: {runtime_us: 950000, period_us: 1000000}
wake_ms: 0.2
"""


def profile_file(tmp_path: Path, text: str = GOOD, name: str = "rig.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_costs_by_hand(tmp_path: Path) -> None:
    profile = read_machine(profile_file(tmp_path)).profile
    # A slot pays its head's hop beyond the enforcer's CPU: 0.45 - 0.2 = 0.25 > the spec's 0.12
    # (the 0.2 ms switch latency is not charged); 1 - 0.95 + max(0.011, 0.03) = 0.08 > 0.05.
    found = costs(Schedule(), profile)
    assert found.switch_ms == pytest.approx(0.25)
    assert found.slack == pytest.approx(0.08)
    # Never below the spec's values.
    generous = costs(Schedule(switch_ms=0.5, slack=0.2), profile)
    assert (generous.switch_ms, generous.slack) == (0.5, 0.2)
    assert generous.measured_switch_ms == pytest.approx(0.25)
    # An unthrottled kernel leaves the enforcer's overhead only.
    unlimited = profile.model_copy(update={"rt": profile.rt.model_copy(update={"runtime_us": -1})})
    assert costs(Schedule(slack=0.0), unlimited).slack == pytest.approx(0.03)
    # A profile without wake_ms (written before it was measured) charges the whole hop.
    old = read_machine(profile_file(tmp_path, GOOD.replace("wake_ms: 0.2\n", ""), "old.yaml")).profile
    assert old.wake_ms == 0.0
    assert costs(Schedule(), old).switch_ms == pytest.approx(0.45)
    # A wake-up dearer than the hop (the loop on another core than the heads) charges nothing, never less.
    assert costs(Schedule(switch_ms=0.0), profile.model_copy(update={"wake_ms": 0.9})).switch_ms == 0.0


def test_vr_on_one_core_keeps_render_at_vsync_with_this_vms_costs() -> None:
    # What `catanc run` measured of itself running VR on one core of this VM (docs/results.md
    # section 4): switch p95 0.336 ms, hop p95 0.505 ms, 0.236 ms of its own CPU per wake-up,
    # 11.4% of the core; RT limit 95%.  Timewarp at vsync locks T = 8.333 ms.
    # Counted once: slack 1 - 0.95 + 0.114 = 0.164, per slot 0.505 - 0.236 = 0.269 ms, so
    # (1 - 0.164) * 8.333 - 3 * 0.269 = 6.16 ms hold Timewarp 1.5 + Render 3 + VIO's least slice
    # 1 ms = 5.5 ms: Render runs every period (120 Hz), as the kernel ran it.  Charging the switch
    # and the whole hop besides the overhead (3 * 0.841 ms) left 4.45 ms: not even Timewarp and
    # Render (4.5 ms), so Render fell to every other period.
    spec = load_spec("specs/vr_illixr.yaml")
    profile = MachineProfile.model_validate(
        {
            "format": "catanc-machine/1",
            "machine": {"host": "vm"},
            "switch_ms": 0.336,
            "hop_ms": 0.505,
            "wake_ms": 0.236,
            "overhead": [0.114],
            "rt": {"runtime_us": 950000, "period_us": 1000000},
        }
    )
    measured, use = apply_machine(spec, MachineFile(profile, "vm.yaml", "0" * 64))
    assert use.costs.switch_ms == pytest.approx(0.269)
    assert use.costs.slack == pytest.approx(0.164)
    planned = plan(measured, 1)
    assert planned.shared_cores[0].period_ms == pytest.approx(1000.0 / 120.0, rel=1e-6)
    assert planned.subchains["render"].period_ms == pytest.approx(1000.0 / 120.0, rel=1e-6)
    assert planned.subchains["timewarp"].period_ms == pytest.approx(1000.0 / 120.0, rel=1e-6)


def test_write_then_read_round_trips_with_the_same_bytes(tmp_path: Path) -> None:
    profile = read_machine(profile_file(tmp_path)).profile
    target = tmp_path / "again.yaml"
    replace_file(target, profile_text(profile))  # as `catanc calibrate` writes it
    assert read_machine(target).profile == profile
    first = target.read_bytes()
    replace_file(target, profile_text(profile))
    assert target.read_bytes() == first
    assert first.decode().splitlines()[1] == f"format: {MACHINE_FORMAT}"


BAD = [
    # (case, text, line, field, fragment)
    ("other format", GOOD.replace("machine/1", "machine/2"), 1, "format", "not format 'catanc-machine/2'"),
    ("no format", GOOD.replace("format: catanc-machine/1\n", ""), 1, "", "not no format"),
    ("negative switch", GOOD.replace("switch_ms: 0.2", "switch_ms: -0.2"), 3, "switch_ms", "must be >= 0"),
    ("negative hop", GOOD.replace("hop_ms: 0.45", "hop_ms: -1"), 4, "hop_ms", "must be >= 0"),
    ("negative wake", GOOD.replace("wake_ms: 0.2", "wake_ms: -1"), 7, "wake_ms", "must be >= 0"),
    ("overhead of a whole core", GOOD.replace("0.03]", "1.0]"), 5, "overhead[1]", "in [0, 1), got 1"),
    ("negative overhead", GOOD.replace("[0.011", "[-0.1"), 5, "overhead[0]", "in [0, 1), got -0.1"),
    ("RT limit above 1", GOOD.replace("950000", "1200000"), 6, "rt.runtime_us", "must be in (0, 1]"),
    ("RT limit 0", GOOD.replace("950000", "0"), 6, "rt.runtime_us", "must be in (0, 1]"),
    ("RT period 0", GOOD.replace("period_us: 1000000", "period_us: 0"), 6, "rt.period_us", "must be > 0"),
    ("unknown field", GOOD + "speed: 3\n", 8, "speed", "unknown field 'speed'"),
    ("missing field", GOOD.replace("hop_ms: 0.45\n", ""), 1, "hop_ms", "missing required field 'hop_ms'"),
    ("a string for a number", GOOD.replace("0.2", "fast"), 3, "switch_ms", "got 'fast'"),
    ("YAML syntax", GOOD.replace("cpus: 8}", "cpus: 8"), 2, "", "not closed"),
    ("not a mapping", "- 1\n- 2\n", 1, "", "a machine profile is a mapping"),
]


@pytest.mark.parametrize("bad", BAD, ids=[case[0] for case in BAD])
def test_bad_profiles_name_file_line_and_field(tmp_path: Path, bad: tuple[str, str, int, str, str]) -> None:
    case, text, line, field, fragment = bad
    path = profile_file(tmp_path, text)
    with pytest.raises(ProfileError) as caught:
        read_machine(path)
    diagnostic = caught.value.diagnostics[0]
    assert diagnostic.location is not None, case
    assert (diagnostic.location.file, diagnostic.location.line) == (str(path), line), str(diagnostic)
    assert diagnostic.field == field, str(diagnostic)
    assert fragment in diagnostic.message, str(diagnostic)


def test_missing_unreadable_and_binary_profiles(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match=r"nothing\.yaml: cannot read machine profile: No such file"):
        read_machine(tmp_path / "nothing.yaml")
    with pytest.raises(ProfileError, match="cannot read machine profile: a folder"):
        read_machine(tmp_path)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"format: \xff\xfe\n")
    with pytest.raises(ProfileError, match="not UTF-8"):
        read_machine(binary)
    later = tmp_path / "later.yaml"
    later.write_bytes(b"format: catanc-machine/1\nhost: ab\xffc\n")  # the bad byte: line 2, column 9
    with pytest.raises(ProfileError) as caught:
        read_machine(later)
    assert str(caught.value).startswith(f"{later}:2:9: ")


def test_an_overhead_that_takes_the_whole_rt_limit_cannot_be_planned(tmp_path: Path) -> None:
    path = profile_file(tmp_path, GOOD.replace("runtime_us: 950000", "runtime_us: 20000"))  # 2% for FIFO
    with pytest.raises(ProfileError) as caught:
        apply_machine(load_spec("specs/nav2d.yaml"), read_machine(path))
    assert str(caught.value).startswith(f"{path}:5:")
    assert "overhead[1]" in str(caught.value)
    assert "takes the whole RT limit" in str(caught.value)


@pytest.mark.parametrize("command", ["compile", "explain"])
@pytest.mark.parametrize(
    "text", [None, GOOD.replace("catanc-machine/1", "catanc-machine/9"), GOOD.replace("0.2", "-1")]
)
def test_cli_bad_profile_exit_2_and_nothing_written(tmp_path: Path, command: str, text: str | None) -> None:
    profile = tmp_path / "missing.yaml" if text is None else profile_file(tmp_path, text)
    out = tmp_path / "out"
    args = [command, "specs/nav2d.yaml", "--cores", "1", "--machine", str(profile)]
    result = CliRunner().invoke(app, args + (["--out", str(out)] if command == "compile" else []))
    assert result.exit_code == ExitCode.BAD_INPUT, result.output
    assert str(profile) in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_compile_with_a_profile_records_it_and_plans_with_its_costs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    profile_file(tmp_path)
    monkeypatch.chdir(tmp_path)
    # nav2d, not VR: VR's period is locked to vsync (8.333 ms / k) whatever the costs.
    spec = Path(__file__).parents[2] / "specs" / "nav2d.yaml"
    runner = CliRunner()
    for folder, extra in (("plain", []), ("measured", ["--machine", "rig.yaml"])):
        result = runner.invoke(app, ["compile", str(spec), "--cores", "1", "--out", folder, *extra])
        assert result.exit_code == 0, result.output
    plain = json.loads((tmp_path / "plain" / "runtime.json").read_text())
    table = json.loads((tmp_path / "measured" / "runtime.json").read_text())
    assert "machine" not in plain
    record = table["machine"]
    assert record["profile"] == "rig.yaml"  # the name only: no absolute path
    assert record["measured_on"] == "rig-7"
    assert record["switch_ms"]["used"] == pytest.approx(0.25)
    assert record["slack"]["used"] == pytest.approx(0.08)
    # The table's spec is what was planned: the enforcer re-solves with the raised costs.
    assert table["spec"]["schedule"]["switch_ms"] == pytest.approx(0.25)
    assert table["spec"]["schedule"]["slack"] == pytest.approx(0.08)
    assert table["generated_by"]["command"].endswith("--machine rig.yaml")
    # Dearer switches and more slack leave less of the core: the shared schedule's period grows.
    assert table["plan"]["cores"][0]["period_ms"] > plain["plan"]["cores"][0]["period_ms"]
    plan_md = (tmp_path / "measured" / "PLAN.md").read_text()
    assert "Machine profile rig.yaml (measured on rig-7" in plan_md
    assert str(tmp_path) not in plan_md + json.dumps(table)
    # Same inputs, same bytes.
    again = runner.invoke(app, ["compile", str(spec), "--cores", "1", "--out", "measured", "--machine", "rig.yaml"])
    assert again.exit_code == 0
    assert "up to date" in again.output
