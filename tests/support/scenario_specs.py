"""The results scenarios' spec variants and time buckets (benchmarks/scenarios.py writes docs/results with them).

Pure helpers that the benchmark and the tests share: an example spec as
YAML data, variants of it with one thing changed, and the paper's 10 s
buckets of output periods and responses.
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
