"""The spec language: what an app developer writes (docs/reference/spec.md).

These pydantic models are the schema of record: ``catanc schema`` exports them
as JSON Schema.  They check the *shape* of a spec (types, ranges, unknown
keys).  Checks that need the whole spec (names, the DAG, subchain paths) live
in :mod:`catanc.model.problem`, which turns a valid ``Spec`` into the solver's view.

Units: milliseconds for times, hertz for rates.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    PrivateAttr,
    Tag,
    ValidationError,
    WithJsonSchema,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from catanc.spec.source import SourceMap
from catanc.spec.speedup import best_speedup

SPEC_VERSIONS = (1,)
"""The ``catan:`` versions this catanc reads."""

MODE_SHARE_TOLERANCE = 1e-6

IDENTIFIER_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
APP_NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_.-]*$"

Name = Annotated[str, Field(pattern=IDENTIFIER_PATTERN, description="An identifier.")]
MAX_QUANTITY = 1e9
"""The largest time (ms), rate (Hz) or weight a spec may give: a billion, far beyond any robot's (a run of 11.6
days, a GHz rate), and small enough that sums and products of them stay finite."""
PositiveMs = Annotated[float, Field(gt=0, le=MAX_QUANTITY, description="Milliseconds, > 0.")]
PositiveHz = Annotated[float, Field(gt=0, le=MAX_QUANTITY, description="Hertz, > 0.")]
HopMs = Annotated[float, Field(ge=0, le=MAX_QUANTITY, description="Milliseconds, >= 0.")]


def field_error(model: str, loc: tuple[str | int, ...], message: str, value: Any) -> ValidationError:
    """An error at a field below the model being validated (pydantic prefixes the model's own place)."""
    detail = InitErrorDetails(type=PydanticCustomError("value_error", message), loc=loc, input=value)
    return ValidationError.from_exception_data(model, [detail])


class _Model(BaseModel):
    """Base of every spec model: unknown keys are errors, no silent coercion."""

    model_config = ConfigDict(
        extra="forbid",
        strict=True,
        allow_inf_nan=False,
        frozen=True,
        populate_by_name=True,
    )


def _any_case_pattern(choices: tuple[str, ...]) -> str:
    """A JSON Schema pattern matching ``choices`` in any letter case (ECMA regexes have no ``(?i)``)."""
    options = ["".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else c for c in choice) for choice in choices]
    return f"^(?:{'|'.join(options)})$"


def lower_case_of(choices: tuple[str, ...]) -> BeforeValidator:
    """Read lower-case words in any case (``Hz``, ``HZ``) and store them lower-case.

    For words the ecosystem spells several ways.  A value that matches no
    choice is left as written, so its error quotes it as the user wrote it.
    """

    def canonical(value: Any) -> Any:
        if isinstance(value, str) and value.lower() in choices:
            return value.lower()
        return value

    return BeforeValidator(canonical)


def any_case_schema(choices: tuple[str, ...]) -> WithJsonSchema:
    """The JSON Schema of such a word: the choices (which editors offer) or the same in any case."""
    return WithJsonSchema(
        {"type": "string", "anyOf": [{"enum": list(choices)}, {"pattern": _any_case_pattern(choices)}]}
    )


# --------------------------------------------------------------------------- nodes


class Mode(_Model):
    """One mode of a multimodal compute profile."""

    share: float = Field(gt=0, le=1, description="Fraction of runs in this mode.")
    ms: PositiveMs


class ModalCompute(_Model):
    """A multimodal compute time: runs fall into modes with given shares."""

    modes: list[Mode] = Field(min_length=1)

    @field_validator("modes")
    @classmethod
    def _shares_sum_to_one(cls, modes: list[Mode]) -> list[Mode]:
        total = math.fsum(mode.share for mode in modes)
        if abs(total - 1.0) > MODE_SHARE_TOLERANCE:
            shares = " + ".join(f"{mode.share:g}" for mode in modes)
            raise ValueError(f"mode shares must sum to 1, got {shares} = {total:g}")
        return modes

    @property
    def mean_ms(self) -> float:
        return math.fsum(mode.share * mode.ms for mode in self.modes)


