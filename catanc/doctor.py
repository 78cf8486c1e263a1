"""``catanc doctor``: does this machine give a plan what it needs?

Three steps, as the rest of catanc: :func:`needs_of` reads what a runtime
table asks for (the SCHED_FIFO priority, the cores and CPUs, the share of
each CPU its real-time threads keep), :func:`inspect_machine` reads this
machine's facts at the edge (privileges, RLIMIT_RTPRIO, a real SCHED_FIFO
probe, ``sched_rt_runtime_us``, the cgroup's real-time budget, the CPUs,
the tools ``launch.sh`` runs), and :func:`diagnose` compares them without
touching anything: one :class:`Finding` per check, saying what it found
and, when that falls short, how to fix it.

The compile machine need not be the target, so this runs on the target.
"""

from __future__ import annotations

import os
import resource
import shutil
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from catanc.artifacts.runtime_table import RuntimeTable
from catanc.errors import CatancError, Diagnostic, SpecError
from catanc.model.priorities import ENFORCER_FIFO
from catanc.runtime.compiled import ready as compiled_ready
from catanc.runtime.compiled.ready import LoopState
from catanc.runtime.linux.sched import check_fifo_allowed, fix_message, format_cpus, privilege_facts

LAUNCH_TOOLS = ("chrt", "setsid", "taskset")
"""What launch.sh runs besides the app (all from util-linux)."""
KERNEL = Path("/proc/sys/kernel")
DEFAULT_SLACK = 0.05  # the spec's default schedule.slack: shared cores keep 95% for real-time threads


class Verdict(Enum):
    OK = "ok"
    WARN = "warn"  # works, with a cost worth knowing
    FAIL = "FAIL"  # the plan cannot run as planned here


@dataclass(frozen=True)
class Finding:
    check: str
    verdict: Verdict
    found: str
    fix: str = ""


@dataclass(frozen=True)
class Needs:
    """What a plan asks of the machine it runs on."""

    fifo_priority: int  # the highest SCHED_FIFO priority it uses (the enforcer's threads)
    cores: int  # plan cores; the enforcer runs core i on the i-th CPU it may use
    cpus: frozenset[int]  # CPUs launch.sh and launch.py pin processes to, by number
    rt_share: float  # the share of each CPU its real-time threads keep (1 - schedule.slack)
    dedicated: tuple[str, ...]  # subchains with cores of their own: they may run back to back at SCHED_FIFO


ENFORCER_ONLY = Needs(ENFORCER_FIFO, 1, frozenset(), 1.0 - DEFAULT_SLACK, ())
"""Without a table: what ``catanc run`` needs for any plan."""


@dataclass(frozen=True)
class RtBudget:
    """Real-time time per period (``-1``: unlimited), as ``sched_rt_runtime_us`` / ``cpu.rt_runtime_us`` say."""

    runtime_us: int
    period_us: int

    @property
    def share(self) -> float:
        return 1.0 if self.runtime_us < 0 else self.runtime_us / self.period_us

    def __str__(self) -> str:
        if self.runtime_us < 0:
            return "unlimited (-1)"
        return f"{self.runtime_us} us of every {self.period_us} us ({self.share:.0%} of each CPU)"


@dataclass(frozen=True)
class CgroupBudget:
    """This process's cpu cgroup and its real-time budget (None: the kernel has no per-group budget)."""

    folder: Path
    path: str  # inside the hierarchy: ``/`` is the root group
    budget: RtBudget | None


@dataclass(frozen=True)
class Machine:
    """What decides whether a plan runs as planned here."""

    euid: int
    cap_sys_nice: bool | None  # None: unknown
    rtprio: int  # RLIMIT_RTPRIO's soft limit (what the kernel checks); resource.RLIM_INFINITY if unlimited
    fifo_refused: str | None  # why a real SCHED_FIFO probe was refused; None if it was allowed
    global_rt: RtBudget | None  # None: unreadable
    cgroup: CgroupBudget | None  # None: no cpu cgroup found
    allowed_cpus: frozenset[int]  # this process's affinity, within its cpuset
    online_cpus: frozenset[int]
    isolated_cpus: frozenset[int]
    missing_tools: tuple[str, ...]
    loop: LoopState  # whether catanc run's compiled loop is built here


# --------------------------------------------------------------------------- what a plan needs


