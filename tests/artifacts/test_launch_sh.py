"""launch.sh, really run on this machine with stand-in commands.

The processes come from a small spec planned for 2 cores: ``fast`` gets a
dedicated core (SCHED_FIFO 2 on CPU 0), the Mapper-like ``/slow`` hosts two
nodes that share CPU 1 (SCHED_OTHER with ``--static``: no enforcer switches
its slices), and the unscheduled ``sensor`` may use both CPUs (FIFO 3).
Most tests run ``bash launch.sh --static``; those of the default deployment
run the real enforcer (``catanc run``) too.  Each test writes the emitted
files to a folder, runs the script and reads every child's policy, priority
and CPUs from /proc, comparing them with
:func:`catanc.artifacts.deploy.processes` (not with the script's text).
The stand-ins are small Python programs that say they are ready, note every
signal they get and linger a moment after the first, so a signal forwarded
twice would show.  The stopping tests give them children, some of which
ignore every signal but SIGKILL, and time how long the whole tree takes to go.

The tests that need the real kernel skip when SCHED_FIFO is not permitted or
taskset/chrt are missing; the unprivileged ones also need ``setpriv`` and
``prlimit``.  Every run's processes are killed at teardown, whatever happens.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from catanc.artifacts.compile import Target
from catanc.artifacts.deploy import Process, processes
from catanc.artifacts.emit import emit
from catanc.artifacts.provenance import Provenance
from catanc.errors import ExitCode
from catanc.model.build import build_problem
from catanc.model.load import parse_spec
from catanc.model.priorities import RUNNING_FIFO, SHARED_FIFO, UNSCHEDULED_FIFO
from catanc.planning.planner import plan
from catanc.planning.types import Plan
from catanc.spec.language import Spec
from tests.support.linux import as_user, cpu_set, missing_tools, poll

SPECS = sorted((Path(__file__).parents[2] / "specs").glob("*.yaml"))
CATANC = str(Path(sys.executable).with_name("catanc"))  # the enforcer launch.sh starts: this checkout's
WAIT_S = 10.0  # the longest any single wait in here may take
TOP_PRIORITY = UNSCHEDULED_FIFO  # the highest SCHED_FIFO priority a launch.sh here asks for

GRAPH: dict[str, Any] = {
    "catan": 1,
    "app": "launch_test",
    "nodes": {
        "sensor": {"scheduled": False, "rate_hz": 50},
        "fast": {"compute_ms": 1},
        "slowa": {"compute_ms": 40},
        "slowb": {"compute_ms": 30},
        "sink": {"scheduled": False},
    },
    "edges": [["sensor", "fast"], ["fast", "sink"], ["sensor", "slowa"], ["slowa", "slowb"]],
    "subchains": {"fast": ["fast"], "slowa": ["slowa"], "slowb": ["slowb"]},
    "objective": [{"chain": ["sensor", "fast", "sink"], "weight": 1.0}, {"node": "slowb", "weight": 0.1}],
}
KEYS = ("/slow", "fast", "sensor")  # the processes: slowa and slowb share the ROS node /slow

STANDIN = """\
import json, os, signal, sys, time
from pathlib import Path

folder, name, mode = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
received = []
waiting = False

class Stop(Exception):
    pass

def note(signum, frame):
    received.append(signal.Signals(signum).name)
    with (folder / f"{name}.signals").open("a") as log:
        log.write(received[-1] + "\\n")
    if waiting and len(received) == 1:
        raise Stop

signal.signal(signal.SIGINT, note)
signal.signal(signal.SIGTERM, note)
ready = {
    "pid": os.getpid(),
    "argv": sys.argv,
    "policy": os.sched_getscheduler(0),
    "priority": os.sched_getparam(0).sched_priority,
    "cpus": sorted(os.sched_getaffinity(0)),
}
(folder / f"{name}.tmp").write_text(json.dumps(ready))
(folder / f"{name}.tmp").rename(folder / f"{name}.json")
if mode.startswith("exit:"):
    sys.exit(int(mode[len("exit:"):]))
if mode == "tree":  # a child in its process group, as a node's helper process would be
    import subprocess
    child = subprocess.Popen(["sleep", "60"])
    (folder / f"{name}.child").write_text(str(child.pid))
waiting = True
try:
    if not received:
        time.sleep(30)
except Stop:
    pass
