"""The machine profile: the runtime's measured costs on one machine, and the schedule they imply.

``catanc calibrate`` measures them and writes the profile; ``catanc compile
--machine FILE`` and ``explain --machine FILE`` plan with them, so a
committed plan is enforceable on its target (docs/explanation/model.md section 5).
The file is small YAML:

.. code-block:: yaml

    format: catanc-machine/1
    machine: {host: rig-7, cpu: "Intel i7-8650U", kernel: 6.8.0-45-generic, cpus: 8}
    switch_ms: 0.045       # one slot switch of the enforcer (p95)
    hop_ms: 0.030          # a trigger or a node's completion to the next node's start (p95)
    wake_ms: 0.020         # the enforcer's own CPU per wake-up (mean; optional, 0 if absent)
    overhead: [0.011, 0.009]   # the enforcer's own CPU share on each core measured
    rt: {runtime_us: 950000, period_us: 1000000}   # /proc/sys/kernel/sched_rt_{runtime,period}_us

What the plan uses (never below the spec's values), each cost counted once:

- ``slack = max(spec slack, 1 - rt_limit + max(overhead))``: SCHED_FIFO
  threads together get at most ``rt_limit = runtime_us / period_us`` of each
  core (``runtime_us = -1``: no limit, 1), and the enforcer, itself
  SCHED_FIFO, takes its measured share of that budget first (all of its CPU,
  its switches and triggers included); the plan may use the rest.
- ``switch_ms = max(spec switch_ms, hop_ms - wake_ms)``: what each slot of a
  shared core costs beyond the enforcer's CPU: its head's wake-up (the hop
  from its trigger to its start, less the enforcer's own CPU in that hop,
  which the slack holds already).  The switch latency is not charged: its
  CPU is the enforcer's (in the slack) and the rest is the enforcer waking
  late, a delay while the core runs the slot before it, not CPU taken from
  the plan.  Charging both (``switch_ms + hop_ms`` beside the overhead) ran
  VR's 1-core plan at half its Render rate on a VM whose kernel ran the
  full rate (docs/results.md, section 4).
"""

from __future__ import annotations

import hashlib
from collections.abc import Hashable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from catanc.errors import Diagnostic, FieldPath, Location, SpecError, format_path
from catanc.spec.language import Schedule, Spec, field_error
from catanc.spec.source import SourceMap, parse_yaml, read_text

MACHINE_FORMAT = "catanc-machine/1"
"""The ``format`` this catanc reads and writes."""

RT_UNLIMITED = -1
"""``sched_rt_runtime_us = -1``: the kernel does not throttle SCHED_FIFO threads."""


class ProfileError(SpecError):
    """A machine profile is missing, unreadable, of another format, or holds impossible values (exit 2)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class MeasuredOn(_Model):
    """The machine the profile was measured on (for people: planning never reads it)."""

    host: str = Field(description="Host name.")
    cpu: str | None = Field(default=None, description="CPU model.")
    kernel: str | None = Field(default=None, description="Kernel release (uname -r).")
    cpus: int | None = Field(default=None, ge=1, description="Online CPUs.")


class RtLimit(_Model):
    """The kernel's real-time throttle: SCHED_FIFO threads get ``runtime_us`` of every ``period_us``."""

    runtime_us: int = Field(description="/proc/sys/kernel/sched_rt_runtime_us (-1: unlimited).")
    period_us: int = Field(gt=0, description="/proc/sys/kernel/sched_rt_period_us.")

    @model_validator(mode="after")
    def _a_share_of_the_period(self) -> RtLimit:
        if self.runtime_us != RT_UNLIMITED and not 0 < self.runtime_us <= self.period_us:
            message = (
                f"the RT limit runtime_us / period_us = {self.runtime_us} / {self.period_us} must be in (0, 1] "
                "(or runtime_us: -1, unlimited)"
            )
            raise field_error("RtLimit", ("runtime_us",), message, self.runtime_us)
        return self

    @property
    def share(self) -> float:
        """The share of each core SCHED_FIFO threads may use (1.0: unlimited)."""
        return 1.0 if self.runtime_us == RT_UNLIMITED else self.runtime_us / self.period_us