def needs_of(table: RuntimeTable) -> Needs:
    """What ``table``'s plan asks for; :class:`SpecError` if its processes or subchains are malformed."""
    try:
        priorities = [int(process.get("priority", 0)) for process in table.processes]
        cpus = {int(cpu) for process in table.processes for cpu in process.get("cpus", [])}
        cpus.update(table.cpus[: table.cores] if table.cpus is not None else ())  # compile --cpus: the enforcer's
        plan: Mapping[str, Any] = table.plan if table.plan is not None else {}
        subchains = plan.get("subchains", {})
        dedicated = tuple(sorted(name for name, sub in subchains.items() if not sub.get("shared", True)))
    except (AttributeError, TypeError, ValueError):
        raise SpecError(
            [Diagnostic(None, "", f"{table.path}: processes or plan.subchains are not as catanc compile writes them")]
        ) from None
    return Needs(
        fifo_priority=max([ENFORCER_FIFO, *priorities]),
        cores=table.cores,
        cpus=frozenset(cpus),
        rt_share=1.0 - table.spec.schedule.slack,
        dedicated=dedicated,
    )


# --------------------------------------------------------------------------- comparing


def diagnose(needs: Needs, machine: Machine) -> list[Finding]:
    """One finding per check, in a fixed order; pure."""
    return [
        _privilege(needs, machine),
        _probe(needs, machine),
        _global_budget(needs, machine.global_rt),
        _cgroup_budget(needs, machine.cgroup),
        _cpus(needs, machine),
        _tools(machine),
        _loop(machine.loop),
    ]


def _privilege(needs: Needs, machine: Machine) -> Finding:
    check = "privilege"
    need = needs.fifo_priority
    if machine.euid == 0:
        return Finding(check, Verdict.OK, "root (euid 0)")
    if machine.cap_sys_nice:
        return Finding(check, Verdict.OK, f"euid {machine.euid} with CAP_SYS_NICE")
    limit = "unlimited" if machine.rtprio == resource.RLIM_INFINITY else str(machine.rtprio)
    if machine.rtprio == resource.RLIM_INFINITY or machine.rtprio >= need:
        return Finding(
            check,
            Verdict.OK,
            f"euid {machine.euid}, RLIMIT_RTPRIO {limit} >= {need}: enough for this user's own threads "
            "(catanc run --attach of another user's process needs root or CAP_SYS_NICE)",
        )
    cap = "CAP_SYS_NICE unknown" if machine.cap_sys_nice is None else "no CAP_SYS_NICE"
    return Finding(
        check,
        Verdict.FAIL,
        f"not root (euid {machine.euid}), {cap}, and RLIMIT_RTPRIO is {limit}: SCHED_FIFO {need} needs one of them",
        fix_message(need).removeprefix("Fix: "),
    )


def _probe(needs: Needs, machine: Machine) -> Finding:
    check = "SCHED_FIFO"
    need = needs.fifo_priority
    if machine.fifo_refused is None:
        return Finding(check, Verdict.OK, f"a test thread got SCHED_FIFO {need} (and was put back)")
    return Finding(
        check,
        Verdict.FAIL,
        f"the kernel refused a test thread: {machine.fifo_refused}",
        "see the privilege, sched_rt_runtime_us and cgroup checks: one of them says why",
    )


def _budget_verdict(needs: Needs, budget: RtBudget, check: str, fix: str, unthrottle: str) -> Finding:
    """The same rules for the global limit and a cgroup's: none or less than the plan keeps fails."""
    if budget.runtime_us == 0:
        return Finding(check, Verdict.FAIL, f"{budget}: real-time threads get no time at all", fix)
    if budget.share + 1e-9 < needs.rt_share:
        return Finding(
            check,
            Verdict.FAIL,
            f"{budget}: the plan gives real-time threads up to {needs.rt_share:.0%} of a shared core "
            f"(schedule.slack {1 - needs.rt_share:g})",
            fix,
        )
    if budget.share < 1.0 and needs.dedicated:
        return Finding(
            check,
            Verdict.WARN,
            f"{budget}: a subchain with a core of its own ({', '.join(needs.dedicated)}) that keeps its core busy "
            f"at SCHED_FIFO gets {budget.share:.0%} of it",
            unthrottle,
        )
    return Finding(check, Verdict.OK, str(budget))


GLOBAL_FIX = "sudo sysctl -w kernel.sched_rt_runtime_us=950000 (the kernel's default), and keep it in /etc/sysctl.d/"
GLOBAL_UNTHROTTLE = (
    "if that core must be all theirs: sudo sysctl -w kernel.sched_rt_runtime_us=-1 (no throttling: a runaway "
    "SCHED_FIFO thread can then starve its CPU)"
)