time.sleep(0.2)  # linger: a second copy of the signal would be noted now
"""


# --------------------------------------------------------------------------- the spec and its launch.sh


def make_spec(commands: Mapping[str, str]) -> Spec:
    """:data:`GRAPH` with a command for each of :data:`KEYS`."""
    deploy = {
        "sensor": {"command": commands["sensor"]},
        "fast": {"command": commands["fast"]},
        "slowa": {"ros_node": "/slow", "command": commands["/slow"]},
        "slowb": {"ros_node": "/slow"},
    }
    return parse_spec(yaml.safe_dump({**GRAPH, "deploy": deploy}), "launch_test.yaml")


@pytest.fixture(scope="module")
def two_cores() -> Plan:
    """The plan for :data:`GRAPH` on 2 cores; commands do not change it, so every test reuses it."""
    return plan(make_spec(dict.fromkeys(KEYS, "true")), 2)


def launch_files(spec: Spec, planned: Plan) -> dict[str, str]:
    return emit(spec, build_problem(spec), planned, Provenance("0", "catanc compile x", "x.yaml", "0" * 64))


def standin_command(folder: Path, key: str, mode: str = "run", extra: str = "") -> str:
    """The command line of a stand-in: it writes ``<name>.json`` when ready and notes signals in ``<name>.signals``."""
    words = [sys.executable, str(folder / "standin.py"), str(folder), name_of(key), mode]
    return " ".join(shlex.quote(word) for word in words) + (" " + extra if extra else "")


def launched_argv(process: Process, folder: Path) -> list[str]:
    """The command line a process runs with: its command, and for a ROS node the folder's parameters, by absolute
    path (``params_file``, docs/reference/runtime-json.md)."""
    ros_args = ["--ros-args", "--params-file", str(folder / "params.yaml")] if process.ros_node is not None else []
    return [*process.argv, *ros_args]


def name_of(key: str) -> str:
    return key.lstrip("/")


# --------------------------------------------------------------------------- reading /proc


@dataclass(frozen=True)
class Sched:
    policy: int
    priority: int
    cpus: frozenset[int]


def expected(process: Process, *, rt: bool = True) -> Sched:
    """What ``launch.sh --static`` runs a process at: a shared core's under SCHED_OTHER (worked out here)."""
    shared = {"/slow"}  # slowa and slowb share CPU 1 (test_the_plan_mixes_shared_dedicated_and_unscheduled)
    if rt and process.key not in shared:
        return Sched(os.SCHED_FIFO, process.priority, frozenset(process.cpus))
    return Sched(os.SCHED_OTHER, 0, frozenset(process.cpus))


def stat_fields(pid: int) -> list[str]:
    """``/proc/<pid>/stat`` from field 3 (state) on: the name before it may hold spaces."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def status_field(pid: int, field: str) -> str:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name == field:
            return value.strip()
    raise AssertionError(f"no {field} in /proc/{pid}/status")


def sched_of(pid: int) -> Sched:
    fields = stat_fields(pid)
    rt_priority, policy = int(fields[40 - 3]), int(fields[41 - 3])  # stat fields 40 and 41
    return Sched(policy, rt_priority, cpu_set(status_field(pid, "Cpus_allowed_list")))


def cmdline(pid: int) -> list[str]:
    return [os.fsdecode(word) for word in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[:-1]]


def parent_of(pid: int) -> int:
    return int(stat_fields(pid)[4 - 3])


def alive(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie."""
    try:
        return stat_fields(pid)[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def descendants_of(pid: int) -> set[int]:
    """Every process below ``pid``: children, their children, and so on."""
    found: set[int] = set()
    todo = [pid]
    while todo:
        below = children_of(todo.pop()) - found
        found |= below
        todo.extend(below)
    return found


def children_of(pid: int) -> set[int]:
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if parent_of(int(entry.name)) == pid:
                    found.add(int(entry.name))
            except (FileNotFoundError, ProcessLookupError, IndexError):
                continue
    return found


# --------------------------------------------------------------------------- running launch.sh


@dataclass
class Run:
    """One ``bash launch.sh`` (stdout and stderr go to files, so nothing blocks on a pipe)."""

    proc: subprocess.Popen[bytes]
    folder: Path
    token: str  # in every process's environment: teardown kills only processes that carry it

    @property
    def stdout(self) -> str:
        return (self.folder / "stdout.txt").read_text()

    @property
    def stderr(self) -> str:
        return (self.folder / "stderr.txt").read_text()

    def started(self) -> dict[str, int]:
        """``{process key: pid}`` from the script's ``launch.sh: started KEY (pid N, ...)`` lines."""
        found = {}
        for line in self.stdout.splitlines():
            if line.startswith("launch.sh: started ") and "(pid " in line:
                key, _, rest = line.removeprefix("launch.sh: started ").partition(" (pid ")
                found[key] = int(rest.split(",")[0])
        return found

    def ready(self, keys: Sequence[str] = KEYS, also: Sequence[str] = ()) -> dict[str, dict[str, Any]]:
        """Waits until every stand-in has written its ``.json`` and the script has printed its pid (and ``also``'s)."""

        def check() -> dict[str, dict[str, Any]] | None:
            if self.proc.poll() is not None:
                pytest.fail(f"launch.sh exited with {self.proc.returncode} early:\n{self.stdout}{self.stderr}")
            files = [self.folder / f"{name_of(key)}.json" for key in keys]
            if not all(file.exists() for file in files) or set(self.started()) != {*keys, *also}:
                return None
            return {key: json.loads(file.read_text()) for key, file in zip(keys, files, strict=True)}

        return poll(check, f"{', '.join(keys)} to start")

    def signals(self, key: str) -> list[str]:
        log = self.folder / f"{name_of(key)}.signals"
        return log.read_text().split() if log.exists() else []

    def wait(self) -> int:
        try:
            return self.proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"launch.sh still runs after {WAIT_S} s:\n{self.stdout}{self.stderr}")