class MachineProfile(_Model):
    """What ``catanc calibrate`` measured on one machine."""

    format: str = Field(description=f"Profile format; this catanc reads {MACHINE_FORMAT}.")
    machine: MeasuredOn
    switch_ms: float = Field(ge=0, description="The enforcer's cost of one slot switch (ms).")
    hop_ms: float = Field(ge=0, description="A trigger or a node's completion to the next node's start (ms).")
    wake_ms: float = Field(default=0.0, ge=0, description="The enforcer's own CPU per wake-up (ms); 0: unknown.")
    overhead: list[float] = Field(min_length=1, description="The enforcer's CPU share on each core measured, 0..1.")
    rt: RtLimit

    @model_validator(mode="after")
    def _overhead_shares(self) -> MachineProfile:
        for index, share in enumerate(self.overhead):
            if not 0 <= share < 1:
                message = f"an overhead is a share of one core, in [0, 1), got {share:g}"
                raise field_error("MachineProfile", ("overhead", index), message, share)
        return self


@dataclass(frozen=True)
class MachineFile:
    """A checked profile, its file name (no folder: outputs never hold absolute paths) and its bytes' sha256."""

    profile: MachineProfile
    name: str
    sha256: str
    source: SourceMap | None = None


@dataclass(frozen=True)
class Costs:
    """The schedule's two cost settings: the spec's, the profile's, and what the plan uses."""

    spec_switch_ms: float
    spec_slack: float
    measured_switch_ms: float  # hop - wake: a slot's cost beyond the enforcer's CPU
    measured_slack: float  # 1 - rt_limit + max overhead
    switch_ms: float
    slack: float


@dataclass(frozen=True)
class MachineUse:
    """Which profile a plan was made with, and the values it used: what the table and PLAN.md record."""

    name: str
    sha256: str
    host: str
    costs: Costs
    cpu: str | None = None  # the CPU model measured on, for the thread configurator's hardware check
    rt: RtLimit | None = None  # the kernel's SCHED_FIFO budget measured

    def record(self) -> dict[str, Any]:
        """``runtime.json``'s ``machine`` entry (deterministic: no path, no time)."""
        costs = self.costs
        return {
            "format": MACHINE_FORMAT,
            "profile": self.name,
            "profile_sha256": self.sha256,
            "measured_on": self.host,
            "switch_ms": {"spec": costs.spec_switch_ms, "measured": costs.measured_switch_ms, "used": costs.switch_ms},
            "slack": {"spec": costs.spec_slack, "measured": costs.measured_slack, "used": costs.slack},
        }

    def sentence(self) -> str:
        """One line for ``explain`` and PLAN.md."""
        costs = self.costs
        return (
            f"Machine profile {self.name} (measured on {self.host}, sha256 {self.sha256[:12]}): "
            f"switch_ms {costs.switch_ms:.4g} (spec {costs.spec_switch_ms:.4g}, measured hop beyond the enforcer's CPU "
            f"{costs.measured_switch_ms:.4g}), slack {costs.slack:.4g} (spec {costs.spec_slack:.4g}, "
            f"measured 1 - RT limit + overhead {costs.measured_slack:.4g})."
        )


def costs(schedule: Schedule, profile: MachineProfile) -> Costs:
    """The module docstring's formulas."""
    measured_switch = max(profile.hop_ms - profile.wake_ms, 0.0)
    measured_slack = 1.0 - profile.rt.share + max(profile.overhead)
    return Costs(
        spec_switch_ms=schedule.switch_ms,
        spec_slack=schedule.slack,
        measured_switch_ms=measured_switch,
        measured_slack=measured_slack,
        switch_ms=max(schedule.switch_ms, measured_switch),
        slack=max(schedule.slack, measured_slack),
    )


