"""The runtime table, ``runtime.json`` (docs/reference/runtime-json.md): its one writer and its one reader.

A table is in format :data:`RUNTIME_FORMAT`; its shape is the typed
dictionaries below.  It imports neither jinja2 nor the explanation: the
enforcer reads tables with it, and ``catanc explain --json`` prints its plan.

Writing.  :func:`plan_payload` is the table's ``plan``.  It is deterministic:
times are rounded to :data:`MS_DIGITS` decimals (ms), fractions to
:data:`FRACTION_DIGITS`, rates to :data:`RATE_DIGITS`, and every derived
number is recomputed from the rounded ones, so the table is self-consistent
as written:

- each subchain's ``rate_hz`` is ``1000 / period_ms`` and ``slice_ms`` is
  ``fraction * c(S)`` (``c(S)`` from the problem, not printed);
- ``rate_as_run_hz``, only where an executor's thread takes some of ``rate_hz``
  (docs/explanation/executor-planning.md), is the planner's prediction of what is left:
  what ``catanc report`` holds the measured rate to;
- each chain's metrics are section 2 of docs/explanation/model.md over the rounded
  subchain timings and the rounded ``clocks`` (unscheduled nodes' periods);
- ``objective`` is :func:`catanc.model.metrics.objective` over those same numbers.

:func:`plan_json` dumps it with sorted keys, two-space indents and a final
newline: the same plan gives the same bytes.  :func:`runtime_json` is the
whole table: the plan, the processes, the normalised spec and where it came from.

Reading.  The table carries the normalised spec, so the enforcer re-plans
without the YAML.  :func:`load_table` refuses a table of another ``format``
and reports a broken one like a bad spec: file, line, field, what is wrong.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict, cast

from catanc.artifacts.provenance import Provenance
from catanc.errors import Diagnostic, FieldPath, Location, SpecError
from catanc.model.build import build_problem
from catanc.model.metrics import Timing, evaluate_chain, objective
from catanc.model.problem import Chain, Problem, Stage
from catanc.spec.language import Spec
from catanc.spec.parse import validate_data
from catanc.spec.source import SourceMap, parse_yaml, read_input

if TYPE_CHECKING:
    from catanc.planning.types import ChainPlan, Plan
    from catanc.spec.machine import MachineUse

RUNTIME_FORMAT = "catanc-runtime/1"
"""``runtime.json``'s ``format``: the enforcer refuses a table of another format."""


# --------------------------------------------------------------------------- the table's shape


class SubchainEntry(TypedDict):
    nodes: list[str]
    cores: list[int]
    shared: bool
    threads: int
    period_ms: float
    latency_ms: float
    rate_hz: float
    fraction: float
    slice_ms: float | None  # a shared subchain's slice per schedule period
    priority: int
    every: NotRequired[int]  # a shared non-batch subchain: triggered at its slot every k schedule periods
    rate_as_run_hz: NotRequired[float]  # where an executor's thread takes some of rate_hz: what is left


class CoreEntry(TypedDict):
    core: int
    period_ms: float
    order: list[str]


class ClockEntry(TypedDict):
    period_ms: float


class ChainEntry(TypedDict):
    nodes: list[str]
    subchains: list[str]
    head_period_ms: float | None
    latency_ms: float
    period_ms: float
    response_ms: float


class PlanPayload(TypedDict):
    objective: float
    constraint_scale: float
    subchains: dict[str, SubchainEntry]
    cores: list[CoreEntry]  # the shared cores
    clocks: dict[str, ClockEntry]  # unscheduled nodes' own clocks
    chains: list[ChainEntry]


class ProcessEntry(TypedDict):
    key: str
    ros_node: str | None
    nodes: list[str]
    argv: list[str]  # the spec's command; a launcher appends ros_arguments(params_file) to it
    params_file: NotRequired[str | None]  # beside the table, for a process hosting a ROS node (later field)
    ros_nodes: NotRequired[dict[str, list[str]]]  # a process of several ROS nodes: each one's DAG nodes
    package: str | None
    executable: str | None
    cpus: list[int]
    priority: int