def _global_budget(needs: Needs, budget: RtBudget | None) -> Finding:
    check = "sched_rt_runtime_us"
    if budget is None:
        return Finding(check, Verdict.WARN, "cannot read /proc/sys/kernel/sched_rt_runtime_us")
    return _budget_verdict(needs, budget, check, GLOBAL_FIX, GLOBAL_UNTHROTTLE)


def _cgroup_budget(needs: Needs, cgroup: CgroupBudget | None) -> Finding:
    check = "cgroup"
    if cgroup is None:
        return Finding(check, Verdict.WARN, "cannot find this process's cpu cgroup in /proc/self/cgroup")
    if cgroup.budget is None:
        return Finding(
            check,
            Verdict.OK,
            f"{cgroup.path}: no per-cgroup real-time budget (no cpu.rt_runtime_us): the global limit applies",
        )
    if cgroup.path == "/":
        return Finding(check, Verdict.OK, "the root cgroup: its budget is sched_rt_runtime_us")
    file = cgroup.folder / "cpu.rt_runtime_us"
    fix = (
        f"give the cgroup a budget: echo 950000 > {file} (each parent needs at least as much); in Docker: "
        "docker run --cpu-rt-runtime=950000 --ulimit rtprio=99 (and dockerd --cpu-rt-runtime=950000 for its parent)"
    )
    unthrottle = f"if that core must be all theirs: echo {cgroup.budget.period_us} > {file} (the parents first)"
    finding = _budget_verdict(needs, cgroup.budget, check, fix, unthrottle)
    return Finding(check, finding.verdict, f"{cgroup.path}: cpu.rt_runtime_us {finding.found}", finding.fix)


def _cpus(needs: Needs, machine: Machine) -> Finding:
    check = "CPUs"
    usable = machine.allowed_cpus & machine.online_cpus
    here = f"this process may use CPUs {format_cpus(usable) or 'none'}"
    if machine.isolated_cpus:
        here += f" (isolated: {format_cpus(machine.isolated_cpus)})"
    missing = needs.cpus - usable
    problems = []
    if missing:
        problems.append(f"the plan pins processes to CPUs {format_cpus(needs.cpus)}; {format_cpus(missing)} not here")
    if len(usable) < needs.cores:
        problems.append(f"the plan has {needs.cores} cores, {len(usable)} CPUs here")
    if problems:
        return Finding(
            check,
            Verdict.FAIL,
            f"{'; '.join(problems)}: {here}",
            "run it where those CPUs are allowed (a container's cpuset: docker run --cpuset-cpus; the shell's "
            "affinity: taskset), or compile the plan for the cores there are (catanc compile --cores N, "
            "--cpus LIST)",
        )
    planned = f"the plan uses CPUs {format_cpus(needs.cpus)}; " if needs.cpus else ""
    return Finding(check, Verdict.OK, planned + here)


def _tools(machine: Machine) -> Finding:
    check = "tools"
    if machine.missing_tools:
        return Finding(
            check,
            Verdict.FAIL,
            f"launch.sh runs {', '.join(LAUNCH_TOOLS)}; not on PATH: {', '.join(machine.missing_tools)}",
            "install util-linux (apt-get install util-linux)",
        )
    return Finding(check, Verdict.OK, f"{', '.join(LAUNCH_TOOLS)} found")


def _loop(state: LoopState) -> Finding:
    check = "loop"
    if state is LoopState.READY:
        return Finding(check, Verdict.OK, "catanc run's compiled loop is built here (its default: the least CPU)")
    if state is LoopState.NO_NUMBA:
        return Finding(
            check,
            Verdict.WARN,
            "numba is not installed: catanc run uses its Python loop (about 1.6x the CPU of the compiled one)",
            "pip install numba (a wheel on Linux x86-64 and aarch64)",
        )
    return Finding(
        check,
        Verdict.WARN,
        "catanc run's compiled loop is not built here yet: a run uses the Python loop (about 1.6x the CPU) "
        "and builds it in the background for the next",
        "catanc run --loop compiled builds it before it starts (about a minute, once per machine and version)",
    )


def render(findings: Sequence[Finding], title: str) -> str:
    """Plain text: one line per check, its fix indented below, a verdict last."""
    width = max(len(finding.check) for finding in findings)
    lines = [title]
    for finding in findings:
        lines.append(f"{finding.verdict.value:<4}  {finding.check:<{width}}  {finding.found}")
        if finding.fix and finding.verdict is not Verdict.OK:
            lines.extend(
                f"      {'fix:' if i == 0 else '    '} {line}" for i, line in enumerate(finding.fix.splitlines())
            )
    failed = sum(finding.verdict is Verdict.FAIL for finding in findings)
    if failed:
        lines.append(f"{failed} check{'s' if failed > 1 else ''} failed: this machine cannot run the plan as planned")
    else:
        lines.append("this machine can run the plan")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- reading this machine


