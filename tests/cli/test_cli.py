"""The command line: exit codes, messages, and that it stays a thin shell."""

from __future__ import annotations

import itertools
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from catanc.cli import app
from catanc.cli.main import COMMANDS
from catanc.errors import ExitCode

ROOT = Path(__file__).parents[2]
runner = CliRunner()

GOOD = """catan: 1
app: demo
nodes:
  cam: {compute_ms: 5}
  det: {compute_ms: 20}
  odom: {scheduled: false, rate_hz: 50}
  motor: {scheduled: false}
edges: [[cam, det], [odom, det], [det, motor]]
subchains:
  main: [cam, det]
objective:
  - {chain: [cam, det, motor], weight: 1.0}
constraints:
  - {chains: {from: odom}, max_response_ms: 100}
"""


@pytest.fixture
def good(tmp_path: Path) -> Path:
    path = tmp_path / "good.yaml"
    path.write_text(GOOD)
    return path


def test_validate_ok(good: Path) -> None:
    result = runner.invoke(app, ["validate", str(good)])
    assert result.exit_code == ExitCode.OK, result.output
    assert f"{good}: ok: app demo, 4 nodes, 1 subchain, 2 chains" in result.stdout


def test_validate_reports_every_file(good: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("[cam, det], [odom", "[cam, dett], [odom"))
    result = runner.invoke(app, ["validate", str(bad), str(good)])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert f"{bad}:8:15: edges[0][1]: unknown node 'dett' (did you mean 'det'?)" in result.stderr
    assert f"{good}: ok" in result.stdout
    assert "Traceback" not in result.output


def test_chains_table_and_json(good: Path) -> None:
    result = runner.invoke(app, ["chains", str(good)])
    assert result.exit_code == ExitCode.OK, result.output
    assert "objective[0] w=1" in result.stdout
    result = runner.invoke(app, ["chains", str(good), "--json"])
    payload = json.loads(result.stdout)
    rows = {tuple(row["nodes"]): row for row in payload["chains"]}
    assert payload["total_source_to_sink"] == 2
    assert rows[("cam", "det", "motor")]["subchains"] == ["main"]
    assert rows[("odom", "det", "motor")]["subchains"] == ["odom@50Hz", "main"]
    assert rows[("odom", "det", "motor")]["used_by"] == ["constraints[0] R<=100ms"]


def test_chains_warns_about_dense_dags(tmp_path: Path) -> None:
    layers = [[f"l{i}x{j}" for j in range(3)] for i in range(12)]
    names = [n for layer in layers for n in layer]
    nodes = "\n".join(f"  {n}: {{compute_ms: 1}}" for n in names)
    edges = ", ".join(f"[{a}, {b}]" for up, low in itertools.pairwise(layers) for a in up for b in low)
    subchains = "\n".join(f"  s_{n}: [{n}]" for n in names)
    path = tmp_path / "dense.yaml"
    path.write_text(f"catan: 1\napp: dense\nnodes:\n{nodes}\nedges: [{edges}]\nsubchains:\n{subchains}\n")
    result = runner.invoke(app, ["chains", str(path), "--limit", "10", "--json"])
    assert result.exit_code == ExitCode.OK, result.output
    assert "531,441 source-to-sink paths; listing the first 10" in result.stderr  # 3**12
    assert len(json.loads(result.stdout)["chains"]) == 10


def test_schema_is_json_schema_of_the_spec() -> None:
    result = runner.invoke(app, ["schema"])
    schema = json.loads(result.stdout)
    assert schema["additionalProperties"] is False
    assert set(schema["required"]) == {"catan", "app", "nodes"}
    assert "from" in json.dumps(schema["$defs"]["ChainSelector"])


def test_committed_schema_is_current() -> None:
    committed = (ROOT / "specs" / "catanc.schema.json").read_text()
    assert committed == runner.invoke(app, ["schema"]).stdout, "regenerate: catanc schema > specs/catanc.schema.json"


def test_messages_show_the_users_text_as_it_is(tmp_path: Path) -> None:
    # rich would print ':smile:' as an emoji and a tab as spaces; a file's name is the user's own text.
    good = tmp_path / "a:smile:\tb.yaml"
    good.write_text(GOOD)
    bad = tmp_path / "c:smile:.yaml"
    bad.write_text(GOOD.replace("[cam, det], [odom", "[cam, dett], [odom"))
    result = runner.invoke(app, ["validate", str(good), str(bad)])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert result.stdout.startswith(f"{good}: ok: app demo")
    assert result.stderr.startswith(f"{bad}:8:15: edges[0][1]: unknown node 'dett'")