class GeneratedBy(TypedDict):
    catanc: str
    command: str
    spec: str
    spec_sha256: str


PARAMS_FILE = "params.yaml"
"""The ROS parameters beside the table: every process hosting a ROS node is started with them."""


def ros_arguments(params_path: str) -> list[str]:
    """What every launcher appends to a ROS node's process command (docs/reference/runtime-json.md, ``params_file``).

    ``params_path`` is absolute: the process may run in any folder.
    """
    return ["--ros-args", "--params-file", params_path]


# --------------------------------------------------------------------------- writing


MS_DIGITS = 6
FRACTION_DIGITS = 9
RATE_DIGITS = 6
SCALE_DIGITS = 9


def ms(value: float) -> float:
    """A time as written in the table (ms)."""
    return round(value, MS_DIGITS)


def plan_payload(plan: Plan, problem: Problem) -> PlanPayload:
    """The runtime table's ``plan`` for ``plan`` (the problem it was planned for supplies ``c(S)`` and clocks)."""
    rounded = rounded_problem(problem)
    timings = {name: Timing(ms(sub.period_ms), ms(sub.latency_ms)) for name, sub in plan.subchains.items()}
    subchains: dict[str, SubchainEntry] = {}
    for name, sub in plan.subchains.items():
        fraction = round(sub.fraction, FRACTION_DIGITS)
        subchains[name] = {
            "nodes": list(sub.nodes),
            "cores": list(sub.cores),
            "shared": sub.shared,
            "threads": sub.threads,
            "period_ms": timings[name].period_ms,
            "latency_ms": timings[name].latency_ms,
            "rate_hz": round(1000.0 / timings[name].period_ms, RATE_DIGITS),
            "fraction": fraction,
            "slice_ms": ms(fraction * problem.subchain(name).compute_ms) if sub.shared else None,
            "priority": sub.priority,
        }
        if sub.every is not None:  # triggered at its slot every k periods: period_ms = k * the core's
            subchains[name]["every"] = sub.every
        if sub.period_as_run_ms is not None:
            subchains[name]["rate_as_run_hz"] = rate_as_run_hz(sub.period_as_run_ms)
    cores: list[CoreEntry] = [
        {"core": core.core, "period_ms": ms(core.period_ms), "order": list(core.order)}
        for core in sorted(plan.shared_cores, key=lambda c: c.core)
    ]
    chains: list[ChainEntry] = []
    for chain_plan in plan.chains:
        chain = _chain_of(chain_plan, rounded, plan)
        metrics = evaluate_chain(rounded, chain, timings)
        chains.append(
            {
                "nodes": list(chain_plan.nodes),
                "subchains": [stage.name for stage in chain.stages],
                "head_period_ms": chain.head_period_ms,
                "latency_ms": ms(metrics.latency_ms),
                "period_ms": ms(metrics.period_ms),
                "response_ms": ms(metrics.response_ms),
            }
        )
    return {
        "objective": ms(objective(rounded, timings)),
        "constraint_scale": round(plan.constraint_scale, SCALE_DIGITS),
        "subchains": subchains,
        "cores": cores,
        "clocks": {name: {"period_ms": period} for name, period in sorted(rounded.fixed_periods_ms.items())},
        "chains": chains,
    }


def rate_as_run_hz(period_as_run_ms: float) -> float:
    """A rate as run as the table writes it (the planner's prediction, not recomputed: 0 for no run at all)."""
    return round(1000.0 / period_as_run_ms, RATE_DIGITS) if math.isfinite(period_as_run_ms) else 0.0


def plan_json(plan: Plan, problem: Problem, **extra: Any) -> str:
    """``{"plan": plan_payload(...), **extra}`` as deterministic JSON text (sorted keys, final newline)."""
    return json.dumps({**extra, "plan": plan_payload(plan, problem)}, indent=2, sort_keys=True) + "\n"


def rounded_problem(problem: Problem) -> Problem:
    """``problem`` with its clocks and batch-head periods as the table writes them."""
    return replace(
        problem,
        fixed_periods_ms={name: ms(period) for name, period in problem.fixed_periods_ms.items()},
        chains=tuple(_rounded_head(chain) for chain in problem.chains),
    )


