"""A ``catanc run`` log's compute samples, node by node: what ``catanc profile`` measures from.

Pure: :func:`read_samples` turns a log's text into :class:`LogSamples`.  The log must be
this catanc's format (:data:`~catanc.runtime.logs.writer.LOG_FORMAT`) and end with the enforcer's
``stop`` (a killed run's log is truncated); anything else is a :class:`MeasurementsError` naming
the file and line.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from catanc.control.measure import valid_sample
from catanc.errors import CatancError, ExitCode
from catanc.runtime.logs.writer import LOG_FORMAT, expand
from catanc.spec.language import parse_arrow

READ_FORMATS = (LOG_FORMAT,)
"""The log formats this catanc profiles."""


class MeasurementsError(CatancError):
    """A log ``catanc profile`` cannot use: not a log, another format, truncated, or missing a node."""

    exit_code = ExitCode.BAD_INPUT


@dataclass(frozen=True)
class Sample:
    """One run of a node, as the enforcer logged it."""

    ms: float  # one-thread compute time, what the runtime planned with
    threads: int  # threads the run used (1 where the log does not say)
    wall_ms: float | None  # the run's own figure (its wall time on several threads); None if unknown
    kernel_ms: float | None = None  # the kernel's count for the head's thread, on the runs it checked


@dataclass(frozen=True)
class HopFigures:
    """An edge's hops (or a head's dispatches) as the enforcer measured them (its last ``status`` or ``stop`` event's
    ``hop_by_edge``, ``dispatch_by_head``)."""

    p95_ms: float
    count: int


@dataclass(frozen=True)
class LogSamples:
    """Each node's compute samples from one log."""

    file: str
    samples: Mapping[str, tuple[Sample, ...]]  # node -> its samples, in log order
    first_line: Mapping[str, int]  # node -> the log line of its first sample
    length_s: float
    observed: bool = False  # a ``catanc run --observe`` log: the nodes ran on their own timers
    hops: Mapping[tuple[str, str], HopFigures] = field(default_factory=dict)  # (producer, consumer) -> its hops
    ages: Mapping[str, tuple[float, ...]] = field(default_factory=dict)  # node -> its runs' ends less their origins
    dispatches: Mapping[str, HopFigures] = field(default_factory=dict)  # head -> its triggers' delays to its starts


def read_samples(text: str, file: str) -> LogSamples:
    """The compute samples of a ``catanc run`` log's text; :class:`MeasurementsError` naming ``file`` and the line."""
    samples: dict[str, list[Sample]] = {}
    first_line: dict[str, int] = {}
    started = stopped = observed = False
    length = 0.0
    hops: dict[tuple[str, str], HopFigures] = {}
    dispatches: dict[str, HopFigures] = {}
    ages: dict[str, list[float]] = {}
    lines = text.splitlines()
    if not any(line.strip() for line in lines):
        raise MeasurementsError(f"{file}: empty: not a catanc run log")
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            torn = number == len(lines) and not text.endswith("\n")
            why = "a torn last line: the run was killed while writing" if torn else "not a JSON object"
            raise MeasurementsError(f"{file}:{number}: {why} (the log is truncated or corrupt)") from None
        if not isinstance(event, dict) or not isinstance(event.get("event"), str):
            raise MeasurementsError(f"{file}:{number}: not a catanc run log event (no `event` field)")
        if not started:
            _check_start(event, file, number)
            started, observed = True, event.get("observe") is True
            continue
        if isinstance(event.get("t"), int | float) and math.isfinite(event["t"]):
            length = max(length, float(event["t"]))
        if event["event"] == "stop":
            stopped = True
        if event["event"] in ("status", "stop"):
            hops = _hops(event) or hops
            dispatches = _dispatches(event) or dispatches
        for single in expand(event):
            if not isinstance(single, dict) or single.get("event") != "compute":
                continue
            node, ms = single.get("node"), single.get("ms")
            age = _number(single.get("age_ms"))
            if isinstance(node, str) and age is not None:
                ages.setdefault(node, []).append(age)
            if not isinstance(node, str) or not isinstance(ms, int | float) or not valid_sample(ms):
                continue
            threads = single.get("threads")
            samples.setdefault(node, []).append(
                Sample(
                    float(ms),
                    threads if isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1 else 1,
                    _number(single.get("reported_ms")),
                    _number(single.get("kernel_ms")),
                )
            )
            first_line.setdefault(node, number)
    if not stopped:
        raise MeasurementsError(
            f"{file}:{len(lines)}: truncated: the log ends without the enforcer's stop event "
            f"(the run was killed {length:.1f} s in?); profile a run that ended (--duration, Ctrl-C or SIGTERM)"
        )
    return LogSamples(
        file,
        {k: tuple(v) for k, v in samples.items()},
        first_line,
        length,
        observed,
        hops,
        {k: tuple(v) for k, v in ages.items()},
        dispatches,
    )


def _hops(event: dict[str, Any]) -> dict[tuple[str, str], HopFigures]:
    """The ``hop_by_edge`` figures of a ``status`` (its own) or ``stop`` event (its summary's); readable ones only."""
    found: dict[tuple[str, str], HopFigures] = {}
    for key, figures in _cost_figures(event, "hop_by_edge").items():
        try:
            found[parse_arrow(key)] = figures
        except ValueError:
            continue
    return found


def _dispatches(event: dict[str, Any]) -> dict[str, HopFigures]:
    """The ``dispatch_by_head`` figures of a ``status`` or ``stop`` event; readable ones only."""
    return _cost_figures(event, "dispatch_by_head")


def _cost_figures(event: dict[str, Any], field_name: str) -> dict[str, HopFigures]:
    """The readable figures (p95 and a positive count) by key of the event's ``costs.<field_name>``."""
    row = event.get("summary") if event["event"] == "stop" else event
    costs = row.get("costs") if isinstance(row, dict) else None
    by_key = costs.get(field_name) if isinstance(costs, dict) else None
    found: dict[str, HopFigures] = {}
    for key, figures in by_key.items() if isinstance(by_key, dict) else ():
        p95 = _number(figures.get("p95_ms")) if isinstance(figures, dict) else None
        count = figures.get("count") if isinstance(figures, dict) else None
        if p95 is not None and isinstance(count, int) and not isinstance(count, bool) and count > 0:
            found[str(key)] = HopFigures(p95, count)
    return found


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and valid_sample(value) else None


def _check_start(event: dict[str, Any], file: str, number: int) -> None:
    if event["event"] != "start":
        raise MeasurementsError(f"{file}:{number}: the log does not begin with a start event: not a catanc run log")
    version = event.get("format")
    readable = ", ".join(str(v) for v in READ_FORMATS)
    if version is None:
        raise MeasurementsError(
            f"{file}:{number}: log format missing: written by an older catanc (this one reads format {readable}); "
            "run catanc run again"
        )
    if version not in READ_FORMATS:
        raise MeasurementsError(f"{file}:{number}: log format {version!r}: this catanc reads format {readable}")