def apply_machine(spec: Spec, machine: MachineFile) -> tuple[Spec, MachineUse]:
    """``spec`` with its schedule's costs raised to cover the profile's; raise :class:`ProfileError` if none can."""
    found = costs(spec.schedule, machine.profile)
    if found.slack >= 1.0:
        overhead = max(machine.profile.overhead)
        share = machine.profile.rt.share
        message = (
            f"the enforcer's overhead {overhead:g} takes the whole RT limit {share:g}: nothing is left to plan "
            "(measure again on a quieter machine, or raise sched_rt_runtime_us)"
        )
        index = machine.profile.overhead.index(overhead)
        raise ProfileError([_diagnostic(machine.name, machine.source, ("overhead", index), message)])
    schedule = spec.schedule.model_copy(update={"switch_ms": found.switch_ms, "slack": found.slack})
    planned = spec.model_copy(update={"schedule": schedule})
    measured_on = machine.profile.machine
    return planned, MachineUse(
        machine.name, machine.sha256, measured_on.host, found, measured_on.cpu, machine.profile.rt
    )


# --------------------------------------------------------------------------- reading and writing


def read_machine(path: str | Path) -> MachineFile:
    """Read and check a profile; raise :class:`ProfileError` naming the file and field on any problem."""
    file = str(path)
    try:
        raw, text = read_text(path, "machine profile")
        parsed = parse_yaml(text, file)
    except SpecError as exc:
        raise ProfileError(exc.diagnostics) from None
    if parsed.problems:
        raise ProfileError(parsed.problems)
    profile = _validate(parsed.data, parsed.source)
    return MachineFile(profile, Path(path).name, hashlib.sha256(raw).hexdigest(), parsed.source)


def profile_text(profile: MachineProfile) -> str:
    """The profile as YAML, fields in the documented order (same profile, same bytes)."""
    data = profile.model_dump(mode="json")
    return f"# catanc machine profile ({MACHINE_FORMAT})\n" + yaml.safe_dump(data, sort_keys=False)


def _validate(data: Any, source: SourceMap) -> MachineProfile:
    if not isinstance(data, dict):
        message = f"a machine profile is a mapping starting with `format: {MACHINE_FORMAT}`"
        raise ProfileError([Diagnostic(source.locate(()), "", message)])
    kind = data.get("format")
    if kind != MACHINE_FORMAT:
        found = "no format" if kind is None else f"format {kind!r}"
        message = f"this catanc reads machine profiles of format {MACHINE_FORMAT}, not {found}: run catanc calibrate"
        path: FieldPath = ("format",) if "format" in data else ()
        raise ProfileError([_diagnostic(source.file, source, path, message)])
    try:
        return MachineProfile.model_validate(data)
    except ValidationError as exc:
        diagnostics = []
        for error in exc.errors(include_url=False):
            path = _existing(tuple(error["loc"]), data)
            ctx = error.get("ctx") or {}
            text = str(ctx.get("error", error["msg"])) if error["type"] == "value_error" else _reworded(error)
            diagnostics.append(_diagnostic(source.file, source, path, text))
        raise ProfileError(diagnostics) from None


def _reworded(error: Any) -> str:
    kind: str = error["type"]
    ctx: dict[str, Any] = error.get("ctx") or {}
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()))
        return f"must be {op} {bound:g}, got {error.get('input')!r}"
    if kind == "missing":
        return f"missing required field {error['loc'][-1]!r}"
    if kind == "extra_forbidden":
        return f"unknown field {error['loc'][-1]!r}"
    return f"{error['msg']}, got {error.get('input')!r}"


def _existing(loc: tuple[Hashable, ...], data: Any) -> FieldPath:
    """The part of a pydantic location that is in the data (a missing field: its parent's path plus its name)."""
    path: list[Hashable] = []
    node = data
    for part in loc:
        path.append(part)
        in_mapping = isinstance(node, dict) and part in node
        in_list = isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node)
        if not (in_mapping or in_list):
            break
        node = node[part]
    return tuple(path)


def _diagnostic(file: str, source: SourceMap | None, path: FieldPath, message: str) -> Diagnostic:
    location = source.locate(path) if source is not None else Location(file, 1, 1)
    return Diagnostic(location, format_path(path), message)