Launcher = Callable[..., Run]


@pytest.fixture
def launcher() -> Iterator[Launcher]:
    """``launch(folder, files, *args, prefix=())``: writes the files and runs ``prefix bash launch.sh args``."""
    runs: list[Run] = []

    def launch(
        folder: Path,
        files: Mapping[str, str],
        *args: str,
        prefix: Sequence[str] = (),
        static: bool = True,
        catanc: str = CATANC,
    ) -> Run:
        for name, text in files.items():
            (folder / name).write_text(text)
        (folder / "standin.py").write_text(STANDIN)
        token = f"CATANC_LAUNCH_TEST={folder}"
        with (
            (folder / "stdout.txt").open("wb") as out,
            (folder / "stderr.txt").open("wb") as err,
            sigint_not_ignored(),
        ):
            proc = subprocess.Popen(
                [*prefix, "bash", "launch.sh", *(["--static"] if static else []), *args],
                cwd=folder,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=err,
                env={**os.environ, "CATANC_LAUNCH_TEST": str(folder), "CATANC": catanc},
                start_new_session=True,
            )
        run = Run(proc, folder, token)
        runs.append(run)
        return run

    yield launch
    for run in runs:
        kill_run(run)


@contextlib.contextmanager
def sigint_not_ignored() -> Iterator[None]:
    """Children of a process that ignores SIGINT (pytest run as a background job) would ignore it too.

    A script cannot trap a signal ignored when it started, so the SIGINT tests need it handled here.
    """
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        yield
        return
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def kill_run(run: Run) -> None:
    """SIGKILL a run's script and each process it started (by pid, checking the run's token first)."""
    pids = set(run.started().values())
    if run.proc.poll() is None:
        pids |= children_of(run.proc.pid)
        os.killpg(run.proc.pid, signal.SIGKILL)
    for pid in pids:
        try:
            if run.token.encode() in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
                os.kill(pid, signal.SIGKILL)
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
    run.proc.wait(timeout=WAIT_S)


# --------------------------------------------------------------------------- what the machine allows


REALTIME_PRIORITY = TOP_PRIORITY  # conftest's real_kernel: the highest priority a launch.sh here asks for
REALTIME_TOOLS = ("bash", "taskset", "chrt")


# --------------------------------------------------------------------------- the tests


def test_the_plan_mixes_shared_dedicated_and_unscheduled(two_cores: Plan) -> None:
    """The premise of the other tests: the processes differ in CPUs and priority."""
    found = {p.key: (p.cpus, p.priority) for p in processes(make_spec(dict.fromkeys(KEYS, "true")), two_cores)}
    assert set(found) == set(KEYS)
    assert {priority for _, priority in found.values()} == {SHARED_FIFO, RUNNING_FIFO, UNSCHEDULED_FIFO}
    assert found["sensor"] == ((0, 1), UNSCHEDULED_FIFO)
    assert found["fast"][1] == RUNNING_FIFO
    assert found["/slow"][1] == SHARED_FIFO
    assert len({cpus for cpus, _ in found.values()}) == 3
    static = {p.key: p.static_priority for p in processes(make_spec(dict.fromkeys(KEYS, "true")), two_cores)}
    assert static == {"/slow": 0, "fast": RUNNING_FIFO, "sensor": UNSCHEDULED_FIFO}


