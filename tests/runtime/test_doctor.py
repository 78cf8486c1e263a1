"""``catanc doctor``: the checks worked by hand, then the command on the real kernel.

The real-kernel tests run ``catanc doctor`` in a child that lacks something for real: run as
``nobody`` with a lowered RLIMIT_RTPRIO (``setpriv`` and ``prlimit``, as tests/runtime/test_sched.py),
pinned to one CPU with ``taskset``, or moved into a cgroup v1 cpu group whose real-time budget
is 0.  Each verdict is checked against the kernel itself (a plain SCHED_FIFO probe in the same
situation), never against catanc's own checks.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from catanc.artifacts.runtime_table import load_table
from catanc.doctor import (
    ENFORCER_ONLY,
    CgroupBudget,
    Machine,
    Needs,
    RtBudget,
    Verdict,
    diagnose,
    find_cpu_cgroup,
    needs_of,
    parse_cpu_list,
    render,
)
from catanc.errors import ExitCode
from catanc.runtime.compiled.ready import LoopState
from catanc.runtime.linux.sched import format_cpus
from tests.support.linux import as_user, missing_tools, nobody_ids, require_fifo

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "out" / "nav2d" / "cores-2" / "runtime.json"
WAIT_S = 60.0

NEEDS = Needs(fifo_priority=4, cores=2, cpus=frozenset({0, 1}), rt_share=0.95, dedicated=())
GOOD = Machine(
    euid=0,
    cap_sys_nice=True,
    rtprio=0,
    fifo_refused=None,
    global_rt=RtBudget(950_000, 1_000_000),
    cgroup=CgroupBudget(Path("/sys/fs/cgroup/cpu"), "/", RtBudget(950_000, 1_000_000)),
    allowed_cpus=frozenset({0, 1}),
    online_cpus=frozenset({0, 1}),
    isolated_cpus=frozenset(),
    missing_tools=(),
    loop=LoopState.READY,
)
USER = replace(GOOD, euid=1000, cap_sys_nice=False)


def verdicts(needs: Needs, machine: Machine) -> dict[str, Verdict]:
    return {finding.check: finding.verdict for finding in diagnose(needs, machine)}


def finding(needs: Needs, machine: Machine, check: str) -> tuple[Verdict, str, str]:
    (found,) = (f for f in diagnose(needs, machine) if f.check == check)
    return found.verdict, found.found, found.fix


# --------------------------------------------------------------------------- the checks, by hand


def test_a_machine_with_everything_passes_every_check() -> None:
    assert set(verdicts(NEEDS, GOOD).values()) == {Verdict.OK}
    assert render(diagnose(NEEDS, GOOD), "t").endswith("this machine can run the plan\n")


@pytest.mark.parametrize(
    ("machine", "verdict"),
    [
        (GOOD, Verdict.OK),  # root
        (replace(USER, cap_sys_nice=True), Verdict.OK),
        (replace(USER, rtprio=4), Verdict.OK),  # exactly the enforcer's priority
        (replace(USER, rtprio=resource.RLIM_INFINITY), Verdict.OK),
        (replace(USER, rtprio=3), Verdict.FAIL),  # one short
        (replace(USER, rtprio=0), Verdict.FAIL),
        (replace(USER, cap_sys_nice=None), Verdict.FAIL),  # unknown is not granted
    ],
)
def test_privilege_is_root_or_cap_sys_nice_or_an_rtprio_limit_reaching_the_priority(
    machine: Machine, verdict: Verdict
) -> None:
    assert finding(NEEDS, machine, "privilege")[0] is verdict


def test_a_missing_privilege_names_the_facts_and_every_fix() -> None:
    verdict, found, fix = finding(NEEDS, replace(USER, rtprio=3), "privilege")
    assert verdict is Verdict.FAIL
    assert "not root (euid 1000), no CAP_SYS_NICE, and RLIMIT_RTPRIO is 3" in found
    assert "SCHED_FIFO 4" in found
    for way in ("sudo", "CAP_SYS_NICE", "rtprio 4", "--no-rt"):
        assert way in fix


def test_the_priority_needed_is_the_highest_of_the_plan() -> None:
    needs = replace(NEEDS, fifo_priority=9)
    assert finding(needs, replace(USER, rtprio=8), "privilege")[0] is Verdict.FAIL
    assert finding(needs, replace(USER, rtprio=9), "privilege")[0] is Verdict.OK


def test_a_refused_probe_fails_with_the_kernels_reason() -> None:
    verdict, found, _ = finding(NEEDS, replace(GOOD, fifo_refused="Operation not permitted"), "SCHED_FIFO")
    assert verdict is Verdict.FAIL
    assert "Operation not permitted" in found


@pytest.mark.parametrize(
    ("runtime_us", "dedicated", "verdict"),
    [
        (-1, ("local",), Verdict.OK),  # no throttling at all
        (1_000_000, ("local",), Verdict.OK),  # the whole period
        (950_000, (), Verdict.OK),  # shared cores keep 95% (slack 0.05): it fits exactly
        (950_000, ("local",), Verdict.WARN),  # a dedicated core loses 5% when it is busy
        (949_999, (), Verdict.FAIL),  # less than the shared cores keep
        (0, (), Verdict.FAIL),
    ],
)
def test_the_real_time_budget_against_what_the_plan_keeps(
    runtime_us: int, dedicated: tuple[str, ...], verdict: Verdict
) -> None:
    needs = replace(NEEDS, dedicated=dedicated)
    machine = replace(GOOD, global_rt=RtBudget(runtime_us, 1_000_000))
    assert finding(needs, machine, "sched_rt_runtime_us")[0] is verdict
    in_a_group = CgroupBudget(Path("/sys/fs/cgroup/cpu/app"), "/app", RtBudget(runtime_us, 1_000_000))
    assert finding(needs, replace(GOOD, cgroup=in_a_group), "cgroup")[0] is verdict


def test_a_cgroup_without_a_budget_says_where_to_give_it_one() -> None:
    group = CgroupBudget(Path("/sys/fs/cgroup/cpu/docker/abc"), "/docker/abc", RtBudget(0, 1_000_000))
    verdict, found, fix = finding(NEEDS, replace(GOOD, cgroup=group), "cgroup")
    assert verdict is Verdict.FAIL
    assert found.startswith("/docker/abc: cpu.rt_runtime_us 0 us of every 1000000 us")
    assert "echo 950000 > /sys/fs/cgroup/cpu/docker/abc/cpu.rt_runtime_us" in fix
    assert "--cpu-rt-runtime" in fix


@pytest.mark.parametrize(
    "cgroup",
    [
        CgroupBudget(Path("/sys/fs/cgroup/user.slice"), "/user.slice", None),  # no RT group scheduling
        CgroupBudget(Path("/sys/fs/cgroup/cpu"), "/", RtBudget(0, 1_000_000)),  # the root group is the global one
    ],
)
def test_no_group_budget_or_the_root_group_leaves_it_to_the_global_limit(cgroup: CgroupBudget) -> None:
    assert finding(NEEDS, replace(GOOD, cgroup=cgroup), "cgroup")[0] is Verdict.OK


@pytest.mark.parametrize(
    ("allowed", "online", "verdict", "says"),
    [
        ({0, 1}, {0, 1}, Verdict.OK, "may use CPUs 0-1"),
        ({0, 1, 2, 3}, {0, 1, 2, 3}, Verdict.OK, "may use CPUs 0-3"),
        ({0}, {0, 1}, Verdict.FAIL, "CPUs 0-1; 1 not here"),  # a cpuset or taskset leaves one CPU
        ({0, 1}, {0}, Verdict.FAIL, "the plan has 2 cores, 1 CPUs here"),  # CPU 1 offline
        ({2, 3}, {0, 1, 2, 3}, Verdict.FAIL, "0-1 not here"),  # enough CPUs, the wrong ones for taskset -c
    ],
)
def test_the_plans_cpus_must_be_allowed_and_online(
    allowed: set[int], online: set[int], verdict: Verdict, says: str
) -> None:
    machine = replace(GOOD, allowed_cpus=frozenset(allowed), online_cpus=frozenset(online))
    result, found, fix = finding(NEEDS, machine, "CPUs")
    assert result is verdict
    assert says in found
    assert (fix != "") == (verdict is Verdict.FAIL)


def test_missing_tools_fail() -> None:
    verdict, found, fix = finding(NEEDS, replace(GOOD, missing_tools=("chrt",)), "tools")
    assert verdict is Verdict.FAIL
    assert "not on PATH: chrt" in found
    assert "util-linux" in fix


@pytest.mark.parametrize(
    ("state", "verdict", "fix"),
    [
        (LoopState.READY, Verdict.OK, ""),
        (LoopState.UNBUILT, Verdict.WARN, "catanc run --loop compiled builds it"),
        (LoopState.NO_NUMBA, Verdict.WARN, "pip install numba"),
    ],
)
def test_a_compiled_loop_not_built_warns_with_how_to_build_it(state: LoopState, verdict: Verdict, fix: str) -> None:
    result, found, how = finding(NEEDS, replace(GOOD, loop=state), "loop")
    assert result is verdict
    assert ("Python loop" in found) == (verdict is Verdict.WARN)
    assert fix in how
    assert render(diagnose(NEEDS, replace(GOOD, loop=state)), "t").splitlines()[-1] == "this machine can run the plan"


def test_render_counts_the_failures_and_shows_fixes_only_where_needed() -> None:
    machine = replace(USER, rtprio=0, fifo_refused="Operation not permitted", allowed_cpus=frozenset({0}))
    text = render(diagnose(NEEDS, machine), "title")
    lines = text.splitlines()
    assert lines[0] == "title"
    assert [line.split()[0] for line in lines if not line.startswith(" ")][1:-1] == [
        "FAIL",
        "FAIL",
        "ok",
        "ok",
        "FAIL",
        "ok",
        "ok",
    ]
    assert sum(line.lstrip().startswith("fix:") for line in lines) == 3
    assert lines[-1] == "3 checks failed: this machine cannot run the plan as planned"


def test_needs_of_the_committed_nav2d_table() -> None:
    data = json.loads(TABLE.read_text())
    needs = needs_of(load_table(TABLE))
    assert needs.cores == data["cores"] == 2
    assert needs.cpus == {cpu for process in data["processes"] for cpu in process["cpus"]}
    assert needs.fifo_priority == max(4, *(process["priority"] for process in data["processes"]))
    assert needs.rt_share == pytest.approx(1 - data["spec"]["schedule"]["slack"])
    assert needs.dedicated == tuple(sorted(n for n, s in data["plan"]["subchains"].items() if not s["shared"]))


# --------------------------------------------------------------------------- reading /proc


V1_DOCKER = (
    ["12:cpu,cpuacct:/docker/abc", "4:memory:/docker/abc", "0::/system.slice/docker-abc.scope"],
    [
        "30 25 0:26 / /sys/fs/cgroup ro,nosuid - tmpfs tmpfs ro,mode=755",
        "40 30 0:36 /docker/abc /sys/fs/cgroup/cpu,cpuacct ro,nosuid - cgroup cgroup rw,cpu,cpuacct",
        "41 30 0:37 /docker/abc /sys/fs/cgroup/memory ro,nosuid - cgroup cgroup rw,memory",
    ],
)
V1_HOST = (
    ["2:cpuacct:/", "1:cpu:/app/x", "0::/"],
    [
        "33 31 0:30 / /sys/fs/cgroup/cpuacct rw,relatime - cgroup cgroup rw,cpuacct",
        "32 31 0:29 / /sys/fs/cgroup/cpu rw,relatime - cgroup cgroup rw,cpu",
        "41 31 0:38 / /sys/fs/cgroup/unified rw,relatime - cgroup2 cgroup2 rw",
    ],
)
V2_ONLY = (
    ["0::/user.slice/user-1000.slice/session-3.scope"],
    ["29 23 0:26 / /sys/fs/cgroup rw,nosuid,nodev,noexec,relatime shared:4 - cgroup2 cgroup2 rw,nsdelegate"],
)


@pytest.mark.parametrize(
    ("lines", "folder", "path"),
    [
        (V1_DOCKER, "/sys/fs/cgroup/cpu,cpuacct", "/docker/abc"),  # the container sees its group as the root
        (V1_HOST, "/sys/fs/cgroup/cpu/app/x", "/app/x"),  # cpuacct alone is not cpu
        (
            V2_ONLY,
            "/sys/fs/cgroup/user.slice/user-1000.slice/session-3.scope",
            "/user.slice/user-1000.slice/session-3.scope",
        ),
    ],
)
def test_the_cpu_cgroup_is_found_from_proc(lines: tuple[list[str], list[str]], folder: str, path: str) -> None:
    assert find_cpu_cgroup(*lines) == (Path(folder), path)


def test_no_cpu_cgroup_is_none() -> None:
    assert find_cpu_cgroup(["4:memory:/a"], V1_HOST[1]) is None


@pytest.mark.parametrize(("text", "cpus"), [("0-2,5\n", {0, 1, 2, 5}), ("\n", set()), ("3", {3}), ("0-1,1", {0, 1})])
def test_parse_cpu_list(text: str, cpus: set[int]) -> None:
    assert parse_cpu_list(text) == cpus


@pytest.mark.parametrize("text", ["a", "2-1", "-1", "0-", "1-x"])
def test_parse_cpu_list_refuses_garbage(text: str) -> None:
    with pytest.raises(ValueError):  # noqa: PT011 (int() and the range check word it differently)
        parse_cpu_list(text)


@given(st.frozensets(st.integers(0, 300), min_size=1))
def test_parse_cpu_list_reads_what_format_cpus_writes(cpus: frozenset[int]) -> None:
    assert parse_cpu_list(format_cpus(cpus)) == cpus


# --------------------------------------------------------------------------- the command, on the real kernel


@pytest.fixture(scope="module")
def real_kernel() -> None:
    require_fifo(4)
    if missing := missing_tools("taskset", "chrt", "setsid"):
        pytest.skip(f"needs {', '.join(missing)}")


@pytest.fixture(scope="module")
def nobody(real_kernel: None) -> tuple[int, int]:
    return nobody_ids()


@pytest.fixture(scope="module")
def table(real_kernel: None) -> Iterator[Path]:
    """The committed two-core nav2d table, in a folder ``nobody`` may read."""
    folder = Path(tempfile.mkdtemp(prefix="catanc-doctor-", dir="/tmp"))
    folder.chmod(0o755)
    try:
        shutil.copy(TABLE, folder / "runtime.json")
        (folder / "runtime.json").chmod(0o644)
        yield folder / "runtime.json"
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def doctor(prefix: Sequence[str], *arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*prefix, sys.executable, "-m", "catanc", "doctor", *arguments],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
        cwd="/",
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )


def fifo_allowed(prefix: Sequence[str], priority: int) -> bool:
    """The kernel's own answer, without catanc: may a process started with ``prefix`` use SCHED_FIFO?"""
    probe = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"
    result = subprocess.run([*prefix, sys.executable, "-c", probe], capture_output=True, timeout=WAIT_S, check=False)
    return result.returncode == 0