def _rounded_head(chain: Chain) -> Chain:
    if chain.head_period_ms is None:
        return chain
    return replace(chain, head_period_ms=ms(chain.head_period_ms))


def _chain_of(chain_plan: ChainPlan, problem: Problem, plan: Plan) -> Chain:
    """The problem's chain over these nodes; else one rebuilt from the plan's stage names."""
    for chain in problem.chains:
        if chain.nodes == chain_plan.nodes:
            return chain
    stages = tuple(Stage(name, fixed=name not in plan.subchains) for name in chain_plan.subchains)
    # A batch head's observed period depends on the head node alone: any chain from it knows it.
    head = next((c.head_period_ms for c in problem.chains if c.nodes[0] == chain_plan.nodes[0]), None)
    return Chain(chain_plan.nodes, stages, head)


def runtime_json(
    spec: Spec,
    problem: Problem,
    plan: Plan,
    provenance: Provenance,
    processes: Iterable[ProcessEntry],
    *,
    machine: MachineUse | None = None,
    cpus: tuple[int, ...] | None = None,
) -> str:
    """The runtime table (docs/reference/runtime-json.md): the plan, processes, origin, the machine profile used.

    ``cpus`` (``compile --cpus``): the CPUs plan core 0, 1, ... run on, listed under ``cpus``; the plan's
    ``cores`` stay plan cores, the processes' ``cpus`` are these CPUs.  Without it there is no ``cpus``
    and plan core ``i`` is the ``i``-th CPU the enforcer may use.
    """
    generated_by: GeneratedBy = {
        "catanc": provenance.version,
        "command": provenance.command,
        "spec": provenance.spec_name,
        "spec_sha256": provenance.spec_sha256,
    }
    table: dict[str, Any] = {
        "format": RUNTIME_FORMAT,
        "generated_by": generated_by,
        "app": spec.app,
        "cores": plan.cores,
        "plan": plan_payload(plan, problem),
        "processes": list(processes),
    }
    if machine is not None:
        table["machine"] = machine.record()
    if cpus is not None:
        table["cpus"] = list(cpus)
    # Keys sorted, except inside the spec: its order of nodes and subchains breaks ties between plans.
    ordered = {**sorted_keys(table), "spec": normalised_spec(spec)}
    return json.dumps(dict(sorted(ordered.items())), indent=2, allow_nan=False, ensure_ascii=False) + "\n"


def sorted_keys(data: Any) -> Any:
    """``data`` with every mapping's keys in sorted order."""
    if isinstance(data, dict):
        return {key: sorted_keys(data[key]) for key in sorted(data)}
    if isinstance(data, list):
        return [sorted_keys(item) for item in data]
    return data


def normalised_spec(spec: Spec) -> dict[str, Any]:
    """The spec with every default written out, as JSON data ``Spec.model_validate`` reads back."""
    data: dict[str, Any] = spec.model_dump(mode="json", by_alias=True)
    if not data["executors"]:
        del data["executors"]  # a later field: tables of specs without executors stay as they were
    for entry in data["deploy"].values():  # later fields too: written only where not the default
        for field, default in LATER_DEPLOY_DEFAULTS.items():
            if entry.get(field) == default:
                del entry[field]
    return data


LATER_DEPLOY_DEFAULTS = {"rate_type": "float", "any_namespace": False, "process": None}
"""Fields ``deploy.<node>`` gained after tables were first written, with their defaults."""


# --------------------------------------------------------------------------- reading


MAX_TABLE_BYTES = 16 * 1024 * 1024
"""The largest runtime table read (a real one is tens of kilobytes)."""

REQUIRED = {"format": str, "app": str, "cores": int, "spec": dict, "plan": dict, "processes": list}


@dataclass(frozen=True)
class RuntimeTable:
    """A table as read back: the enforcer starts from its spec (it re-plans) and its processes."""

    path: Path
    app: str
    cores: int
    spec: Spec
    plan: PlanPayload | None  # the table's ``plan`` (None: a table made in memory, with no plan written)
    processes: tuple[ProcessEntry, ...]
    cpus: tuple[int, ...] | None = None  # ``compile --cpus``: the CPUs plan cores run on, ascending