@pytest.mark.usefixtures("real_kernel")
def test_each_process_runs_with_its_planned_policy_priority_and_cpus(
    tmp_path: Path, two_cores: Plan, launcher: Launcher
) -> None:
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores))
    ready = run.ready()
    started = run.started()
    for process in processes(spec, two_cores):
        pid = started[process.key]
        # The printed pid is the command itself: taskset and chrt exec'd it, no shell or wrapper in between.
        assert ready[process.key]["pid"] == pid
        assert cmdline(pid) == launched_argv(process, tmp_path)
        assert parent_of(pid) == run.proc.pid
        assert sched_of(pid) == expected(process), process.key
        seen = ready[process.key]  # the stand-in's own view, as it started
        assert Sched(seen["policy"], seen["priority"], frozenset(seen["cpus"])) == expected(process)
        assert f"started {process.key} (pid {pid}, CPUs {','.join(map(str, process.cpus))}, " in run.stdout
    assert children_of(run.proc.pid) == set(started.values())
    run.proc.send_signal(signal.SIGTERM)
    assert run.wait() == 128 + signal.SIGTERM


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_reaches_every_process_once_and_the_script_waits_for_them(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, signum: signal.Signals
) -> None:
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores))
    run.ready()
    pids = run.started()
    run.proc.send_signal(signum)
    assert run.wait() == 128 + signum
    # Each stand-in lingers 0.2 s after the signal: had the script not waited, they would still run.
    assert not [key for key, pid in pids.items() if alive(pid)]
    assert {key: run.signals(key) for key in KEYS} == {key: [signum.name] for key in KEYS}
    assert run.stderr == ""


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("failing", KEYS)
def test_a_process_that_fails_early_is_reported_while_the_others_run(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, failing: str
) -> None:
    """Reported when it happens, whether the script started it first or last, and not lost on a later SIGINT."""
    spec = make_spec({key: standin_command(tmp_path, key, "exit:3" if key == failing else "run") for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores))
    run.ready()
    pids = run.started()
    report = f"launch.sh: {failing} (pid {pids[failing]}) exited with status 3\n"
    poll(lambda: report in run.stderr, f"the report of {failing}'s exit")
    others = [key for key in KEYS if key != failing]
    assert run.proc.poll() is None
    assert [key for key in others if alive(pids[key])] == others
    run.proc.send_signal(signal.SIGINT)
    assert run.wait() == 128 + signal.SIGINT
    assert run.stderr == report  # once, and the stopped processes' exits are not failures
    assert {key: run.signals(key) for key in others} == {key: ["SIGINT"] for key in others}
    assert run.signals(failing) == []


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("delay_ms", [0, 2, 5, 10, 20])
def test_a_signal_at_any_moment_stops_the_script(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, delay_ms: int
) -> None:
    """SIGINT a few milliseconds in: while bash starts, runs its checks, starts or waits.

    Before its trap is set bash dies of it (nothing started yet); after, it ends with 130
    once every process it started has ended, and none started got the signal twice.
    """
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores))
    time.sleep(delay_ms / 1000)
    run.proc.send_signal(signal.SIGINT)
    code = run.wait()
    started = run.started()
    assert code in {128 + signal.SIGINT, -signal.SIGINT}, run.stdout + run.stderr
    assert code > 0 or not started  # killed by the signal only before it started anything
    assert not [key for key, pid in started.items() if alive(pid)]
    assert [key for key in started if run.signals(key) not in ([], ["SIGINT"])] == []


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("attempt", range(5))
def test_a_signal_while_starting_reaches_every_process_started(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, attempt: int
) -> None:
    """The first process SIGTERMs the script at once, most likely while it starts the others.

    Whatever the timing, every process it starts gets the signal (none is left running, so
    the script ends) and it starts none after it.  Each attempt is one roll of the timing dice.
    """
    commands = {key: standin_command(tmp_path, key) for key in KEYS}
    first = min(KEYS)  # the script starts the processes in key order
    commands[first] = shlex.join(["sh", "-c", 'kill -TERM "$PPID" && exec "$@"', "sh"]) + " " + commands[first]
    spec = make_spec(commands)
    run = launcher(tmp_path, launch_files(spec, two_cores))
    assert run.wait() == 128 + signal.SIGTERM, run.stdout + run.stderr
    started = run.started()
    assert first in started
    assert not [key for key, pid in started.items() if alive(pid)]
    # One SIGTERM for those that had set up their handlers by then; the others died of it, unnoted.
    assert [key for key in started if run.signals(key) not in ([], ["SIGTERM"])] == []
    assert run.stderr == ""


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("statuses", [{}, {"fast": 5, "sensor": 7}])
def test_without_signals_the_script_ends_with_its_processes(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, statuses: dict[str, int]
) -> None:
    spec = make_spec({key: standin_command(tmp_path, key, f"exit:{statuses.get(key, 0)}") for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores))
    code = run.wait()
    pids = run.started()
    assert set(pids) == set(KEYS)
    reports = {f"launch.sh: {key} (pid {pids[key]}) exited with status {status}" for key, status in statuses.items()}
    assert set(run.stderr.splitlines()) == reports
    # The status of the first failure, in the order they happened (fast and sensor end at about the same time).
    assert code == (int(run.stderr.splitlines()[0].rsplit(" ", 1)[1]) if statuses else 0)