def lines_of(result: subprocess.CompletedProcess[str]) -> dict[str, str]:
    """``{check: verdict}`` from the report."""
    found = {}
    for line in result.stdout.splitlines()[1:-1]:
        if not line.startswith(" "):
            verdict, check = line.split()[:2]
            found[check] = verdict
    return found


@pytest.mark.usefixtures("real_kernel")
def test_here_as_root_every_check_passes(table: Path) -> None:
    result = doctor([], str(table))
    assert result.returncode == ExitCode.OK, result.stdout + result.stderr
    assert lines_of(result)["privilege"] == "ok"
    assert lines_of(result)["SCHED_FIFO"] == "ok"
    assert result.stdout.splitlines()[0] == f"catanc doctor: {table} (nav2d, 2 cores)"
    without = doctor([])
    assert without.returncode == ExitCode.OK, without.stdout + without.stderr


@pytest.mark.parametrize(
    ("rtprio", "caps", "allowed"), [(0, "", False), (3, "", False), (4, "", True), (0, "sys_nice", True)]
)
def test_as_nobody_privilege_follows_the_kernel(
    table: Path, nobody: tuple[int, int], rtprio: int, caps: str, allowed: bool
) -> None:
    if rtprio and subprocess.run(["prlimit", f"--rtprio={rtprio}:{rtprio}", "true"], check=False).returncode:
        pytest.skip(f"cannot raise RLIMIT_RTPRIO to {rtprio} here (no CAP_SYS_RESOURCE)")
    prefix = as_user(*nobody, rtprio=rtprio, caps=caps)
    assert fifo_allowed(prefix, 4) is allowed  # the oracle: what the kernel itself says
    result = doctor(prefix, str(table))
    found = lines_of(result)
    expected = "ok" if allowed else "FAIL"
    assert (found["privilege"], found["SCHED_FIFO"]) == (expected, expected), result.stdout
    assert result.returncode == (ExitCode.OK if allowed else ExitCode.MACHINE), result.stdout + result.stderr
    if not allowed:
        assert f"RLIMIT_RTPRIO is {rtprio}" in result.stdout
        assert "fix: run catanc as root (sudo)" in result.stdout