def load_table(path: str | Path) -> RuntimeTable:
    """Read and check a runtime table; raise :class:`SpecError` naming the file, line and field."""
    file = str(path)
    try:
        text = read_input(path, MAX_TABLE_BYTES).decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise SpecError([Diagnostic(None, "", f"{file}: cannot read the runtime table: {reason}")]) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        location = Location(file, exc.lineno, exc.colno)
        raise SpecError([Diagnostic(location, "", f"not JSON: {exc.msg}")]) from None
    except RecursionError:
        raise SpecError([Diagnostic(Location(file, 1, 1), "", "nested too deeply for a runtime table")]) from None
    try:
        return _checked(Path(path), data, SourceMap(file))
    except SpecError:  # again with the lines and columns, which cost a YAML parse (~80 ms) to find
        return _checked(Path(path), data, _source_map(text, file))


def _checked(path: Path, data: Any, source: SourceMap) -> RuntimeTable:
    """The table in ``data``; :class:`SpecError` where it is wrong, located in ``source``."""

    def fail(field: FieldPath, message: str) -> SpecError:
        return SpecError([Diagnostic(source.locate(field), ".".join(map(str, field)), message)])

    if not isinstance(data, dict):
        raise fail((), "a runtime table is a JSON object (written by `catanc compile`)")
    found = data.get("format")
    if found != RUNTIME_FORMAT:
        what = "has no format" if found is None else f"is in format {found!r}"
        raise fail(
            ("format",),
            f"this table {what}; this catanc reads {RUNTIME_FORMAT!r}: regenerate it with `catanc compile`",
        )
    for key, kind in REQUIRED.items():
        value = data.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise fail((key,) if key in data else (), f"missing or not a {kind.__name__}: {key!r}")
    spec = _spec(data["spec"], source)
    if spec.app != data["app"]:
        raise fail(("app",), f"the table is for app {data['app']!r} but its spec is for {spec.app!r}")
    if data["cores"] < 1:
        raise fail(("cores",), "at least one core")
    cpus = data.get("cpus")
    if cpus is not None:
        numbers = cpus if isinstance(cpus, list) else []
        if not numbers or not all(isinstance(cpu, int) and not isinstance(cpu, bool) and cpu >= 0 for cpu in numbers):
            raise fail(("cpus",), "a list of CPU numbers (written by `catanc compile --cpus`)")
        if numbers != sorted(set(numbers)):
            raise fail(("cpus",), "CPU numbers in ascending order, each once")
        if len(numbers) < data["cores"]:
            raise fail(("cpus",), f"{len(numbers)} CPUs for {data['cores']} cores")
    return RuntimeTable(
        path=path,
        app=data["app"],
        cores=data["cores"],
        spec=spec,
        plan=cast("PlanPayload", data["plan"]),
        processes=tuple(cast("list[ProcessEntry]", data["processes"])),
        cpus=tuple(cpus) if cpus is not None else None,
    )


def _source_map(text: str, file: str) -> SourceMap:
    """Lines and columns of the table's fields (JSON is YAML); none if YAML cannot read it."""
    try:
        return parse_yaml(text, file).source
    except SpecError:
        return SourceMap(file)


def _spec(data: dict[str, Any], table: SourceMap) -> Spec:
    """The table's spec, checked as a spec file would be; diagnostics name ``spec.<field>``."""
    inner = SourceMap(
        table.file,
        values={path[1:]: where for path, where in table.values.items() if path[:1] == ("spec",)},
        keys={path[1:]: where for path, where in table.keys.items() if path[:1] == ("spec",)},
    )
    try:
        spec = validate_data(data, inner)
        build_problem(spec)
    except SpecError as exc:
        raise SpecError(
            [Diagnostic(d.location, f"spec.{d.field}" if d.field else "spec", d.message) for d in exc.diagnostics]
        ) from None
    return spec
