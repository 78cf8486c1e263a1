"""The results scenarios' spec variants, time buckets and statistics (benchmarks/scenarios.py writes docs/results).

Pure helpers that the benchmark and the tests share: an example spec as
YAML data, variants of it with one thing changed, the paper's 10 s
buckets of output periods and responses, and the mean with its 95%
interval over seeds.
"""

from __future__ import annotations

import copy
import itertools
import math
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml
from scipy import stats

SPECS = Path(__file__).resolve().parents[2] / "specs"
BUCKET_S = 10.0  # the paper's Figures 10-12 average the YOLO period over 10 s buckets


def spec_yaml(name: str) -> dict[str, Any]:
    loaded: dict[str, Any] = yaml.safe_load((SPECS / f"{name}.yaml").read_text())
    return loaded


@contextmanager
def spec_file(data: Mapping[str, Any]) -> Iterator[Path]:
    """``data`` as a spec file in a temporary folder (the real run's workers load it)."""
    with tempfile.TemporaryDirectory(prefix="catanc-scenario-") as folder:
        path = Path(folder) / f"{data['app']}.yaml"
        path.write_text(yaml.safe_dump(dict(data), sort_keys=False))
        yield path


def with_rates(data: Mapping[str, Any], rates: Mapping[str, float]) -> dict[str, Any]:
    """The spec with some hand-tuned baseline rates changed."""
    changed = copy.deepcopy(dict(data))
    changed["baseline"]["rates_hz"].update(rates)
    return changed


def with_baseline_rates(data: Mapping[str, Any], rates: Mapping[str, float]) -> dict[str, Any]:
    """The spec with its hand-tuned timers replaced by ``rates`` alone (the paper's Figure 12 runs a static
    plan's rates as timers under CFS: every other scheduled node then runs on new input)."""
    changed = copy.deepcopy(dict(data))
    changed["baseline"] = {"rates_hz": dict(rates)}
    return changed


DATASET = "Dataset"
"""The ILLIXR variant's offline sensor dataset: an unscheduled node that hands the camera a frame at its rate."""


def with_vsync_display_and_dataset(data: Mapping[str, Any], vsync_hz: float, dataset_hz: float) -> dict[str, Any]:
    """VR as ILLIXR runs it (the paper's section 7.3): Display shows a frame at every vsync, and Camera reads
    the newest frame of an offline dataset that produces ``dataset_hz`` frames a second (EuRoC: 20 Hz)."""
    changed = copy.deepcopy(dict(data))
    changed["nodes"]["Display"] = {**changed["nodes"]["Display"], "rate_hz": vsync_hz}
    changed["nodes"] = {DATASET: {"scheduled": False, "rate_hz": dataset_hz}, **changed["nodes"]}
    changed["edges"] = [f"{DATASET} -> Camera", *changed["edges"]]
    return changed


def with_growth_over(data: Mapping[str, Any], over_s: float) -> dict[str, Any]:
    """The spec with every growing node's growth compressed into ``over_s`` seconds."""
    changed = copy.deepcopy(dict(data))
    for node in changed["nodes"].values():
        growth = (node.get("workload") or {}).get("growth")
        if growth:
            growth["over_s"] = over_s
    return changed


def bucket_periods(done_ms: Sequence[float], duration_s: float) -> list[float | None]:
    """Per :data:`BUCKET_S` bucket, the mean gap (s) between consecutive outputs ending in it (the paper's)."""
    buckets: list[list[float]] = [[] for _ in range(math.ceil(duration_s / BUCKET_S))]
    for before, after in itertools.pairwise(done_ms):
        index = min(int(after / 1000.0 // BUCKET_S), len(buckets) - 1)
        buckets[index].append((after - before) / 1000.0)
    return [round(sum(gaps) / len(gaps), 3) if gaps else None for gaps in buckets]


def bucket_medians(samples: Sequence[tuple[float, float]], duration_s: float) -> list[float | None]:
    """Per :data:`BUCKET_S` bucket, the median response (ms) of the outputs in it."""
    buckets: list[list[float]] = [[] for _ in range(math.ceil(duration_s / BUCKET_S))]
    for done, value in samples:
        buckets[min(int(done / 1000.0 // BUCKET_S), len(buckets) - 1)].append(value)
    return [round(sorted(b)[len(b) // 2], 2) if b else None for b in buckets]


def t_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float]:
    """The mean of ``values`` and the half-width of its two-sided Student-t interval (n - 1 degrees of
    freedom, the sample standard deviation); NaN half-width for fewer than two values."""
    n = len(values)
    mean = math.fsum(values) / n
    if n < 2:
        return mean, math.nan
    deviation = math.sqrt(math.fsum((value - mean) ** 2 for value in values) / (n - 1))
    return mean, float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * deviation / math.sqrt(n)


def over_seeds(measured: Sequence[Any]) -> Any:
    """Per-seed measurements (equal nested dicts and lists of numbers) as one: each number becomes
    ``{"mean", "ci95", "n", "values"}`` (:func:`stat`); a list is summarised item by item."""
    first = measured[0]
    if isinstance(first, dict):
        return {key: over_seeds([m[key] for m in measured]) for key in first}
    if isinstance(first, list):
        width = max(len(m) for m in measured)
        return [over_seeds([m[i] if i < len(m) else None for m in measured]) for i in range(width)]
    return stat([m for m in measured if m is not None])


def stat(values: Sequence[float]) -> dict[str, Any] | None:
    """The mean over seeds and the half-width of its 95% t-interval (None: no seed had a value)."""
    if not values:
        return None
    mean, half = t_interval([float(v) for v in values])
    return {
        "mean": round(mean, 4),
        "ci95": None if math.isnan(half) else round(half, 4),
        "n": len(values),
        "values": [round(float(v), 4) for v in values],
    }


def paired_ratio(mine: Mapping[str, Any] | None, theirs: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """``mine / theirs - 1`` seed by seed (the same workload draws), as a :func:`stat`."""
    if mine is None or theirs is None or len(mine["values"]) != len(theirs["values"]):
        return None
    return stat([a / b - 1.0 for a, b in zip(mine["values"], theirs["values"], strict=True) if b])