def tricky_arguments(markers: Sequence[Path]) -> str:
    """Shell-like words a shell would act on: each ``$(touch ...)`` or backtick would create a marker."""
    return (
        f'a;b ";" ; "$(touch {markers[0]})" $(touch {markers[1]}) `touch {markers[2]}` "`touch {markers[3]}`" '
        f"'$(touch {markers[4]})' \"it's\" 'say \"hi\"' \"\\\"x\\\" \\$y\" it\\'s * '*' ~ $HOME ${{HOME}} '' "
        "\"tab\there\" 'new\nline' na\u00efve \\| '&&' '>' out <in 2>&1 '#' #not-a-comment"
    )


@pytest.mark.usefixtures("real_kernel")
def test_commands_are_passed_literally(tmp_path: Path, two_cores: Plan, launcher: Launcher) -> None:
    """Nothing in a command is run by a shell: not ``$(...)``, backticks, ``;``, globs, ``~`` or ``$VAR``."""
    markers = [tmp_path / f"marker{index}" for index in range(5)]
    commands = {key: standin_command(tmp_path, key) for key in KEYS}
    commands["/slow"] = standin_command(tmp_path, "/slow", extra=tricky_arguments(markers))
    spec = make_spec(commands)
    files = launch_files(spec, two_cores)
    run = launcher(tmp_path, files)
    ready = run.ready()
    want = shlex.split(commands["/slow"])
    assert want[5:8] == ["a;b", ";", ";"]  # the test's premise: shlex keeps these as words
    assert [process.argv for process in processes(spec, two_cores) if process.key == "/slow"] == [tuple(want)]
    slow = next(process for process in processes(spec, two_cores) if process.key == "/slow")
    assert [sys.executable, *ready["/slow"]["argv"]] == launched_argv(slow, tmp_path)
    assert cmdline(run.started()["/slow"]) == launched_argv(slow, tmp_path)
    assert not [marker.name for marker in markers if marker.exists()]
    assert not (tmp_path / "out").exists()
    run.proc.send_signal(signal.SIGTERM)
    assert run.wait() == 128 + signal.SIGTERM
    assert not [marker.name for marker in markers if marker.exists()]


@pytest.mark.usefixtures("real_kernel")
def test_no_rt_runs_everything_under_sched_other_with_the_same_cpus(
    tmp_path: Path, two_cores: Plan, launcher: Launcher
) -> None:
    """Even when launch.sh itself runs under SCHED_FIFO, --no-rt starts its processes under SCHED_OTHER."""
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores), "--no-rt", prefix=["chrt", "-f", "1"])
    run.ready()
    started = run.started()
    for process in processes(spec, two_cores):
        assert sched_of(started[process.key]) == expected(process, rt=False), process.key
        assert f"started {process.key} (pid {started[process.key]}, CPUs " in run.stdout
    assert run.stdout.count("SCHED_OTHER)") == len(KEYS)
    assert "SCHED_FIFO" not in run.stdout
    run.proc.send_signal(signal.SIGINT)
    assert run.wait() == 128 + signal.SIGINT


def touch_and_sleep(marker: Path) -> str:
    """A stand-in an unprivileged user can run: it creates ``marker`` and becomes ``sleep 30``."""
    return shlex.join(["sh", "-c", 'touch "$0" && exec sleep 30', str(marker)])