@pytest.mark.usefixtures("real_kernel")
def test_pinned_to_one_cpu_the_two_core_plan_fails_the_cpu_check(table: Path) -> None:
    result = doctor(["taskset", "-c", "0"], str(table))
    assert result.returncode == ExitCode.MACHINE, result.stdout + result.stderr
    assert lines_of(result)["CPUs"] == "FAIL"
    assert "1 not here" in result.stdout
    one_core = doctor(["taskset", "-c", "0"])  # any plan: one CPU is enough for the enforcer
    assert one_core.returncode == ExitCode.OK, one_core.stdout


@pytest.fixture
def no_rt_cgroup(real_kernel: None) -> Iterator[Path]:
    """A new cgroup v1 cpu group beside this process's, with a real-time budget of 0 (a new group's default)."""
    membership = next(
        (
            line.split(":", 2)[2]
            for line in Path("/proc/self/cgroup").read_text().splitlines()
            if "cpu" in line.split(":", 2)[1].split(",")
        ),
        None,
    )
    base = Path("/sys/fs/cgroup/cpu")
    if membership is None or not (base / "cpu.rt_runtime_us").exists():
        pytest.skip("needs cgroup v1's cpu controller with real-time group scheduling at /sys/fs/cgroup/cpu")
    folder = base / membership.lstrip("/") / f"catanc-doctor-{os.getpid()}"
    try:
        folder.mkdir()
    except OSError as exc:
        pytest.skip(f"cannot create a cpu cgroup: {exc.strerror}")
    try:
        (folder / "cpu.rt_runtime_us").write_text("0\n")
        yield folder
    finally:
        deadline = time.monotonic() + WAIT_S
        while folder.exists():
            try:
                folder.rmdir()
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)