def _compute_kind(value: Any) -> str | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return "<ms>"
    if isinstance(value, dict | ModalCompute):  # a mapping when parsing, the model when dumping
        return "<modes>"
    return None


Compute = Annotated[
    Annotated[PositiveMs, Tag("<ms>")] | Annotated[ModalCompute, Tag("<modes>")],
    Discriminator(
        _compute_kind,
        custom_error_type="compute_kind",
        custom_error_message="expected a time in ms (e.g. 2.5) or {modes: [{share, ms}, ...]}",
    ),
]


class Threads(_Model):
    """How a node's compute time scales with threads."""

    max: int = Field(default=1, ge=1, le=1024, description="Most threads the node can use.")
    speedup: list[Annotated[float, Field(gt=0)]] | None = Field(
        default=None,
        description=(
            "speedup[q-1] = (time on 1 thread) / (time on q threads), for q = 1..max; "
            "speedup[0] is 1.  Omitted: perfect scaling (speedup q on q threads)."
        ),
    )

    @model_validator(mode="after")
    def _speedup_fits_max(self) -> Threads:
        if self.speedup is None:
            return self
        if len(self.speedup) != self.max:
            message = (
                f"speedup lists {len(self.speedup)} value(s) but threads.max is {self.max}: "
                f"give one speedup per thread count 1..{self.max}"
            )
            raise field_error("Threads", ("speedup",), message, self.speedup)
        if self.speedup[0] != 1.0:
            message = f"speedup[0] is the 1-thread speedup and must be 1.0, got {self.speedup[0]:g}"
            raise field_error("Threads", ("speedup", 0), message, self.speedup[0])
        return self

    @property
    def speedups(self) -> tuple[float, ...]:
        """Speedup with 1..max threads (perfect scaling when ``speedup`` is omitted)."""
        if self.speedup is None:
            return tuple(float(q) for q in range(1, self.max + 1))
        return tuple(self.speedup)

    def speedup_at(self, threads: int) -> float:
        return best_speedup(self.speedups, threads)


class Batch(_Model):
    """A batch node consumes every buffered input per run (like GL in nav2d)."""

    output_rate_hz: PositiveHz | None = Field(
        default=None,
        description="Observed rate of useful outputs; chains that start at this node use its period.",
    )


def _batch_kind(value: Any) -> str | None:
    if isinstance(value, bool):
        return "<flag>"
    if isinstance(value, dict | Batch):
        return "<options>"
    return None


BatchFlag = Annotated[
    Annotated[bool, Tag("<flag>")] | Annotated[Batch, Tag("<options>")],
    Discriminator(
        _batch_kind,
        custom_error_type="batch_kind",
        custom_error_message="expected true/false or {output_rate_hz: ...}",
    ),
]


# --------------------------------------------------------------------------- workload

JitterDistName = Literal["lognormal", "uniform", "normal"]
JITTER_DISTS: tuple[JitterDistName, ...] = ("lognormal", "uniform", "normal")
JitterDist = Annotated[JitterDistName, lower_case_of(JITTER_DISTS), any_case_schema(JITTER_DISTS)]

JITTER_MAX_CV = 2.0
"""Above this, run times are more noise than signal (lognormal: a median under half the mean)."""

SYMMETRIC_JITTER_MAX_CV = {"uniform": 0.5, "normal": 0.3}
"""Largest cv per symmetric distribution: a uniform stays in [0.13, 1.87] x compute; a normal
falls below 0 (and is redrawn) in under 0.05% of runs, so its mean stays 1 within 0.05%."""


class Growth(_Model):
    """Compute time that changes linearly over a run, then holds (e.g. a map that grows, paper section 4.5)."""

    start: float = Field(default=1.0, gt=0, description="Multiplier of compute_ms at t = 0 s.")
    end: float = Field(gt=0, description="Multiplier of compute_ms at t = over_s and after.")
    over_s: float = Field(gt=0, description="Seconds from the run's start until the multiplier reaches end.")