def test_without_privileges_it_starts_nothing_and_says_how_to_fix_it(
    shared_folder: Path, two_cores: Plan, launcher: Launcher, nobody: tuple[int, int]
) -> None:
    markers = {key: shared_folder / f"{name_of(key)}.started" for key in KEYS}
    spec = make_spec({key: touch_and_sleep(marker) for key, marker in markers.items()})
    run = launcher(shared_folder, launch_files(spec, two_cores), prefix=as_user(*nobody, rtprio=0))
    assert run.wait() == ExitCode.NO_PRIVILEGE
    message = run.stderr
    assert f"cannot run processes at SCHED_FIFO priority {TOP_PRIORITY}" in message
    assert "RLIMIT_RTPRIO is 0" in message
    assert "run as root" in message
    assert "rtprio" in message.split("Fix:", 1)[1]  # the limits.conf line
    assert "--no-rt" in message
    assert run.stdout == ""
    assert not [marker.name for marker in markers.values() if marker.exists()]


def test_without_privileges_no_rt_starts_everything(
    shared_folder: Path, two_cores: Plan, launcher: Launcher, nobody: tuple[int, int]
) -> None:
    markers = {key: shared_folder / f"{name_of(key)}.started" for key in KEYS}
    spec = make_spec({key: touch_and_sleep(marker) for key, marker in markers.items()})
    run = launcher(shared_folder, launch_files(spec, two_cores), "--no-rt", prefix=as_user(*nobody, rtprio=0))
    poll(lambda: all(marker.exists() for marker in markers.values()) and len(run.started()) == len(KEYS), "markers")
    started = run.started()
    poll(lambda: all(cmdline(pid) == ["sleep", "30"] for pid in started.values()), "each sh to exec sleep")
    for process in processes(spec, two_cores):
        pid = started[process.key]
        assert sched_of(pid) == expected(process, rt=False), process.key
        assert status_field(pid, "Uid").split()[:2] == [str(nobody[0])] * 2
    run.proc.send_signal(signal.SIGTERM)
    assert run.wait() == 128 + signal.SIGTERM
    assert run.stderr == ""


def can_raise_rtprio(limit: int) -> bool:
    probe = subprocess.run(["prlimit", f"--rtprio={limit}:{limit}", "true"], capture_output=True, check=False)
    return probe.returncode == 0


@pytest.mark.parametrize("how", ["CAP_SYS_NICE", "RLIMIT_RTPRIO"])
def test_an_unprivileged_user_allowed_real_time_passes_the_check(
    shared_folder: Path, two_cores: Plan, launcher: Launcher, nobody: tuple[int, int], how: str
) -> None:
    """Root is not needed: CAP_SYS_NICE, or an RLIMIT_RTPRIO as high as the plan's priorities, is enough."""
    if how == "CAP_SYS_NICE":
        prefix = as_user(*nobody, rtprio=0, caps="sys_nice")
    elif can_raise_rtprio(10):
        prefix = as_user(*nobody, rtprio=10)
    else:
        pytest.skip("cannot raise RLIMIT_RTPRIO to 10 here (its hard limit is lower and CAP_SYS_RESOURCE is missing)")
    markers = {key: shared_folder / f"{name_of(key)}.started" for key in KEYS}
    spec = make_spec({key: touch_and_sleep(marker) for key, marker in markers.items()})
    run = launcher(shared_folder, launch_files(spec, two_cores), prefix=prefix)
    poll(lambda: all(marker.exists() for marker in markers.values()) and len(run.started()) == len(KEYS), "markers")
    started = run.started()
    for process in processes(spec, two_cores):
        assert sched_of(started[process.key]) == expected(process), process.key
        assert status_field(started[process.key], "Uid").split()[0] == str(nobody[0])
    run.proc.send_signal(signal.SIGTERM)
    assert run.wait() == 128 + signal.SIGTERM


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("args", [(), ("--no-rt",)], ids=["rt", "no-rt"])
def test_cpus_this_machine_lacks_stop_it_before_it_starts_anything(
    tmp_path: Path, launcher: Launcher, args: tuple[str, ...]
) -> None:
    """A plan for more cores than the machine has: exit 4, naming the CPUs and the --cores to compile for.

    taskset alone would accept ``-c 1,2`` here and quietly drop CPU 2, so the script checks each CPU.
    """
    cores = max(os.cpu_count() or 1, max(os.sched_getaffinity(0)) + 1) + 1  # CPU cores-1 does not exist
    if cores > 8:
        pytest.skip(f"planning for {cores} cores would take a while")
    markers = {key: tmp_path / f"{name_of(key)}.started" for key in KEYS}
    spec = make_spec({key: touch_and_sleep(marker) for key, marker in markers.items()})
    planned = plan(spec, cores)
    used = {cpu for process in processes(spec, planned) for cpu in process.cpus}
    assert cores - 1 in used  # the unscheduled sensor may use every core
    run = launcher(tmp_path, launch_files(spec, planned), *args)
    assert run.wait() == ExitCode.NO_PRIVILEGE
    refused = run.stderr.partition("may not run on CPU ")[2].partition(" (allowed here: ")[0]
    assert cores - 1 in cpu_set(refused), run.stderr
    assert cpu_set(refused) <= used
    assert f"the plan is for {cores} cores: recompile with --cores " in run.stderr
    assert run.stdout == ""
    assert not [marker.name for marker in markers.values() if marker.exists()]


