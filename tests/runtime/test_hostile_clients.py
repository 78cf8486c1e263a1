"""``catanc run`` against broken and hostile clients, on the real kernel (issue 31).

Each test runs a small app under the enforcer (``--demo`` workers, one core) and attacks it
the way a buggy or malicious local process could, through the enforcer's socket, its nodes'
rings, its watchdog or the file system; then checks that the run went on as planned, ended
when it should, and left nothing raised.  What the enforcer did is read from its log and from
``/proc``, never from catanc's own view of itself.

Skips with the reason where SCHED_FIFO (up to the watchdog's priority) or CPUs 0 and 1 are
not available; every process started here is killed at teardown.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from catanc import client as client_module
from catanc.errors import ExitCode
from catanc.runtime.linux.watchdog import WATCHDOG_PRIORITY
from tests.support.enforcer_runs import ENFORCER_MAIN, EnforcerRun, Event, cmdline, compile_table, kill_groups, of_kind
from tests.support.linux import WAIT_S, Sched, alive, poll, sched_of, threads_of

# One core, two subchains: `front` (cam -> det, 4 + 4 ms, at most 50 Hz) and `map` (8 ms, at most 20 Hz);
# imu is unscheduled and registers (FIFO 3).  Both planned rates are their caps: a run takes a fifth of
# its period, so a lost trigger, a stolen slot or a stall shows as a rate well below the plan.
HOSTILE_SPEC = """\
catan: 1
app: hostile
nodes:
  imu: {scheduled: false, rate_hz: 100}
  cam: {compute_ms: 4}
  det: {compute_ms: 4}
  map: {compute_ms: 8}
edges: [[imu, det], [cam, det], [det, map]]
subchains: {front: [cam, det], map: [map]}
objective:
  - {chain: [cam, det], weight: 1.0}
  - {node: map, weight: 0.2}
constraints:
  - {node: cam, max_rate_hz: 50}
  - {node: map, max_rate_hz: 20}