class Jitter(_Model):
    """Run-to-run noise: each run's time is multiplied by a draw with mean 1."""

    cv: float = Field(
        ge=0,
        le=JITTER_MAX_CV,
        description="Coefficient of variation (standard deviation / mean) of the multiplier, 0..2.",
    )
    dist: JitterDist = Field(
        default="lognormal",
        description=(
            "lognormal (default); uniform (cv <= 0.5); normal (cv <= 0.3, redrawn when not positive, "
            "which moves its mean by under 0.05%)."
        ),
    )

    @model_validator(mode="after")
    def _cv_fits_dist(self) -> Jitter:
        limit = SYMMETRIC_JITTER_MAX_CV.get(self.dist)
        if limit is not None and self.cv > limit:
            message = (
                f"a {self.dist} jitter takes cv <= {limit:g} (wider, it would reach 0 ms), got {self.cv:g}: "
                "use dist: lognormal for larger variation"
            )
            raise field_error("Jitter", ("cv",), message, self.cv)
        return self


class Spikes(_Model):
    """Rare expensive runs (e.g. GL's loop closures, paper section 4.5)."""

    every_s: float = Field(gt=0, description="Mean interval (s) between spike arrivals, a Poisson process.")
    ms: float = Field(
        gt=0,
        description="Time (ms) of the first run starting at or after an arrival, instead of its normal draw.",
    )


class Workload(_Model):
    """How a node's run times behave over a run, for simulation and synthetic workers; planning ignores it.

    A run draws a mode of compute_ms by share, multiplies it by growth at its
    start time, then by jitter; a pending spike replaces the whole draw.
    """

    growth: Growth | None = Field(default=None, description="Linear change of compute_ms over the run.")
    jitter: Jitter | None = Field(default=None, description="Multiplicative run-to-run noise with mean 1.")
    spikes: Spikes | None = Field(default=None, description="Rare runs that take a fixed, long time.")


class Node(_Model):
    """One task of the app DAG."""

    compute_ms: Compute | None = Field(
        default=None, description="Time of one run (ms), or a multimodal profile. Required when scheduled."
    )
    threads: Threads = Field(default_factory=Threads)
    scheduled: bool = Field(default=True, description="false: the scheduler never triggers this node.")
    rate_hz: PositiveHz | None = Field(
        default=None, description="Fixed rate of an unscheduled node (omit for a pure sink)."
    )
    batch: BatchFlag = Field(default=False, description="true or {output_rate_hz}: batch-processes inputs.")
    workload: Workload | None = Field(
        default=None,
        description=(
            "How run times vary over a run (growth, jitter, spikes), for simulation; "
            "compute_ms stays the figure planning uses."
        ),
    )

    @model_validator(mode="after")
    def _fields_fit_scheduling(self) -> Node:
        if self.scheduled:
            if self.compute_ms is None:
                raise ValueError("a scheduled node needs compute_ms (or set scheduled: false)")
            if self.rate_hz is not None:
                message = (
                    "rate_hz fixes the rate of an unscheduled node; for a scheduled node "
                    "use a constraint {node: ..., rate_hz: ...} or set scheduled: false"
                )
                raise field_error("Node", ("rate_hz",), message, self.rate_hz)
        elif self.is_batch:
            message = "an unscheduled node cannot be batch: batch applies to nodes the scheduler triggers"
            raise field_error("Node", ("batch",), message, self.batch)
        elif self.workload is not None:
            message = "an unscheduled node has no compute time for a workload to vary: remove workload"
            raise field_error("Node", ("workload",), message, self.workload)
        return self

    @property
    def is_batch(self) -> bool:
        return self.batch is not False

    @property
    def batch_output_rate_hz(self) -> float | None:
        return self.batch.output_rate_hz if isinstance(self.batch, Batch) else None

    @property
    def mean_compute_ms(self) -> float:
        """Planning compute time: the value, or the share-weighted mean of the modes."""
        if self.compute_ms is None:
            return 0.0
        if isinstance(self.compute_ms, ModalCompute):
            return self.compute_ms.mean_ms
        return float(self.compute_ms)

    def compute_ms_with(self, threads: int) -> float:
        """Compute time with at most ``threads`` threads (``c^q_j`` of Eq. 1)."""
        return self.mean_compute_ms / self.threads.speedup_at(threads)