def inspect_machine(needs: Needs) -> Machine:
    """This process's facts (the probe tries ``needs.fifo_priority`` for real, on a helper thread)."""
    facts = privilege_facts()
    return Machine(
        euid=facts.euid,
        cap_sys_nice=facts.cap_sys_nice,
        rtprio=facts.rtprio_soft,
        fifo_refused=_fifo_refusal(needs.fifo_priority),
        global_rt=_read_budget(
            Path("/proc/sys/kernel/sched_rt_runtime_us"), Path("/proc/sys/kernel/sched_rt_period_us")
        ),
        cgroup=_read_cgroup(Path("/proc/self/cgroup"), Path("/proc/self/mountinfo")),
        allowed_cpus=frozenset(os.sched_getaffinity(0)),
        online_cpus=_read_cpu_list(Path("/sys/devices/system/cpu/online"), default=os.sched_getaffinity(0)),
        isolated_cpus=_read_cpu_list(Path("/sys/devices/system/cpu/isolated"), default=()),
        missing_tools=tuple(tool for tool in LAUNCH_TOOLS if shutil.which(tool) is None),
        loop=compiled_ready.state(),
    )


def _fifo_refusal(priority: int) -> str | None:
    try:
        check_fifo_allowed(priority)
    except CatancError as exc:
        return (str(exc).splitlines() or [type(exc).__name__])[0]
    return None


def _read_int(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def _read_budget(runtime: Path, period: Path) -> RtBudget | None:
    runtime_us, period_us = _read_int(runtime), _read_int(period)
    if runtime_us is None or period_us is None or period_us <= 0:
        return None
    return RtBudget(runtime_us, period_us)


def parse_cpu_list(text: str) -> frozenset[int]:
    """``0-2,5`` -> {0, 1, 2, 5}; an empty text is no CPU; ValueError if it is not a CPU list."""
    cpus: set[int] = set()
    for part in text.strip().split(","):
        if not part:
            continue
        low, dash, high = part.partition("-")
        first = int(low)
        last = int(high) if dash else first
        if first < 0 or last < first:
            raise ValueError(f"{part!r} is not a CPU range")
        cpus.update(range(first, last + 1))
    return frozenset(cpus)


def _read_cpu_list(path: Path, default: Iterable[int]) -> frozenset[int]:
    try:
        return parse_cpu_list(path.read_text())
    except (OSError, ValueError):
        return frozenset(default)


def _read_cgroup(cgroup_file: Path, mountinfo_file: Path) -> CgroupBudget | None:
    """The cpu cgroup of this process (cgroup v1's ``cpu`` controller, else v2's unified one) and its budget."""
    try:
        memberships = cgroup_file.read_text().splitlines()
        mounts = mountinfo_file.read_text().splitlines()
    except OSError:
        return None
    found = find_cpu_cgroup(memberships, mounts)
    if found is None:
        return None
    folder, path = found
    budget = _read_budget(folder / "cpu.rt_runtime_us", folder / "cpu.rt_period_us")
    return CgroupBudget(folder, path, budget)


def find_cpu_cgroup(memberships: Sequence[str], mounts: Sequence[str]) -> tuple[Path, str] | None:
    """``(folder, path in the hierarchy)`` of the cpu cgroup, from ``/proc/self/cgroup`` and ``mountinfo`` lines."""
    v1 = v2 = None
    for line in memberships:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        hierarchy, controllers, path = parts
        if "cpu" in controllers.split(","):
            v1 = path
        elif hierarchy == "0" and not controllers:
            v2 = path
    searches: list[tuple[str, str, str | None]] = []
    if v1 is not None:
        searches.append((v1, "cgroup", "cpu"))
    if v2 is not None:
        searches.append((v2, "cgroup2", None))
    for path, fstype, wanted in searches:
        for mount in mounts:
            fields = mount.split()
            if "-" not in fields:
                continue
            dash = fields.index("-")
            if len(fields) < dash + 4 or fields[dash + 1] != fstype:
                continue
            if wanted is not None and wanted not in fields[dash + 3].split(","):
                continue
            root, mountpoint = fields[3], fields[4]
            inside = path
            if root != "/" and (path == root or path.startswith(root + "/")):
                inside = path[len(root) :] or "/"
            return Path(mountpoint) / inside.lstrip("/"), path
    return None