# --------------------------------------------------------------------------- static checks


@pytest.fixture(scope="module")
def example_scripts(
    tmp_path_factory: pytest.TempPathFactory, example_targets: Mapping[tuple[str, int], Target]
) -> dict[str, Path]:
    """launch.sh of every example spec on 1 and 2 cores (compiled once: tests/artifacts/conftest.py), written out."""
    folder = tmp_path_factory.mktemp("examples")
    scripts = {}
    for spec in SPECS:
        for cores in (1, 2):
            path = folder / f"{spec.stem}-{cores}.sh"
            path.write_text(example_targets[spec.stem, cores].files["launch.sh"])
            scripts[path.stem] = path
    return scripts


@pytest.mark.slow
def test_every_example_script_parses(example_scripts: dict[str, Path]) -> None:
    if missing_tools("bash"):
        pytest.skip("needs bash")
    assert len(example_scripts) == 2 * len(SPECS) > 0
    for name, path in example_scripts.items():
        result = subprocess.run(["bash", "-n", str(path)], capture_output=True, text=True, timeout=WAIT_S, check=False)
        assert result.returncode == 0, f"{name}: {result.stderr}"


@pytest.mark.slow
def test_every_example_script_passes_shellcheck(
    example_scripts: dict[str, Path], tmp_path: Path, two_cores: Plan
) -> None:
    if missing_tools("shellcheck"):
        pytest.skip("shellcheck is not installed")
    markers = [tmp_path / f"marker{index}" for index in range(5)]
    tricky = make_spec(dict.fromkeys(KEYS, "sh -c 'echo \"$HOME\"; `true`' " + tricky_arguments(markers)))
    (tmp_path / "tricky.sh").write_text(launch_files(tricky, two_cores)["launch.sh"])
    for path in [*example_scripts.values(), tmp_path / "tricky.sh"]:
        result = subprocess.run(
            ["shellcheck", "--shell=bash", str(path)], capture_output=True, text=True, timeout=WAIT_S, check=False
        )
        assert result.returncode == 0, f"{path.name}:\n{result.stdout}"


# --------------------------------------------------------------------------- the default: with the enforcer


def socket_of(run: Run) -> str:
    """The enforcer's socket, from ``launch.sh: started catanc run (pid N, socket PATH)``."""
    line = next(line for line in run.stdout.splitlines() if line.startswith("launch.sh: started catanc run "))
    return line.rpartition("socket ")[2].rstrip(")")


def environment_of(pid: int) -> dict[str, str]:
    pairs = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(os.fsdecode(pair).partition("=")[::2] for pair in pairs if pair)


@pytest.mark.usefixtures("real_kernel")
def test_by_default_the_enforcer_starts_first_and_the_processes_reach_it(
    tmp_path: Path, two_cores: Plan, launcher: Launcher
) -> None:
    """catanc run on the table beside launch.sh, then each process on its CPUs under SCHED_OTHER, with its socket."""
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores), static=False)
    ready = run.ready(KEYS, also=["catanc run"])
    started = run.started()
    assert next(iter(started)) == "catanc run"
    enforcer = started["catanc run"]
    socket = socket_of(run)
    table = str(tmp_path / "runtime.json")
    assert cmdline(enforcer)[-7:] == ["run", table, "--socket", socket, "--start", "spec", "--quiet"]
    assert Path(socket).is_socket()  # up before any process started
    for process in processes(spec, two_cores):
        pid = started[process.key]
        assert ready[process.key]["pid"] == pid
        assert sched_of(pid) == expected(process, rt=False), process.key  # the enforcer raises what registers
        assert environment_of(pid)["CATANC_SOCKET"] == socket
        assert os.getpgid(pid) == pid  # a group of its own
    run.proc.send_signal(signal.SIGTERM)
    assert run.wait() == 128 + signal.SIGTERM
    assert not alive(enforcer)
    assert not Path(socket).parent.exists()  # launch.sh's socket folder is gone with it


FAKE_ENFORCER = """\
import socket, sys, time
path = sys.argv[sys.argv.index("--socket") + 1]
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.bind(path)
time.sleep(0.5)
sys.exit(5)
"""