# --------------------------------------------------------------------------- edges

EDGE_ARROW = "->"


def _edge_kind(value: Any) -> str | None:
    if isinstance(value, str):
        return "<arrow>"
    if isinstance(value, list):
        return "<pair>"
    return None


def parse_arrow(value: str) -> tuple[str, str]:
    parts = [part.strip() for part in value.split(EDGE_ARROW)]
    if len(parts) != 2 or not all(parts):
        raise ValueError(f"expected 'a -> b', got {value!r}")
    return parts[0], parts[1]


ARROW_EDGE_PATTERN = r"^\s*[A-Za-z_][A-Za-z0-9_]*\s*->\s*[A-Za-z_][A-Za-z0-9_]*\s*$"
ArrowEdge = Annotated[str, Field(pattern=ARROW_EDGE_PATTERN)]
PairEdge = Annotated[list[Name], Field(min_length=2, max_length=2)]

Edge = Annotated[
    Annotated[ArrowEdge, Tag("<arrow>")] | Annotated[PairEdge, Tag("<pair>")],
    Discriminator(
        _edge_kind,
        custom_error_type="edge_kind",
        custom_error_message="expected an edge as [a, b] or 'a -> b'",
    ),
]


# --------------------------------------------------------------------------- chains


def _through_kind(value: Any) -> str | None:
    if isinstance(value, str):
        return "<one>"
    if isinstance(value, list):
        return "<many>"
    return None


Through = Annotated[
    Annotated[Name, Tag("<one>")] | Annotated[list[Name], Tag("<many>")],
    Discriminator(
        _through_kind,
        custom_error_type="through_kind",
        custom_error_message="expected a node name or a list of node names",
    ),
]


class ChainSelector(_Model):
    """Every DAG path that starts at ``from``, visits ``through`` and ends at ``to``."""

    from_: Name | None = Field(default=None, alias="from", description="Start node (default: any source).")
    through: Through = Field(default_factory=list, description="Node(s) every path visits.")
    to: Name | None = Field(default=None, description="End node (default: any sink).")

    @property
    def through_nodes(self) -> list[str]:
        return [self.through] if isinstance(self.through, str) else list(self.through)


ChainPath = Annotated[list[Name], Field(min_length=1, description="Nodes of a DAG path, in order.")]
Weight = Annotated[float, Field(ge=0, le=MAX_QUANTITY, description="Weight in the objective, >= 0.")]


class ChainTerm(_Model):
    """Minimise the response time of one chain."""

    chain: ChainPath
    weight: Weight


class NodeTerm(_Model):
    """Minimise a node's period (maximise its throughput)."""

    node: Name
    weight: Weight


class ChainsTerm(_Model):
    """Minimise the response time of every chain a selector matches (each with this weight)."""

    chains: ChainSelector
    weight: Weight


def _kind_by_key(*keys: str) -> Callable[[Any], str | None]:
    """A union discriminator: the tag of the first of ``keys`` a mapping has."""

    def kind(value: Any) -> str | None:
        present = type(value).model_fields if isinstance(value, BaseModel) else value  # the model when dumping
        if isinstance(present, dict):
            for key in keys:
                if key in present:
                    return f"<{key}>"
        return None

    return kind


ObjectiveTerm = Annotated[
    Annotated[ChainTerm, Tag("<chain>")] | Annotated[NodeTerm, Tag("<node>")] | Annotated[ChainsTerm, Tag("<chains>")],
    Discriminator(
        _kind_by_key("chain", "node", "chains"),
        custom_error_type="term_kind",
        custom_error_message="an objective term needs one of chain: [...], node: NAME or chains: {from, through, to}",
    ),
]


def _rate_kind(value: Any) -> str | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return "<hz>"
    if isinstance(value, list):
        return "<offered>"
    return None


OfferedRates = Annotated[
    Annotated[PositiveHz, Tag("<hz>")] | Annotated[list[PositiveHz], Tag("<offered>")],
    Discriminator(
        _rate_kind,
        custom_error_type="rate_kind",
        custom_error_message="expected a rate in Hz (e.g. 30) or the rates the driver offers (e.g. [15, 30])",
    ),
]