def test_in_a_cgroup_without_a_real_time_budget_even_root_fails(table: Path, no_rt_cgroup: Path) -> None:
    enter = ["sh", "-c", f'echo $$ > {no_rt_cgroup}/cgroup.procs && exec "$@"', "sh"]
    assert not fifo_allowed(enter, 1)  # the oracle: the kernel refuses root there
    result = doctor(enter, str(table))
    assert result.returncode == ExitCode.MACHINE, result.stdout + result.stderr
    found = lines_of(result)
    assert (found["privilege"], found["SCHED_FIFO"], found["cgroup"]) == ("ok", "FAIL", "FAIL")
    assert "cpu.rt_runtime_us 0 us of every" in result.stdout
    assert f"echo 950000 > {no_rt_cgroup}/cpu.rt_runtime_us" in result.stdout


def test_a_bad_table_is_a_compiler_style_error(tmp_path: Path) -> None:
    bad = tmp_path / "runtime.json"
    bad.write_text('{"format": "catanc-runtime/1",\n "app": 3}\n')
    result = doctor([], str(bad))
    assert result.returncode == ExitCode.BAD_INPUT
    assert result.stderr.startswith(f"{bad}:")
    assert "Traceback" not in result.stderr
    assert result.stdout == ""


def test_a_table_with_broken_processes_is_a_bad_input_error(tmp_path: Path) -> None:
    data = json.loads(TABLE.read_text())
    data["processes"][0]["cpus"] = ["zero"]
    bad = tmp_path / "runtime.json"
    bad.write_text(json.dumps(data))
    result = doctor([], str(bad))
    assert result.returncode == ExitCode.BAD_INPUT, result.stdout + result.stderr
    assert "processes or plan.subchains are not as catanc compile writes them" in result.stderr
    assert "Traceback" not in result.stderr


def test_without_a_table_it_checks_for_any_plan() -> None:
    assert ENFORCER_ONLY.fifo_priority == 4
    assert ENFORCER_ONLY.cpus == frozenset()