@pytest.mark.usefixtures("real_kernel")
def test_when_the_enforcer_ends_the_processes_are_stopped(tmp_path: Path, two_cores: Plan, launcher: Launcher) -> None:
    """An enforcer that binds its socket and exits with 5 half a second later: launch.sh stops the rest, exits 5."""
    fake = tmp_path / "fake-catanc"
    fake.write_text(f"#!{sys.executable}\n{FAKE_ENFORCER}")
    fake.chmod(0o755)
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores), static=False, catanc=str(fake))
    assert run.wait() == 5, run.stdout + run.stderr
    started = run.started()
    assert not [key for key, pid in started.items() if alive(pid)]
    assert "the enforcer (pid " in run.stderr
    assert "exited with status 5: stopping the processes" in run.stderr
    # Each stand-in that had started when the enforcer ended got one SIGTERM.
    assert [key for key in KEYS if key in started and run.signals(key) not in ([], ["SIGTERM"])] == []


@pytest.mark.usefixtures("real_kernel")
def test_without_catanc_it_starts_nothing_and_says_how_to_deploy(
    tmp_path: Path, two_cores: Plan, launcher: Launcher
) -> None:
    spec = make_spec({key: standin_command(tmp_path, key) for key in KEYS})
    run = launcher(tmp_path, launch_files(spec, two_cores), static=False, catanc=str(tmp_path / "no-such-catanc"))
    assert run.wait() == 127
    assert "cannot find the enforcer" in run.stderr
    assert "--static" in run.stderr
    assert run.stdout == ""


# --------------------------------------------------------------------------- stopping the whole tree

STOP_TARGET_S = 3.0  # issue 32: every process launch.sh started, children included, gone within 3 s


def tree_commands(folder: Path) -> dict[str, str]:
    """Processes with children, as nodes have them; ``*.child`` holds each child's pid.

    ``/slow`` stops on the signal and its child (``sleep``) dies of it; ``fast`` and its child ignore
    SIGINT, SIGTERM and SIGHUP (only SIGKILL ends them); ``sensor`` dies of the signal but leaves a
    child that ignores it behind, in its process group.
    """
    ignoring = 'trap "" INT TERM HUP; sleep 60 & echo $! > "$0.child"; exec sleep 60'
    orphaning = '(trap "" INT TERM HUP; exec sleep 60) & echo $! > "$0.child"; exec sleep 60'
    return {
        "/slow": standin_command(folder, "/slow", "tree"),
        "fast": shlex.join(["sh", "-c", ignoring, str(folder / "fast")]),
        "sensor": shlex.join(["sh", "-c", orphaning, str(folder / "sensor")]),
    }


@pytest.mark.usefixtures("real_kernel")
@pytest.mark.parametrize("static", [True, False], ids=["static", "enforced"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_stops_every_process_and_child_within_3_s(
    tmp_path: Path, two_cores: Plan, launcher: Launcher, static: bool, signum: signal.Signals
) -> None:
    spec = make_spec(tree_commands(tmp_path))
    run = launcher(tmp_path, launch_files(spec, two_cores), static=static)
    children = [tmp_path / f"{name_of(key)}.child" for key in KEYS]

    def up() -> set[int] | None:
        if run.proc.poll() is not None:
            pytest.fail(f"launch.sh exited with {run.proc.returncode} early:\n{run.stdout}{run.stderr}")
        if not all(file.exists() and file.read_text().strip() for file in children):
            return None
        if not set(KEYS) <= set(run.started()):
            return None
        tree = descendants_of(run.proc.pid)
        return tree if {int(file.read_text()) for file in children} <= tree else None

    tree = poll(up, "every process and its child")
    assert len(tree) >= 2 * len(KEYS) + (0 if static else 1)
    began = time.monotonic()
    run.proc.send_signal(signum)
    poll(lambda: not [pid for pid in tree if alive(pid)] or None, "the tree to end", timeout=WAIT_S, step=0.01)
    elapsed = time.monotonic() - began
    print(f"{'static' if static else 'enforced'} {signum.name}: {len(tree)} processes gone in {elapsed:.2f} s")
    assert elapsed <= STOP_TARGET_S, run.stdout + run.stderr
    assert run.wait() == 128 + signum, run.stdout + run.stderr
    # Only the processes that ignored the signal needed SIGKILL.
    assert "launch.sh: fast (pid " in run.stderr
    assert "still ran: SIGKILL" in run.stderr
    assert "/slow (pid" not in run.stderr