class RateConstraint(_Model):
    """Bounds on a scheduled node's rate (hence on its subchain's)."""

    node: Name
    max_rate_hz: PositiveHz | None = None
    min_rate_hz: PositiveHz | None = None
    rate_hz: OfferedRates | None = Field(
        default=None,
        description=(
            "Fixed rate, or the rates the node's driver offers, ascending (e.g. a camera's [15, 30]): "
            "the plan runs its subchain at exactly one of them."
        ),
    )

    @model_validator(mode="after")
    def _bounds_consistent(self) -> RateConstraint:
        if self.max_rate_hz is None and self.min_rate_hz is None and self.rate_hz is None:
            raise ValueError("a node constraint needs max_rate_hz, min_rate_hz or rate_hz")
        if isinstance(self.rate_hz, list):
            self._check_offered(self.rate_hz)
        low, high = self.bounds_hz
        if low > high:
            raise ValueError(f"contradictory rate bounds: needs a rate >= {low:g} Hz and <= {high:g} Hz")
        return self

    def _check_offered(self, offered: list[float]) -> None:
        if not offered:
            message = "the offered-rate list is empty: list the rates the driver offers (e.g. [15, 30]) or drop it"
            raise field_error("RateConstraint", ("rate_hz",), message, offered)
        for index in range(1, len(offered)):
            if offered[index] <= offered[index - 1]:
                ascending = ", ".join(f"{rate:g}" for rate in sorted(set(offered)))
                message = (
                    f"offered rates must be ascending, each once: {offered[index]:g} Hz follows "
                    f"{offered[index - 1]:g} Hz (write [{ascending}])"
                )
                raise field_error("RateConstraint", ("rate_hz", index), message, offered[index])
        low = self.min_rate_hz if self.min_rate_hz is not None else 0.0
        high = self.max_rate_hz if self.max_rate_hz is not None else math.inf
        for index, rate in enumerate(offered):
            if not low <= rate <= high:
                side = f"above max_rate_hz {high:g}" if rate > high else f"below min_rate_hz {low:g}"
                message = f"offered rate {rate:g} Hz is {side} Hz: remove it from the list, or widen that bound"
                raise field_error("RateConstraint", ("rate_hz", index), message, rate)

    @property
    def offered_hz(self) -> tuple[float, ...]:
        """The rates a list ``rate_hz`` offers, ascending (one rate for a fixed rate; none without)."""
        if self.rate_hz is None:
            return ()
        return tuple(self.rate_hz) if isinstance(self.rate_hz, list) else (self.rate_hz,)

    @property
    def bounds_hz(self) -> tuple[float, float]:
        """The allowed rate interval ``[low, high]`` (Hz) this constraint states (offered rates: their span)."""
        offered = self.offered_hz
        low = max(x for x in (self.min_rate_hz, offered[0] if offered else None, 0.0) if x is not None)
        high = min(x for x in (self.max_rate_hz, offered[-1] if offered else None, math.inf) if x is not None)
        return low, high


class ChainConstraint(_Model):
    """An upper bound on one chain's response time."""

    chain: ChainPath
    max_response_ms: PositiveMs


class ChainsConstraint(_Model):
    """An upper bound on the response time of every chain a selector matches."""

    chains: ChainSelector
    max_response_ms: PositiveMs


Constraint = Annotated[
    Annotated[RateConstraint, Tag("<node>")]
    | Annotated[ChainConstraint, Tag("<chain>")]
    | Annotated[ChainsConstraint, Tag("<chains>")],
    Discriminator(
        _kind_by_key("node", "chain", "chains"),
        custom_error_type="constraint_kind",
        custom_error_message=(
            "a constraint needs node: NAME (with max_rate_hz/min_rate_hz/rate_hz) "
            "or chain: [...] / chains: {...} (with max_response_ms)"
        ),
    ),
]


# --------------------------------------------------------------------------- settings