def test_missing_file_is_a_bad_input(tmp_path: Path) -> None:
    result = runner.invoke(app, ["validate", str(tmp_path / "nope.yaml")])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "cannot read spec" in result.stderr


def test_bugs_get_their_own_exit_code(good: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import catanc.model.load

    def broken(path: object) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(catanc.model.load, "read_spec", broken)
    monkeypatch.delenv("CATANC_DEBUG", raising=False)
    result = runner.invoke(app, ["chains", str(good)])
    assert result.exit_code == ExitCode.INTERNAL
    assert "internal error: RuntimeError: boom" in result.stderr
    assert "Traceback" not in result.output


def test_help_lists_every_command_in_order() -> None:
    # The commands are built when looked up; --help looks up each, in COMMANDS' order.
    result = runner.invoke(app, ["--help"], env={"COLUMNS": "200"})
    assert result.exit_code == ExitCode.OK, result.output
    listed = re.findall(r"^[│|] ([a-z][a-z-]*) {2,}\S", result.stdout, re.MULTILINE)
    assert listed == list(COMMANDS)
    for name in COMMANDS:
        assert runner.invoke(app, [name, "--help"]).exit_code == ExitCode.OK, name


def test_a_misspelt_command_gets_suggestions() -> None:
    result = runner.invoke(app, ["compil", "specs/nav2d.yaml"])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "No such command 'compil'. Did you mean 'compile'?" in result.output


def test_the_spec_reference_documents_every_exit_code() -> None:
    reference = (ROOT / "docs" / "reference" / "spec.md").read_text()
    for code in ExitCode:
        assert re.search(rf"^\|\s*{code.value}\s*\|\s*`{code.name}`", reference, re.MULTILINE), code


def test_python_m_catanc_runs_without_heavy_imports(good: Path) -> None:
    # validate never solves (cvxpy, pulp), prints plain lines (no rich), and loads no other command's module
    # (issue 33: at most 0.5 s).
    others = sorted(f"catanc.cli.{module}" for module, _ in COMMANDS.values() if module not in ("spec", "main"))
    code = (
        "import sys; from catanc.cli import app\n"
        "try:\n"
        f"    app(['validate', {str(good)!r}])\n"
        "except SystemExit as exit:\n"
        "    assert exit.code == 0, exit.code\n"
        f"heavy = sorted(m for m in ('cvxpy', 'pulp', 'numpy', 'jinja2', 'rich', *{others!r}) if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
    result = subprocess.run(
        [sys.executable, "-m", "catanc", "validate", str(good)], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stderr


def test_allocate_json_and_errors() -> None:
    nav2d = str(ROOT / "specs" / "nav2d.yaml")
    result = runner.invoke(app, ["allocate", nav2d, "--cores", "2", "--json"])
    assert result.exit_code == ExitCode.OK, result.output
    payload = json.loads(result.stdout)
    assert payload["optimal"] is True
    assert payload["cores_used"] == 2
    assert set(payload["subchains"]) == {"local", "GL", "GM", "GP", "NC"}
    assert all(row["cores"][0] in (0, 1) for row in payload["subchains"].values())
    table = runner.invoke(app, ["allocate", nav2d, "-k", "2", "--stage1", "milp", "--solver", "cbc"])
    assert table.exit_code == ExitCode.OK, table.output
    assert "optimal, by milp/cbc" in table.stdout
    bad = runner.invoke(app, ["allocate", nav2d, "-k", "2", "--stage1", "greedy"])
    assert bad.exit_code == ExitCode.BAD_INPUT
    assert "unknown Stage I method 'greedy'" in bad.stderr
    assert runner.invoke(app, ["allocate", nav2d, "-k", "0"]).exit_code == ExitCode.BAD_INPUT


def test_compile_reads_checks_and_builds_each_spec_once(
    good: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One spec for two core counts: one read, one pass of each kind, one problem (issue 33: parse once).
    import catanc.model.build
    import catanc.model.load
    import catanc.spec.parse

    calls: dict[str, int] = {}

    def counting(module: object, name: str) -> None:
        real = getattr(module, name)

        def wrapper(*args: object, **kwargs: object) -> object:
            calls[name] = calls.get(name, 0) + 1
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, wrapper)

    counting(catanc.spec.parse, "parse_yaml")
    counting(catanc.spec.parse, "validate_data")
    counting(catanc.model.load, "read_spec_text")
    counting(catanc.model.build._Builder, "build")  # whoever builds a problem, wherever from
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["compile", "--dry-run", str(good), "-k", "1", "-k", "2"])
    assert result.exit_code == 0, result.output
    assert calls == {"read_spec_text": 1, "parse_yaml": 1, "validate_data": 1, "build": 1}


@pytest.mark.parametrize(
    ("missing", "command", "extra"),
    [
        ("numba", ["simulate", "{spec}", "-k", "1", "--duration", "1"], "sim"),
        ("matplotlib", ["simulate", "{spec}", "-k", "1", "--duration", "1", "--plot", "{tmp}"], "plot"),
        ("matplotlib", ["report", "{tmp}/run.jsonl", "--plot", "{tmp}/t.png"], "plot"),
    ],
)
def test_a_missing_extra_is_one_line_naming_the_fix(
    good: Path, tmp_path: Path, missing: str, command: list[str], extra: str
) -> None:
    # The module is made unimportable in a fresh interpreter, as if its extra were not installed.
    (tmp_path / "run.jsonl").write_text("")
    argv = [word.format(spec=good, tmp=tmp_path) for word in command]
    code = (
        f"import sys; sys.modules[{missing!r}] = None; sys.argv = ['catanc', *{argv!r}]\n"
        "from catanc.cli import main; main()"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == ExitCode.BAD_INPUT, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"catanc: catanc {argv[0]}{' --plot' if missing == 'matplotlib' else ''} needs {missing}, which is not "
        f"installed: pip install 'catanc[{extra}]'"
    ]
    assert not list(tmp_path.glob("*.png"))


# A profile whose measured costs are over nav2d's (0.12 ms a switch, 5% slack): a hop of 1.2 ms beyond a
# 0.2 ms wake-up gives switch_ms 1.0, and 1 - 0.95 (the RT limit) + 0.10 (the enforcer's overhead) slack 0.15.
SLOW_MACHINE = """format: catanc-machine/1
machine: {host: slow-rig}
switch_ms: 0.3
hop_ms: 1.2
wake_ms: 0.2
overhead: [0.10, 0.0]
rt: {runtime_us: 950000, period_us: 1000000}
"""


@pytest.mark.slow
def test_simulate_on_a_machine_profile_simulates_the_spec_with_its_costs_raised(tmp_path: Path) -> None:
    # The oracle: the same spec with the two costs worked out above written into its schedule by hand.
    machine = tmp_path / "slow.yaml"
    machine.write_text(SLOW_MACHINE)
    by_hand = tmp_path / "nav2d-slow.yaml"
    by_hand.write_text((ROOT / "specs" / "nav2d.yaml").read_text() + "\nschedule: {switch_ms: 1.0, slack: 0.15}\n")
    args = ["-k", "1", "--duration", "3", "--policy", "catan", "--json", "--quiet"]

    def simulated(*words: str) -> dict[str, object]:
        result = runner.invoke(app, ["simulate", *words, *args])
        assert result.exit_code == 0, result.output
        payload: dict[str, object] = json.loads(result.stdout)
        return payload

    profiled = simulated(str(ROOT / "specs" / "nav2d.yaml"), "--machine", str(machine))
    assert profiled == simulated(str(by_hand))
    assert profiled != simulated(str(ROOT / "specs" / "nav2d.yaml"))  # the costs changed the plan


def test_simulate_names_a_bad_machine_profile_and_its_field(tmp_path: Path) -> None:
    machine = tmp_path / "slow.yaml"
    machine.write_text(SLOW_MACHINE.replace("hop_ms: 1.2", "hop_ms: fast"))
    result = runner.invoke(app, ["simulate", str(ROOT / "specs" / "nav2d.yaml"), "-k", "1", "--machine", str(machine)])
    assert result.exit_code == ExitCode.BAD_INPUT
    assert "slow.yaml:4" in result.stderr
    assert "hop_ms" in result.stderr