runtime: {first_solve_after_s: 1.5, stage2_every_s: 1, stage1_every_s: 100}
"""
RATE_TOLERANCE = 0.10
MINE = frozenset(os.sched_getaffinity(0))
OTHER = Sched(os.SCHED_OTHER, 0, MINE)


REALTIME_PRIORITY = WATCHDOG_PRIORITY  # conftest's real_kernel: every test here needs SCHED_FIFO up to it
pytestmark = pytest.mark.usefixtures("real_kernel")


@dataclass
class Run(EnforcerRun):
    """One enforcer with --demo workers; :meth:`close` kills what is left."""

    extra: list[subprocess.Popen[bytes]] = field(default_factory=list)
    began: float = 0.0

    def start(self, duration: float, *options: str, table: Path | None = None) -> None:
        table = table or compile_table(HOSTILE_SPEC, self.folder / "app", 1)
        argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--demo", "--start", "spec"]
        argv += ["--socket", str(self.socket), "--log", str(self.log), "--duration", str(duration), *options]
        with (self.folder / "enforcer.err").open("wb") as err:
            self.enforcer = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        poll(lambda: self.enforcer.poll() is not None or self.socket.exists(), "the enforcer's socket")  # type: ignore[union-attr]
        assert self.enforcer.poll() is None, self.stderr()
        self.began = time.monotonic()

    def spawn(self, code: str, *args: str, prefix: Sequence[str] = ()) -> subprocess.Popen[bytes]:
        """A Python process running ``code`` with ``args`` (its stderr in the run's folder)."""
        with (self.folder / f"spawned-{len(self.extra)}.err").open("wb") as err:
            process = subprocess.Popen([*prefix, sys.executable, "-c", code, *args], stderr=err, start_new_session=True)
        self.extra.append(process)
        return process

    def workers(self) -> dict[str, tuple[int, int]]:
        return self.registered(["cam", "det", "map"])

    def close(self) -> None:
        kill_groups([*self.extra, *([self.enforcer] if self.enforcer else [])])
        for event in of_kind(self.events(), "register"):
            if "catanc" in cmdline(event["pid"]):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(event["pid"], signal.SIGKILL)
        for pid in children_of(self.pid) if self.enforcer else []:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def children_of(pid: int) -> list[int]:
    found: list[int] = []
    for tid in threads_of(pid):
        with contextlib.suppress(OSError):
            found += [int(word) for word in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
    return found


@pytest.fixture
def run(tmp_path: Path) -> Iterator[Run]:
    made = Run(tmp_path, Path(tempfile.mkdtemp(prefix="catanc-hostile-")))
    try:
        yield made
    finally:
        made.close()


def rate(events: Sequence[Event], subchain: str, since: float, until: float) -> float:
    times: list[float] = [
        e["t"] for e in of_kind(events, "run") if e["subchain"] == subchain and since <= e["t"] <= until
    ]
    assert len(times) >= 5, f"{subchain}: {len(times)} runs between {since:.1f} and {until:.1f} s"
    return (len(times) - 1) / (times[-1] - times[0])


def planned(events: Sequence[Event], subchain: str) -> float:
    plan = [e["plan"] for e in events if e["event"] in ("start", "resolve")][-1]
    return 1000.0 / float(plan["subchains"][subchain]["period_ms"])


def assert_rates_kept(events: Sequence[Event], since: float, until: float) -> None:
    for subchain in ("front", "map"):
        got, want = rate(events, subchain, since, until), planned(events, subchain)
        assert got == pytest.approx(want, rel=RATE_TOLERANCE), f"{subchain}: {got:.2f} Hz, planned {want:.2f} Hz"


def enforcer_cpu_s(pid: int) -> float:
    total = 0
    for tid in threads_of(pid):
        with contextlib.suppress(OSError, ValueError):
            total += int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
    return total / 1e9


# --------------------------------------------------------------------------- 1. no spin at real-time priority

REGISTER_MANY = """\
import os, socket, sys, threading
path, count = sys.argv[1], int(sys.argv[2])
tid = threading.get_native_id()
answered = 0
for _ in range(count):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("")
    sock.settimeout(0.05)
    sock.sendto(b"catanc/2 hello imu %d %d" % (os.getpid(), tid), path)
    try:
        sock.recvmsg(512, socket.CMSG_SPACE(4))  # the welcome (its ring fd is closed with the socket)
        answered += 1
    except OSError:
        pass
    sock.close()
print(answered, file=sys.stderr)
"""


def test_3000_registrations_of_one_thread_neither_spin_nor_outlive_the_duration(run: Run) -> None:
    """Today's receiver looped in the kernel at FIFO 4 after this, ignoring --duration and signals."""
    run.start(8.0)
    run.workers()
    before = enforcer_cpu_s(run.pid)
    flooder = run.spawn(REGISTER_MANY, str(run.socket), "3000")
    flooder.wait(timeout=60)
    after = enforcer_cpu_s(run.pid)
    flooded_s = time.monotonic() - run.began
    assert run.wait(8.0 + WAIT_S) == 0  # it ends when it should
    events = run.events()
    imu = [e for e in of_kind(events, "register") if e["node"] == "imu" and e["pid"] == flooder.pid]
    assert 1 <= len(imu) <= 2 * 10 + 10 * flooded_s  # a burst, then 10 a second: the rest are not even read
    assert after - before < 0.5 * flooded_s, "the enforcer spent half a core on it"
    end = of_kind(events, "stop")[0]["t"]
    assert_rates_kept(events, 2.5, end - 0.2)
    assert [e for e in of_kind(events, "gone") if e["node"] != "imu"] == []


# --------------------------------------------------------------------------- 2. forged completions

FORGING_NODE = """\
import mmap, struct, sys, time
from catanc.client import Node
from catanc.runtime.worker.burn import burn
with Node("map", socket_path=sys.argv[1]) as node:
    for trigger in node:
        burn(8.0)
        node.done(compute_ms=1e8)  # a thousand seconds per run: impossible
        ring = node._ring
        written = struct.unpack_from("=Q", ring, 16)[0]
        for seq in (10**9, trigger.seq + 5):  # runs that are not in flight
            struct.pack_into("=QQQQIIQ", ring, 64 + (written % 64) * 48, seq, 1, 2, 10**17, 1, 0, 0)
            written += 1
            struct.pack_into("=Q", ring, 16, written)
            node._written = written
"""


def test_forged_completions_are_dropped_and_impossible_times_clamped(run: Run) -> None:
    """Today one forged done with compute 1e8 ms dropped the other subchains to 0.2 Hz for good."""
    run.start(7.0)
    threads = run.workers()
    os.kill(threads["map"][0], signal.SIGKILL)  # the honest map worker: replaced by a forging one
    forger = run.spawn(FORGING_NODE, str(run.socket))
    poll(lambda: [e for e in of_kind(run.events(), "register") if e["pid"] == forger.pid], "the forging node")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as stranger:
        for _ in range(50):
            stranger.sendto(b"catanc/2 done map 1 1000000000", str(run.socket))
    assert run.wait(7.0 + WAIT_S) == 0, run.stderr()
    events = run.events()
    end = of_kind(events, "stop")[0]
    resolves = [e for e in of_kind(events, "resolve") if e["t"] > 3.0]
    assert resolves
    for resolve in resolves:  # the kernel's count bounds what map claims: ~8 ms, never 1e8
        assert resolve["compute_ms"]["map"] < 20.0, resolve["compute_ms"]
    front = rate(events, "front", 3.5, end["t"] - 0.2)
    assert front == pytest.approx(planned(events, "front"), rel=RATE_TOLERANCE)
    assert end["summary"]["subchains"]["map"]["unmatched"] > 0


# --------------------------------------------------------------------------- 3. peers that never read

DEAF_PEERS = """\
import os, socket, sys, threading, time
path, count = sys.argv[1], int(sys.argv[2])
tid = threading.get_native_id()
socks = []
for i in range(count):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("")
    name = (b"imu", b"nope%d" % i, b"map")[i % 3]  # a node, an unknown one, another's node
    sock.sendto(b"catanc/2 hello %s %d %d" % (name, os.getpid(), tid), path)
    socks.append(sock)  # never read
time.sleep(30)
"""


def test_peers_that_never_read_cannot_stop_the_scheduler(run: Run) -> None:
    """Today ~150 unanswered hellos filled the send buffer: every trigger failed, every node was declared gone."""
    run.start(6.0)
    run.workers()
    run.spawn(DEAF_PEERS, str(run.socket), "600")
    assert run.wait(6.0 + WAIT_S) == 0, run.stderr()
    events = run.events()
    assert [e for e in of_kind(events, "gone") if e["node"] in ("cam", "det", "map")] == []
    assert_rates_kept(events, 2.5, of_kind(events, "stop")[0]["t"] - 0.2)


# --------------------------------------------------------------------------- 4. the watchdog is watched


def test_the_watchdogs_death_puts_everything_back_and_stops_the_run(run: Run) -> None:
    """Today a SIGKILLed watchdog went unnoticed; a later SIGKILL of the enforcer left threads at FIFO for good."""
    plain = run.spawn("import time; time.sleep(60)")  # attached as imu: FIFO 3 while the run lasts
    run.start(30.0, "--attach", f"imu={plain.pid}")
    threads = run.workers()
    poll(lambda: (sched_of(plain.pid, plain.pid) or OTHER).policy == os.SCHED_FIFO, "imu attached at FIFO 3")
    watchdog = next(pid for pid in children_of(run.pid) if "watchdog" in cmdline(pid))
    os.kill(watchdog, signal.SIGKILL)
    sent = time.monotonic()
    code = run.wait()
    took = time.monotonic() - sent
    print(f"the watchdog's death: the enforcer exited {code} after {1000 * took:.0f} ms")
    assert code == ExitCode.SAFETY
    assert took < 3.0
    assert "the watchdog process died" in run.stderr()
    assert "Traceback" not in run.stderr()
    assert sched_of(plain.pid, plain.pid) == OTHER
    for pid, tid in threads.values():
        assert sched_of(pid, tid) in (None, OTHER)  # --demo workers are stopped; any left is back
    assert of_kind(run.events(), "watchdog")


# --------------------------------------------------------------------------- 5. who may do what


def as_nobody(uid: int, gid: int) -> list[str]:
    return [
        *("setpriv", f"--reuid={uid}", f"--regid={gid}", "--clear-groups"),
        *("--inh-caps=-all", "--ambient-caps=-all", "--bounding-set=-all"),
    ]


def test_the_default_socket_is_where_only_root_makes_files(run: Run, nobody: tuple[int, int]) -> None:
    table = compile_table(HOSTILE_SPEC, run.folder / "app", 1)
    argv = [sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--demo", "--duration", "3"]
    argv += ["--log", str(run.log)]
    with (run.folder / "enforcer.err").open("wb") as err:
        run.enforcer = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    path = Path("/run/catanc/hostile.sock")
    poll(lambda: path.exists() or run.enforcer.poll() is not None, "the socket in /run/catanc")  # type: ignore[union-attr]
    folder = path.parent.lstat()
    assert (folder.st_uid, folder.st_mode & 0o022) == (0, 0)  # root's, and only root may add files
    squat = subprocess.run(
        [*as_nobody(*nobody), "touch", str(path.parent / "squat.sock")], capture_output=True, check=False
    )
    assert squat.returncode != 0
    assert run.wait() == 0, run.stderr()
    assert not path.exists()


NOBODY_NODE = """\
import os, socket, sys
from client import Node  # the standalone client, copied beside this script
path, victim = sys.argv[1], int(sys.argv[2])
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.bind("")
sock.sendto(b"catanc/2 hello imu %d %d" % (victim, victim), path)  # another user's thread: refused
with Node("imu", socket_path=path) as node:  # its own thread: registered
    print("registered", node.registered, flush=True)
    node.wait(timeout_s=1.0)
"""
SYSTEM_PYTHON = "/usr/bin/python3"


def standalone_client(folder: Path) -> None:
    """catanc.client's file beside a script in ``folder``, readable by anyone: what a node of any user imports."""
    shutil.copyfile(Path(client_module.__file__), folder / "client.py")
    (folder / "client.py").chmod(0o644)


def test_another_users_node_registers_its_own_threads_only(run: Run, nobody: tuple[int, int]) -> None:
    if not Path(SYSTEM_PYTHON).exists():
        pytest.skip(f"needs {SYSTEM_PYTHON} for the other user's node")
    run.short.chmod(0o755)  # nobody reaches the socket (who may register is the enforcer's check)
    standalone_client(run.short)
    script = run.short / "node.py"
    script.write_text(NOBODY_NODE)
    script.chmod(0o644)
    run.start(4.0)
    run.workers()
    node = subprocess.run(
        [*as_nobody(*nobody), SYSTEM_PYTHON, str(script), str(run.socket), str(run.pid)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
        cwd="/",
    )
    assert "registered True" in node.stdout, node.stderr
    assert run.wait() == 0, run.stderr()
    events = run.events()
    imu = [e for e in of_kind(events, "register") if e["node"] == "imu"]
    assert imu
    assert run.pid not in [e["pid"] for e in imu]
    refused = [e for e in of_kind(events, "dropped") if "belongs to uid 0" in e["text"]]
    assert refused, [e["text"] for e in of_kind(events, "dropped")]


SET_CORES = """\
import socket, sys
socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM).sendto(b"catanc/2 set_cores " + sys.argv[2].encode(), sys.argv[1])
"""


def test_set_cores_comes_only_from_root_or_the_enforcers_user(run: Run, nobody: tuple[int, int]) -> None:
    if not Path(SYSTEM_PYTHON).exists():
        pytest.skip(f"needs {SYSTEM_PYTHON} for the other user's datagram")
    run.short.chmod(0o755)
    run.start(6.0)
    run.workers()
    nobody_sends = [*as_nobody(*nobody), SYSTEM_PYTHON, "-c", SET_CORES, str(run.socket), "2"]
    sent = subprocess.run(nobody_sends, capture_output=True, text=True, check=False, cwd="/", timeout=30)
    assert sent.returncode == 0, sent.stderr
    time.sleep(1.0)
    assert not [e for e in of_kind(run.events(), "resolve") if e["reason"] == "cores"]
    assert [e for e in of_kind(run.events(), "dropped") if "set_cores from uid" in e["text"]]
    set_cores = [sys.executable, "-m", "catanc", "set-cores", "2", "--socket", str(run.socket)]
    subprocess.run(set_cores, capture_output=True, check=True, timeout=30)
    poll(lambda: [e for e in of_kind(run.events(), "resolve") if e["reason"] == "cores"], "root's set-cores")
    assert run.wait() == 0, run.stderr()


def test_the_log_is_never_written_through_a_link(run: Run, tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    run.log.symlink_to(victim)
    table = compile_table(HOSTILE_SPEC, tmp_path / "app", 1)
    finished = subprocess.run(
        [
            *(sys.executable, "-c", ENFORCER_MAIN, "run", str(table), "--quiet", "--duration", "1"),
            *("--socket", str(run.socket), "--log", str(run.log)),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert finished.returncode == ExitCode.BAD_INPUT, finished.stderr
    assert "symbolic link" in finished.stderr
    assert victim.read_text() == "precious\n"


# --------------------------------------------------------------------------- 6. smaller things

GARBAGE = """\
import socket, sys, time
path = sys.argv[1]
kinds = [b"\\xff\\xfe", b"{}", b"catanc/1 hello x 1 2", b"catanc/2", b"catanc/2 dance", b"catanc/2 hello LM -1 2",
         b"catanc/2 trigger cam 1 1", b"catanc/2 welcome cam 64", b"catanc/2 stop", b"x" * 600,
         b"catanc/2 route cam 0 - 1 - -", b"catanc/2 bye cam 99999999", b"catanc/2 done cam 1 1"]
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.setblocking(False)
end, sent = time.monotonic() + 2.0, 0
while time.monotonic() < end:
    try:
        sock.sendto(kinds[sent % len(kinds)], path)
        sent += 1
    except BlockingIOError:
        time.sleep(0.0005)
    if sent % 30 == 0:
        time.sleep(0.01)  # about 3000 a second
print(sent, file=sys.stderr)
"""


def test_a_flood_of_bad_datagrams_is_reported_once_a_second_per_kind(run: Run) -> None:
    run.start(6.0)
    run.workers()
    flood = run.spawn(GARBAGE, str(run.socket))
    flood.wait(timeout=30)
    assert run.wait() == 0, run.stderr()
    events = run.events()
    dropped = of_kind(events, "dropped")
    by_kind: dict[str, int] = {}
    for event in dropped:
        by_kind[event["kind"]] = by_kind.get(event["kind"], 0) + 1
    assert by_kind, "the flood was not noticed"
    assert all(count <= 4 for count in by_kind.values()), by_kind  # 2 s of flood: once a second per kind
    assert sum(e["more"] for e in dropped) > 300  # the rest counted (up to the last report), not printed
    assert len(run.stderr().splitlines()) < 20
    assert_rates_kept(events, 2.5, of_kind(events, "stop")[0]["t"] - 0.2)


def test_the_measured_rate_decays_when_a_subchain_stops(run: Run) -> None:
    run.start(9.0)
    threads = run.workers()
    time.sleep(2.0)
    os.kill(threads["map"][0], signal.SIGSTOP)  # map's worker hangs: no more runs
    stopped_at = time.monotonic() - run.began
    assert run.wait(9.0 + WAIT_S) == 0, run.stderr()
    with contextlib.suppress(ProcessLookupError):
        os.kill(threads["map"][0], signal.SIGCONT)
    statuses = [e for e in of_kind(run.events(), "status") if e["t"] > stopped_at + 4.0]
    assert statuses
    assert all((e["subchains"]["map"]["measured_hz"] or 0.0) < 1.0 for e in statuses)
    assert all(e["subchains"]["front"]["measured_hz"] > 30.0 for e in statuses)


def test_a_killed_worker_leaves_the_others_running(run: Run) -> None:
    run.start(6.0)
    threads = run.workers()
    time.sleep(1.0)
    os.kill(threads["map"][0], signal.SIGKILL)
    assert run.wait() == 0, run.stderr()
    events = run.events()
    assert [e["node"] for e in of_kind(events, "gone")] in (["map"], [])  # seen when a trigger fails to go
    assert rate(events, "front", 2.5, of_kind(events, "stop")[0]["t"] - 0.2) == pytest.approx(
        planned(events, "front"), rel=RATE_TOLERANCE
    )


def test_sigkill_of_the_enforcer_puts_every_thread_back(run: Run) -> None:
    run.start(30.0)
    threads = run.workers()
    time.sleep(1.0)
    os.kill(run.pid, signal.SIGKILL)
    sent = time.monotonic()
    poll(
        lambda: all(sched_of(pid, tid) in (None, OTHER) for pid, tid in threads.values()),
        "every node thread back to SCHED_OTHER",
        step=0.002,
    )
    print(f"SIGKILL: every node thread back after {1000 * (time.monotonic() - sent):.1f} ms")
    assert not any(alive(pid) and "watchdog" in cmdline(pid) for pid in children_of(run.pid))