class Schedule(_Model):
    """How shared cores run their periodic schedule."""

    order: list[Name] | None = Field(
        default=None, description="Subchain order inside one period (default: by descending weight)."
    )
    priorities: dict[Name, int] = Field(
        default_factory=dict, description="Stealing priority per subchain; higher steals from lower."
    )
    slack: float = Field(default=0.05, ge=0, lt=1, description="Idle share of each period (Linux caps FIFO at 95%).")
    switch_ms: float = Field(default=0.12, ge=0, description="Cost of one switch between subchains.")
    min_slice_ms: float = Field(default=1.0, ge=0, description="Smallest slice a subchain gets per period.")
    stealing: bool = Field(
        default=True,
        # Written out only when off: runtime tables of specs that keep the default stay as they were.
        exclude_if=bool,
        description="Priority stealing: a late subchain takes the slot of one of lower priority "
        "(false: the paper's ablation 'Catan w/o priority stealing', its Figure 9).",
    )


class Runtime(_Model):
    """How the runtime enforcer measures and re-solves."""

    window: int = Field(default=50, ge=1, description="Compute-time samples kept per node.")
    percentile: float = Field(default=95, gt=0, le=100, description="Percentile of the window planned with.")
    stage1_every_s: float = Field(default=20, gt=0)
    stage2_every_s: float = Field(default=5, gt=0)
    first_solve_after_s: float = Field(default=2, ge=0)
    bootstrap_ms: float = Field(default=5, gt=0, description="Compute time assumed per node before measuring.")


class Baseline(_Model):
    """The hand-tuned configuration catanc is compared with."""

    rates_hz: dict[Name, PositiveHz] = Field(
        default_factory=dict,
        description="Timer rate per node; unlisted nodes run when an input arrives.",
    )
    priorities: dict[Name, Annotated[int, Field(ge=0)]] = Field(
        default_factory=dict,
        # Written out only when given: runtime tables of specs without it stay as they were.
        exclude_if=lambda given: not given,
        description="fifo-static's SCHED_FIFO order per subchain, higher runs first (unlisted: 0); default: by "
        "importance, every subchain its own level. Never schedule.priorities, which rank catanc's own stealing.",
    )


RateUnitName = Literal["hz", "s", "ms"]
RATE_UNITS: tuple[RateUnitName, ...] = ("hz", "s", "ms")
RateUnit = Annotated[RateUnitName, lower_case_of(RATE_UNITS), any_case_schema(RATE_UNITS)]


class Deploy(_Model):
    """How one node is started and named in deployment artifacts."""

    ros_node: str | None = Field(default=None, description="Fully qualified ROS node name, e.g. /local_mapper.")
    rate_param: str | None = Field(default=None, description="Parameter that sets the node's rate.")
    rate_unit: RateUnit = Field(
        default="hz", description="Unit of rate_param: a rate in hz, or a period in s or ms (any case: Hz, S, MS)."
    )
    rate_type: Literal["float", "int"] = Field(
        default="float",
        description="Type of rate_param's value: float, or int for a node that reads an integer (rounded towards "
        "the slower rate: a rate in hz down, a period in s or ms up; a rate below 1 hz is an error).",
    )
    any_namespace: bool = Field(
        default=False,
        description="params.yaml keys the node /**/<ros_node>, so its parameters reach it under any namespace "
        "the launch adds (PushRosNamespace, a launch file's namespace).",
    )
    package: str | None = Field(default=None, description="ROS 2 package (for launch.py).")
    executable: str | None = Field(default=None, description="ROS 2 executable (for launch.py).")
    command: str | None = Field(default=None, description="Shell-free command line that starts the process.")
    process: str | None = Field(
        default=None,
        pattern=APP_NAME_PATTERN,
        description="The process the node runs in, by a name of your choice: nodes naming one process (several ROS "
        "nodes, e.g. a component container) share one command, the union of their CPUs and the highest level, "
        "and one executor thread when the command runs Python or no node names a callback_group. "
        "Default: its ROS node's process (or its own).",
    )
    callback_group: str | None = Field(
        default=None,
        description="The node's ROS 2 callback group as callback_isolated_executor's cie_thread_configurator "
        "names it: the node's full name, then its callbacks after '@' in the tool's order, Subscription(<topic>), "
        "Service(<name>), Client(<name>), Timer(<ns>), then Agnocast's (AgnocastSubscription(<topic>), ...), "
        "e.g. /node@Subscription(/scan)@Timer({period_ns}) ({period_ns} stands for the planned timer period); "
        "compile then also writes cie_thread_configurator.yaml.",
    )


