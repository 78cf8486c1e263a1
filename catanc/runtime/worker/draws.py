"""A synthetic node's compute time per run: a fixed time, weighted modes, or the spec's workload model."""

from __future__ import annotations

import functools
import math
import random
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

Modes = tuple[tuple[float, float], ...]
"""A node's compute profile: (weight, compute_ms) pairs."""


Profile = float | Sequence[tuple[float, float]]
"""What :func:`worker_command` takes per node: a compute time in ms, or (weight, compute_ms) modes."""


def check_profile(profile: Profile) -> Modes:
    """A profile as modes; ValueError if a compute time is negative or a weight not positive."""
    if isinstance(profile, int | float):
        modes: Modes = ((1.0, float(profile)),)
    else:
        modes = tuple((float(weight), float(compute)) for weight, compute in profile)
    if not modes:
        raise ValueError("a node needs at least one mode")
    for weight, compute in modes:
        if not (math.isfinite(weight) and weight > 0):
            raise ValueError(f"a mode's weight must be a positive number, got {weight!r}")
        if not (math.isfinite(compute) and compute >= 0):
            raise ValueError(f"a compute time must be a number of ms >= 0, got {compute!r}")
    return modes


def format_modes(modes: Sequence[tuple[float, float]]) -> str:
    """``[(0.8, 1.0), (0.2, 12.0)]`` -> ``"0.8:1.0,0.2:12.0"`` (what ``--modes`` reads)."""
    return ",".join(f"{float(weight)!r}:{float(compute)!r}" for weight, compute in modes)


def parse_modes(text: str) -> Modes:
    """``"0.8:1,0.2:12"`` -> ``((0.8, 1.0), (0.2, 12.0))``; ValueError with the reason if malformed."""
    modes = []
    for part in text.split(","):
        weight, sep, compute = part.partition(":")
        if not sep:
            raise ValueError(f"{part.strip()!r} is not WEIGHT:MS")
        try:
            modes.append((float(weight), float(compute)))
        except ValueError:
            raise ValueError(f"{part.strip()!r} is not WEIGHT:MS (two numbers)") from None
    return check_profile(modes)


Draw = Callable[[float], float]
"""One node's compute time (ms, on one thread) for a run starting ``at_s`` seconds into the run."""


def mode_draw(modes: Modes, rng: random.Random) -> Draw:
    """Draws from weighted modes, ignoring the time."""
    weights = [weight for weight, _ in modes]
    computes = [compute for _, compute in modes]
    if len(modes) == 1:
        return lambda _at_s: computes[0]
    return lambda _at_s: rng.choices(computes, weights)[0]


def workload_draws(spec_path: Path, nodes: Iterable[str], seed: int) -> dict[str, Draw]:
    """Each node's draws from the workload model of the spec at ``spec_path``.

    Raises :class:`~catanc.errors.CatancError` (a bad spec) or ValueError (a node the spec does
    not schedule).
    """
    from catanc.model.load import load_spec  # noqa: PLC0415 - only --workload needs the spec language
    from catanc.model.workload import ComputeSampler  # noqa: PLC0415

    spec = load_spec(spec_path)
    for name in nodes:
        node = spec.nodes.get(name)
        if node is None or not node.scheduled:
            what = "has no node" if node is None else "does not schedule node"
            raise ValueError(f"{spec_path} {what} {name!r}: a worker burns scheduled nodes only")
    sampler = ComputeSampler(spec, seed)  # one stream per node: threads never share one
    return {name: functools.partial(sampler.compute_ms, name) for name in nodes}