# --------------------------------------------------------------------------- spec


class Spec(_Model):
    """A catanc app spec."""

    catan: int = Field(description="Spec language version.")
    app: str = Field(pattern=APP_NAME_PATTERN, description="App name; names the output folder.")
    nodes: dict[Name, Node] = Field(min_length=1)
    edges: list[Edge] = Field(default_factory=list)
    subchains: dict[Name, Annotated[list[Name], Field(min_length=1)]] = Field(default_factory=dict)
    objective: list[ObjectiveTerm] = Field(default_factory=list)
    constraints: list[Constraint] = Field(default_factory=list)
    schedule: Schedule = Field(default_factory=Schedule)
    runtime: Runtime = Field(default_factory=Runtime)
    baseline: Baseline = Field(default_factory=Baseline)
    deploy: dict[Name, Deploy] = Field(default_factory=dict)
    hops_ms: dict[ArrowEdge, HopMs] = Field(
        default_factory=dict,
        # Written out only when given: runtime tables of specs without hops stay as they were.
        exclude_if=lambda hops: not hops,
        description=(
            "Measured delay of an edge's data hop (ms, as `catanc profile --write` writes it): the producer's end "
            "to the consumer's start, e.g. 'LM -> LP': 1.2 for a ROS 2 topic between processes. Each edge inside "
            "a subchain adds its hop to the subchain's c(S); an edge not given has none. The consumer's own cost "
            "of receiving (an executor's take and deserialisation) is no hop: it is part of its compute_ms."
        ),
    )
    dispatch_ms: dict[Name, HopMs] = Field(
        default_factory=dict,
        # Written out only when given, as hops_ms.
        exclude_if=lambda dispatch: not dispatch,
        description=(
            "Measured delay from catanc's trigger of a subchain's head to the head's start (ms, as `catanc profile "
            "--write` writes it), e.g. scan: 0.7 for a ROS 2 head under catanc.ros (its trigger crosses a watcher "
            "thread and the executor's wake-up). The head's subchain adds it to its c(S), like a hop; a head not "
            "given has none (a shared core's switch_ms covers the enforcer's own switch)."
        ),
    )
    executors: dict[Name, Annotated[list[Name], Field(min_length=2)]] = Field(
        default_factory=dict,
        description=(
            "Nodes that share one single-threaded executor (one ROS process spinning one thread): "
            "name -> its scheduled nodes. They run one after the other, never at once, and are planned "
            "on one core set. A process of the deploy section implies one for its scheduled nodes when it is "
            "Python (its command runs python3, ...) or none of its nodes names a callback_group; an entry "
            "stays inside one process."
        ),
    )

    _source: SourceMap | None = PrivateAttr(default=None)

    @field_validator("catan")
    @classmethod
    def _known_version(cls, version: int) -> int:
        if version not in SPEC_VERSIONS:
            known = ", ".join(str(v) for v in SPEC_VERSIONS)
            raise ValueError(f"this catanc reads spec version {known}, not {version}")
        return version

    @property
    def edge_pairs(self) -> list[tuple[str, str]]:
        """Edges normalised to ``(a, b)`` pairs, in spec order."""
        return [parse_arrow(edge) if isinstance(edge, str) else (edge[0], edge[1]) for edge in self.edges]

    @property
    def source(self) -> SourceMap | None:
        """Where each field came from, if the spec was loaded from YAML."""
        return self._source


def json_schema() -> dict[str, Any]:
    """The JSON Schema of the spec, for editors (``catanc schema``)."""
    schema = Spec.model_json_schema(by_alias=True, mode="validation")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema, "title": "catanc spec"}


def json_schema_text() -> str:
    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"
