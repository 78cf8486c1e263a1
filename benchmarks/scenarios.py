"""Issues 7 and 30: the paper's section 7 scenarios, simulated over 20 seeds and on this machine's kernel.

    python -m benchmarks.scenarios               # the simulator (deterministic): docs/results/sim.json and sim-*.png
    python -m benchmarks.scenarios --real        # the real kernel instead (root, ~30 min): real.json, real-*.png
    python -m benchmarks.scenarios --only vr     # one scenario (face, nav2d, yolo, yolo-fast, vr, vr-illixr)
    python -m benchmarks.scenarios --tables      # docs/results.md's tables rewritten from the saved numbers
    python -m benchmarks.scenarios --tables --check   # ... or exit 1 if they are out of date

Each scenario runs catanc's policies and the paper's baselines through
:func:`catanc.sim.simulate.simulate` or :func:`catanc.realbench.bench.bench_policies`
(same policies, same result shape), on 1 and 2 cores, and keeps the numbers
docs/results.md quotes (a JSON file per source) and one figure per scenario.
Every simulated point is run with seeds 0-19 (the workload's draws): each
number is the mean over the seeds of a per-seed figure (a run's mean, p95 or
rate) with the half-width of its 95% Student-t interval, and the per-seed
values are kept so that policies can be compared seed by seed (paired).
The real kernel runs one seed per point (a run takes real time).
Variants of an example spec (another hand-tuned rate, a faster growth, a
static plan's rates, ILLIXR's vsync display and dataset) are the spec's own
YAML with one thing changed, written to a temporary folder for the real
run's workers.

docs/results.md's tables are not typed by hand: each stands between ``<!-- tables SOURCE KEY -->``
and ``<!-- end tables -->`` (``sim`` or ``real``; a scenario, or ``load_average``), and
``--tables`` rewrites them from the JSON, leaving the prose around them as it is.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from matplotlib.axes import Axes
from matplotlib.figure import Figure

from catanc.errors import ExitCode, OutputError
from catanc.files import write_files
from catanc.model.build import build_problem
from catanc.model.load import load_spec
from catanc.planning.planner import plan_problem
from catanc.sim.metrics import ChainResult, PolicyResult
from catanc.sim.plots import panel_figure, png_bytes
from catanc.sim.simulate import Setup, simulate, static_profile
from tests.support.scenario_specs import (
    BUCKET_S,
    DATASET,
    bucket_medians,
    bucket_periods,
    over_seeds,
    paired_ratio,
    spec_file,
    spec_yaml,
    with_baseline_rates,
    with_growth_over,
    with_rates,
    with_vsync_display_and_dataset,
)

OUT = Path(__file__).resolve().parent.parent / "docs" / "results"
CORES = (1, 2)
SIM_SEEDS = tuple(range(20))
REAL_SEEDS = (0,)

FACE_CHAIN = ("camera", "detection", "planning", "motor")
LOCAL_CHAIN = ("scan", "LM", "LP", "base")
POSE_CHAIN = ("odom", "GL", "NC", "LP", "base")  # odometry through GL and NC to the base
YOLO_CHAIN = ("camera", "YOLO")
VR_CHAINS = {
    "A": ("IMU", "Int", "Timewarp", "Display"),
    "B": ("IMU", "Int", "Render", "Timewarp", "Display"),
    "C": ("Camera", "VIO", "Int", "Timewarp", "Display"),
}
VSYNC_HZ, DATASET_HZ = 120.0, 20.0  # ILLIXR's display and EuRoC's camera (the paper's section 7.3)
ILLIXR_CHAINS = {**VR_CHAINS, "C": (DATASET, *VR_CHAINS["C"])}  # C from the dataset's frame, as ILLIXR sees it

SpecFor = Mapping[str, Any] | Callable[[int, int], Mapping[str, Any]]
"""A scenario's spec: YAML data, or data made per (seed, cores) (a static plan's rates depend on both)."""
Measure = Callable[[PolicyResult], dict[str, Any]]


@dataclass(frozen=True)
class Source:
    """Where runs come from: the simulator or the real kernel, with each scenario's durations and seeds."""

    name: str  # "sim" or "real"
    durations_s: Mapping[str, float]
    face_rates_hz: tuple[float, ...]
    seeds: tuple[int, ...]

    def run(self, spec: SpecFor, cores: int, policy: str, duration_s: float, measure: Measure) -> dict[str, Any]:
        """``measure`` of one run per seed, summarised over the seeds (:func:`over_seeds`)."""
        began = time.monotonic()
        measured = []
        app = ""
        for seed in self.seeds:
            data = spec(seed, cores) if callable(spec) else spec
            app = str(data["app"])
            with spec_file(data) as path:
                loaded = load_spec(path)
                if self.name == "sim":
                    result = simulate(Setup(loaded, cores, duration_s, seed), policy)
                else:
                    from catanc.realbench.bench import BenchSetup, bench_policies  # noqa: PLC0415 - root only

                    result = bench_policies(BenchSetup(path, loaded, cores, duration_s, seed), [policy])[0]
            measured.append(measure(result))
        print(
            f"  {self.name} {app} {cores} core(s) {policy}: {len(self.seeds)} x {duration_s:g} s "
            f"in {time.monotonic() - began:.1f} s",
            file=sys.stderr,
            flush=True,
        )
        summary: dict[str, Any] = over_seeds(measured)
        return summary


SIM = Source(
    "sim",
    {"face": 60.0, "nav2d": 250.0, "yolo": 250.0, "yolo-fast": 60.0, "vr": 60.0, "vr-illixr": 60.0},
    (2, 4, 6, 8, 10, 11, 12, 13, 14, 15, 17, 20, 25, 30),
    SIM_SEEDS,
)
REAL = Source(
    "real",
    {"face": 10.0, "nav2d": 20.0, "yolo-fast": 60.0, "vr": 20.0, "vr-illixr": 20.0},
    (4, 8, 11, 14, 17, 20, 30),
    REAL_SEEDS,
)


def mean_of(value: Mapping[str, Any] | None) -> float:
    return math.nan if value is None else float(value["mean"])


# --------------------------------------------------------------------------- specs and numbers


def chain_of(result: PolicyResult, nodes: Sequence[str]) -> ChainResult:
    return next(chain for chain in result.chains if chain.nodes == tuple(nodes))


def response(result: PolicyResult, nodes: Sequence[str]) -> dict[str, float | None]:
    """Mean, p95 and max response time (ms) of a chain, its outputs, and the plan's R where there is one."""
    chain = chain_of(result, nodes)
    summary = chain.response
    return {
        "mean_ms": None if summary is None else summary.mean,
        "p95_ms": None if summary is None else summary.p95,
        "max_ms": None if summary is None else summary.max,
        "outputs": 0 if summary is None else summary.count,
        "model_ms": chain.model_ms,
    }


def rate(result: PolicyResult, node: str) -> float:
    return result.nodes[node].rate_hz


def staleness(result: PolicyResult, node: str) -> float | None:
    return result.nodes[node].staleness_ms_p95


Variants = Mapping[str, tuple[str, SpecFor]]
"""label -> (policy, spec) of one scenario."""


def per_core_and_variant(
    source: Source,
    duration_s: float,
    variants: Variants | Callable[[int], Variants],
    measure: Measure,
) -> dict[str, Any]:
    """``{cores: {label: measure over the seeds}}`` for each ``label -> (policy, spec)`` on each of :data:`CORES`
    (``variants`` may depend on the cores)."""
    numbers: dict[str, Any] = {}
    for cores in CORES:
        chosen = variants(cores) if callable(variants) else variants
        for label, (policy, data) in chosen.items():
            numbers.setdefault(f"{cores}", {})[label] = source.run(data, cores, policy, duration_s, measure)
    return numbers


def errorbars(ax: Axes, xs: Sequence[float], values: Sequence[Mapping[str, Any] | None], style: str, **kw: Any) -> None:
    """Means with their 95% intervals (none for one seed)."""
    ys = [mean_of(v) for v in values]
    errors = [0.0 if v is None or v["ci95"] is None else v["ci95"] for v in values]
    ax.errorbar(xs, ys, yerr=errors, fmt=style, capsize=2, **kw)


# --------------------------------------------------------------------------- scenarios


def face(source: Source) -> tuple[dict[str, Any], Figure]:
    """Figure 6: the chain's response time against the camera rate (CFS), and catanc's choice."""
    data, duration = spec_yaml("face_tracking"), source.durations_s["face"]

    def measure(result: PolicyResult) -> dict[str, Any]:
        return {"camera_hz": rate(result, "camera"), "achieved_hz": rate(result, "planning"),
                **response(result, FACE_CHAIN)}  # fmt: skip

    numbers: dict[str, Any] = {}
    for cores in CORES:
        sweep = []
        for hz in source.face_rates_hz:
            row = source.run(with_rates(data, {"camera": hz}), cores, "baseline", duration, measure)
            sweep.append({**row, "camera_hz": hz})
        numbers[f"{cores}"] = {"baseline": sweep, "catan": source.run(data, cores, "catan", duration, measure)}
    figure, axes = new_figure(len(CORES), "Face tracking: response time against the camera rate")
    for ax, cores in zip(axes, CORES, strict=True):
        body = numbers[f"{cores}"]
        xs = [row["camera_hz"] for row in body["baseline"]]
        for key, style in (("mean_ms", "-o"), ("p95_ms", "--s")):
            errorbars(ax, xs, [row[key] for row in body["baseline"]], style, color="tab:gray",
                      label=f"CFS, {key[:-3]}")  # fmt: skip
        chosen = body["catan"]
        at = [mean_of(chosen["camera_hz"])]
        errorbars(ax, at, [chosen["mean_ms"]], "*", color="tab:red", markersize=14, label="catanc, mean")
        errorbars(ax, at, [chosen["p95_ms"]], "*", color="tab:orange", markersize=10, label="catanc, p95")
        ax.set_yscale("log")
        ax.set_xlabel("camera rate (Hz)")
        ax.set_ylabel("response time (ms)")
        ax.set_title(f"{cores} core{'s' if cores > 1 else ''}")
        ax.legend(fontsize="small")
    return numbers, figure


NAV_POLICIES = {  # label -> (policy, baseline rates changed)
    "catan": ("catan", {}),
    "catan-nosteal": ("catan-nosteal", {}),
    "default": ("baseline", {}),
    "default, LM/LP 50 Hz": ("baseline", {"LM": 50.0, "LP": 50.0}),
    "fifo-static": ("fifo-static", {}),
}


def nav2d(source: Source) -> tuple[dict[str, Any], Figure]:
    """Section 7.2 and Figure 9: the local chain and GL's staleness, catanc (with and without priority
    stealing) against the hand-tuned defaults."""
    data = spec_yaml("nav2d")
    variants = {label: (policy, with_rates(data, rates)) for label, (policy, rates) in NAV_POLICIES.items()}

    def measure(result: PolicyResult) -> dict[str, Any]:
        return {
            "local": response(result, LOCAL_CHAIN),
            "local_hz": rate(result, "LP"),
            "GL_hz": rate(result, "GL"),
            "GL_staleness_p95_ms": staleness(result, "GL"),
            "pose_at_base": response(result, POSE_CHAIN),
            "GM_hz": rate(result, "GM"),
            "GP_hz": rate(result, "GP"),
        }

    numbers = per_core_and_variant(source, source.durations_s["nav2d"], variants, measure)
    figure, axes = new_figure(2, "nav2d: local chain and GL, catanc against the hand-tuned defaults")
    labels = list(NAV_POLICIES)
    for ax, (key, title) in zip(
        axes, (("local", "local chain p95 (ms)"), ("GL", "GL input staleness p95 (ms)")), strict=True
    ):
        width = 0.8 / len(CORES)
        for i, cores in enumerate(CORES):
            body = numbers[f"{cores}"]
            values = [body[label]["local"]["p95_ms"] if key == "local" else body[label]["GL_staleness_p95_ms"]
                      for label in labels]  # fmt: skip
            xs = [j + (i - (len(CORES) - 1) / 2) * width for j in range(len(labels))]
            errorbars(ax, xs, values, "o", markersize=6, label=f"{cores} core{'s' if cores > 1 else ''}")
        ax.set_xticks(range(len(labels)), labels, rotation=15, fontsize="small")
        ax.set_yscale("log")
        ax.set_ylabel(title)
        ax.legend(fontsize="small")
    return numbers, figure


YOLO_POLICIES = ("catan", "static-fullrun", "static-20s")
ONE_CORE_RATES = {"static-fullrun": "static-fullrun, 1-core rates, CFS", "static-20s": "static-20s, 1-core rates, CFS"}
"""Figure 12's baselines on 2 cores: the static plans made for 1 core, their rates run as timers under CFS."""


def one_core_rates(data: Mapping[str, Any], policy: str, duration_s: float) -> Callable[[int, int], dict[str, Any]]:
    """Per seed: the spec with its baseline timers set to the head rates of ``policy``'s 1-core static plan
    (made from that seed's profiled tail compute times, as ``static-*`` make it)."""

    def spec_for(seed: int, _cores: int) -> dict[str, Any]:
        with spec_file(data) as path:
            spec = load_spec(path)
        setup = Setup(spec, 1, duration_s, seed)
        profiled = build_problem(spec).with_compute(static_profile(setup, policy))
        planned = plan_problem(profiled, spec.schedule, 1, backend="conic")
        heads = {sub.nodes[0]: 1000.0 / sub.period_ms for sub in planned.subchains.values()}
        return with_baseline_rates(data, heads)

    return spec_for


def yolo(source: Source, variant: str) -> tuple[dict[str, Any], Figure]:
    """Figures 10-12: YOLO's output period over time and the pose's age at the base, with growing GM/GP.

    ``variant`` ``yolo``: the spec as it is (growth over 250 s); ``yolo-fast``: growth compressed
    into the run's duration, so that a 60 s real run sees all of it.  On 2 cores the paper's
    baselines also run their 1-core plans' rates under CFS (Figure 12).
    """
    duration = source.durations_s[variant]
    data = spec_yaml("nav2d_yolo")
    if variant == "yolo-fast":
        data = with_growth_over(data, duration)

    def measure(result: PolicyResult) -> dict[str, Any]:
        return {
            "yolo_hz": rate(result, "YOLO"),
            "yolo_period_s": bucket_periods(result.node_done_ms["YOLO"].tolist(), duration),
            "local": response(result, LOCAL_CHAIN),
            "pose_at_base": response(result, POSE_CHAIN),
            "pose_at_base_median_ms": bucket_medians(chain_of(result, POSE_CHAIN).samples.tolist(), duration),
            "GL_hz": rate(result, "GL"),
            "GM_hz": rate(result, "GM"),
            "GP_hz": rate(result, "GP"),
            "replans": result.replans,
        }

    def variants(cores: int) -> Variants:
        chosen: dict[str, tuple[str, SpecFor]] = {policy: (policy, data) for policy in YOLO_POLICIES}
        if cores > 1:
            for policy, label in ONE_CORE_RATES.items():
                chosen[label] = ("baseline", one_core_rates(data, policy, duration))
        return chosen

    numbers: dict[str, Any] = {"growth_over_s": 250.0 if variant == "yolo" else duration}
    numbers |= per_core_and_variant(source, duration, variants, measure)
    figure, axes = new_figure(
        2 * len(CORES), f"nav2d+YOLO, GM and GP growing 0.6x to 2x over {numbers['growth_over_s']:g} s"
    )
    for row, cores in enumerate(CORES):
        body = numbers[f"{cores}"]
        period_ax, pose_ax = axes[2 * row], axes[2 * row + 1]
        for label, measured in body.items():
            times = [BUCKET_S * (i + 0.5) for i in range(len(measured["yolo_period_s"]))]
            period_ax.plot(times, [mean_of(v) for v in measured["yolo_period_s"]], "-o", markersize=3, label=label)
            pose_ax.plot(times, [mean_of(v) for v in measured["pose_at_base_median_ms"]], "-o", markersize=3,
                         label=label)  # fmt: skip
        suffix = f", {cores} core{'s' if cores > 1 else ''}"
        period_ax.set_title("YOLO output period (s), 10 s buckets, mean over seeds" + suffix, fontsize="medium")
        pose_ax.set_title("odom -> GL -> NC -> base, median (ms), mean over seeds" + suffix, fontsize="medium")
        for ax in (period_ax, pose_ax):
            ax.set_xlabel("time (s)")
            ax.legend(fontsize="small")
    return numbers, figure


VR_SLACK = 0.25
"""On this VM the enforcer's own CPU (~20% of a core for VR's short schedule period) exceeded the
default 5% slack on 1 core (2026-11-21): a variant plans with 25% idle so that its plan fits beside it."""
VR_POLICIES = {  # label -> (policy, schedule changes)
    "catan": ("catan", {}),
    "catan-nosteal": ("catan-nosteal", {}),
    f"catan, slack {VR_SLACK:.0%}": ("catan", {"slack": VR_SLACK}),
    "fifo-static": ("fifo-static", {}),
    "baseline": ("baseline", {}),
}


def with_schedule(data: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """The spec with some ``schedule`` settings changed."""
    changed = copy.deepcopy(dict(data))
    changed.setdefault("schedule", {}).update(changes)
    return changed


def vr(source: Source, variant: str) -> tuple[dict[str, Any], Figure]:
    """Section 7.3: chains A, B and C, catanc against FIFO static priorities.

    ``variant`` ``vr``: the spec as it is (Display a pure sink, Camera the source); ``vr-illixr``:
    as ILLIXR runs it, Display at vsync (120 Hz) and Camera reading a 20 Hz dataset.
    """
    data = spec_yaml("vr_illixr")
    chains = VR_CHAINS
    if variant == "vr-illixr":
        data, chains = with_vsync_display_and_dataset(data, VSYNC_HZ, DATASET_HZ), ILLIXR_CHAINS
    variants = {label: (policy, with_schedule(data, changes)) for label, (policy, changes) in VR_POLICIES.items()}

    def measure(result: PolicyResult) -> dict[str, Any]:
        rates = {f"{node}_hz": rate(result, node) for node in ("Render", "VIO", "Timewarp")}
        return {name: response(result, nodes) for name, nodes in chains.items()} | rates

    numbers = per_core_and_variant(source, source.durations_s[variant], variants, measure)
    for cores in CORES:  # seed by seed against fifo-static (the same draws): the issue's targets
        body = numbers[f"{cores}"]
        for label in VR_POLICIES:
            body[label]["vs_fifo_static"] = {
                name: paired_ratio(body[label][name]["mean_ms"], body["fifo-static"][name]["mean_ms"])
                for name in chains
            }
    where = "Display at vsync, Camera from a 20 Hz dataset" if variant == "vr-illixr" else "the spec as it is"
    figure, axes = new_figure(len(CORES), f"VR (ILLIXR, {where}): mean response of chains A, B, C / fifo-static's")
    for ax, cores in zip(axes, CORES, strict=True):
        body = numbers[f"{cores}"]
        width = 0.8 / len(VR_POLICIES)
        for i, policy in enumerate(VR_POLICIES):
            xs = [j + (i - (len(VR_POLICIES) - 1) / 2) * width for j in range(len(chains))]
            ratios = [body[policy]["vs_fifo_static"][name] for name in chains]
            heights = [1.0 + mean_of(r) for r in ratios]
            errors = [0.0 if r is None or r["ci95"] is None else r["ci95"] for r in ratios]
            ax.bar(xs, heights, width, yerr=errors, capsize=2, label=policy)
        ax.axhline(1.0, color="black", linewidth=0.8)
        ax.set_xticks(range(len(chains)), [f"chain {name}" for name in chains])
        ax.set_ylabel("mean response / fifo-static's")
        ax.set_title(f"{cores} core{'s' if cores > 1 else ''}")
        ax.legend(fontsize="small")
    return numbers, figure


# --------------------------------------------------------------------------- figures and files


def new_figure(panels: int, title: str) -> tuple[Figure, list[Axes]]:
    """A scenario's figure: 6 x 3.6 in per panel, two panels per row."""
    columns = 2 if panels > 1 else 1
    return panel_figure(panels, 6.0 * columns, 3.6 * math.ceil(panels / columns), title)


SCENARIOS: dict[str, Callable[[Source], tuple[dict[str, Any], Figure]]] = {
    "face": face,
    "nav2d": nav2d,
    "yolo": lambda source: yolo(source, "yolo"),
    "yolo-fast": lambda source: yolo(source, "yolo-fast"),
    "vr": lambda source: vr(source, "vr"),
    "vr-illixr": lambda source: vr(source, "vr-illixr"),
}


# --------------------------------------------------------------------------- tables for docs/results.md


def _with_ci(value: Mapping[str, Any] | None, digits: str) -> str:
    if value is None:
        return "-"
    text = format(value["mean"], digits)
    return text if value["ci95"] is None else f"{text} ± {format(value['ci95'], digits)}"


def _ms(value: Mapping[str, Any] | None) -> str:
    return _with_ci(value, ".1f")


def _hz(value: Mapping[str, Any] | None) -> str:
    return _with_ci(value, ".3g")


def _pct(value: Mapping[str, Any] | None) -> str:
    if value is None:
        return "-"
    text = f"{100 * value['mean']:+.1f}%"
    return text if value["ci95"] is None else f"{text} ± {100 * value['ci95']:.1f}"


def _plain(value: Mapping[str, Any] | None, digits: str = ".3g") -> str:
    return "-" if value is None else format(value["mean"], digits)


def in_order(body: Mapping[str, Any], order: Sequence[str]) -> list[tuple[str, Any]]:
    """``body``'s rows in the scenario's order (the JSON's keys are sorted), any others after them."""
    return [(label, body[label]) for label in order if label in body] + [
        (label, row) for label, row in body.items() if label not in order
    ]


def _load_average(numbers: Mapping[str, Any]) -> Iterator[str]:
    yield "| scenario | load average (1, 5, 15 min) at the start | at the end |\n|---|---|---|"
    for name, load in numbers["load_average"].items():
        yield f"| {name} | {', '.join(map(str, load['start']))} | {', '.join(map(str, load['end']))} |"


def _face(numbers: Mapping[str, Any]) -> Iterator[str]:
    yield "| cores | camera Hz (CFS) | achieved Hz | mean ms | p95 ms |\n|---|---|---|---|---|"
    for cores, body in numbers["face"].items():
        for row in body["baseline"]:
            rates = f"{row['camera_hz']:g} | {_hz(row['achieved_hz'])}"
            yield f"| {cores} | {rates} | {_ms(row['mean_ms'])} | {_ms(row['p95_ms'])} |"
        chosen = body["catan"]
        yield (f"| {cores} | **catanc: {_hz(chosen['camera_hz'])}** | | **{_ms(chosen['mean_ms'])}** | "
               f"**{_ms(chosen['p95_ms'])}** (model R {_ms(chosen['model_ms'])}) |")  # fmt: skip


def _nav2d(numbers: Mapping[str, Any]) -> Iterator[str]:
    yield ("| cores | policy | local chain Hz | local mean ms | local p95 ms | local max ms | GL Hz "
           "| GL staleness p95 ms | odom->GL->NC->base mean ms | GM Hz |")  # fmt: skip
    yield "|---|---|---|---|---|---|---|---|---|---|"
    for cores, body in numbers["nav2d"].items():
        for label, row in in_order(body, list(NAV_POLICIES)):
            local, pose = row["local"], row["pose_at_base"]
            yield (f"| {cores} | {label} | {_hz(row['local_hz'])} | {_ms(local['mean_ms'])} "
                   f"| {_ms(local['p95_ms'])} | {_ms(local['max_ms'])} | {_hz(row['GL_hz'])} "
                   f"| {_ms(row['GL_staleness_p95_ms'])} "
                   f"| {_ms(pose['mean_ms'])} | {_hz(row['GM_hz'])} |")  # fmt: skip


def _yolo(numbers: Mapping[str, Any], variant: str) -> Iterator[str]:
    over = numbers[variant]["growth_over_s"]
    yield f"Growth over {over:g} s:\n"
    yield ("| cores | policy | YOLO Hz | YOLO period, first / last 10 s bucket (s) | local p95 ms "
           "| odom->GL->NC->base median, first / last bucket (ms) | GL Hz | GM Hz | re-plans |")  # fmt: skip
    yield "|---|---|---|---|---|---|---|---|---|"
    for cores, body in ((k, v) for k, v in numbers[variant].items() if k != "growth_over_s"):
        for policy, row in in_order(body, [*YOLO_POLICIES, *ONE_CORE_RATES.values()]):
            period, pose = row["yolo_period_s"], row["pose_at_base_median_ms"]
            yield (f"| {cores} | {policy} | {_hz(row['yolo_hz'])} "
                   f"| {_with_ci(period[0], '.2f')} / {_with_ci(period[-1], '.2f')} "
                   f"| {_ms(row['local']['p95_ms'])} | {_ms(pose[0])} / {_ms(pose[-1])} | {_hz(row['GL_hz'])} "
                   f"| {_hz(row['GM_hz'])} | {_plain(row['replans'], '.0f')} |")  # fmt: skip


def _vr(numbers: Mapping[str, Any], variant: str) -> Iterator[str]:
    yield f"VR, {variant}:\n"
    yield "| cores | policy | A mean ms | B mean ms | C mean ms | A, B, C p95 ms | Render Hz | VIO Hz |"
    yield "|---|---|---|---|---|---|---|---|"
    for cores, body in numbers[variant].items():
        for policy, row in in_order(body, list(VR_POLICIES)):
            means = " | ".join(_ms(row[n]["mean_ms"]) for n in "ABC")
            p95s = " / ".join(_plain(row[n]["p95_ms"], ".1f") for n in "ABC")
            yield f"| {cores} | {policy} | {means} | {p95s} | {_hz(row['Render_hz'])} | {_hz(row['VIO_hz'])} |"
    yield ""
    yield "Mean response against fifo-static's, seed by seed (paired):\n"
    yield "| cores | policy | A | B | C |\n|---|---|---|---|---|"
    for cores, body in numbers[variant].items():
        for policy, row in in_order(body, list(VR_POLICIES)):
            if policy != "fifo-static":
                ratios = " | ".join(_pct(row["vs_fifo_static"][n]) for n in "ABC")
                yield f"| {cores} | {policy} | {ratios} |"


TABLES: dict[str, Callable[[Mapping[str, Any]], Iterator[str]]] = {
    "load_average": _load_average,
    "face": _face,
    "nav2d": _nav2d,
    "yolo": lambda numbers: _yolo(numbers, "yolo"),
    "yolo-fast": lambda numbers: _yolo(numbers, "yolo-fast"),
    "vr": lambda numbers: _vr(numbers, "vr"),
    "vr-illixr": lambda numbers: _vr(numbers, "vr-illixr"),
}
"""Each key of a source's JSON (a scenario, or the real runs' load averages) -> its markdown tables."""


def tables(numbers: Mapping[str, Any], key: str) -> str:
    """The markdown of one key of a source's numbers: its tables, mean ± 95% half-width, no trailing newline."""
    return "\n".join(TABLES[key](numbers))


# --------------------------------------------------------------------------- docs/results.md's tables in place

RESULTS_MD = Path(__file__).resolve().parent.parent / "docs" / "results.md"
BEGIN_TABLES = re.compile(r"<!-- tables (?P<source>\S+) (?P<key>\S+) -->")
END_TABLES = "<!-- end tables -->"


class TablesError(Exception):
    """docs/results.md's markers do not fit the saved numbers (the message names the file and line)."""


def rewrite_tables(text: str, sources: Mapping[str, Mapping[str, Any]], file: str) -> str:
    """``text`` (docs/results.md) with what stands between each ``<!-- tables SOURCE KEY -->`` and the next
    ``<!-- end tables -->`` replaced by :func:`tables` of ``sources[SOURCE]`` (the JSON), a blank line each side;
    the rest kept byte for byte.  :class:`TablesError` names the line of a marker that names no saved
    numbers or is never closed."""
    lines = text.split("\n")
    out: list[str] = []
    index = 0
    while index < len(lines):
        line = lines[index]
        out.append(line)
        index += 1
        begin = BEGIN_TABLES.fullmatch(line.strip())
        if begin is None:
            if line.strip() == END_TABLES:
                raise TablesError(f"{file}:{index}: {END_TABLES} without a <!-- tables SOURCE KEY --> before it")
            continue
        source, key = begin["source"], begin["key"]
        if source not in sources:
            known = ", ".join(sorted(sources)) or "none"
            raise TablesError(f"{file}:{index}: {line.strip()}: no saved numbers of source {source!r} ({known})")
        if key not in TABLES or key not in sources[source]:
            known = ", ".join(sorted(k for k in sources[source] if k in TABLES))
            raise TablesError(f"{file}:{index}: {line.strip()}: {source}.json holds no {key!r} ({known})")
        end = next((i for i in range(index, len(lines)) if lines[i].strip() == END_TABLES), None)
        if end is None:
            raise TablesError(f"{file}:{index}: {line.strip()}: no {END_TABLES} after it")
        out += ["", tables(sources[source], key), "", lines[end]]
        index = end + 1
    return "\n".join(out)


def saved_numbers(folder: Path) -> dict[str, dict[str, Any]]:
    """Each source's saved numbers (``sim.json``, ``real.json``) found in ``folder``, by source name."""
    found = {}
    for source in (SIM, REAL):
        path = folder / f"{source.name}.json"
        if path.exists():
            found[source.name] = json.loads(path.read_text())
    return found


def tables_command(doc: Path, numbers_folder: Path, check: bool) -> int:
    """``--tables``: rewrite ``doc``'s tables from the saved numbers (``--check``: only say whether they differ);
    the exit status."""
    try:
        text = doc.read_text()
        rewritten = rewrite_tables(text, saved_numbers(numbers_folder), str(doc))
    except (OSError, TablesError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return int(ExitCode.BAD_INPUT)
    if rewritten == text:
        print(f"{doc}: tables up to date", file=sys.stderr)
        return 0
    if check:
        print(f"{doc}: tables out of date: python -m benchmarks.scenarios --tables", file=sys.stderr)
        return 1
    try:
        write_files(doc.parent, {doc.name: rewritten.encode()}, kind="results page")
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return int(ExitCode.OUTPUT)
    print(f"{doc}: tables rewritten", file=sys.stderr)
    return 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", action="store_true", help="Run on this machine's kernel (needs root), not simulated.")
    parser.add_argument("--only", action="append", choices=sorted(SCENARIOS), help="Scenarios to run (repeat).")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--tables", action="store_true", help="Rewrite docs/results.md's tables from the saved numbers; run nothing."
    )
    parser.add_argument("--check", action="store_true", help="With --tables: exit 1 if they are out of date.")
    parser.add_argument("--doc", type=Path, default=RESULTS_MD, help="The page whose tables --tables rewrites.")
    args = parser.parse_args()
    if args.tables:
        sys.exit(tables_command(args.doc, args.out, args.check))
    source = REAL if args.real else SIM
    chosen = [name for name in args.only or SCENARIOS if name in source.durations_s]
    numbers_path = args.out / f"{source.name}.json"
    numbers = json.loads(numbers_path.read_text()) if numbers_path.exists() else {}
    files: dict[str, bytes] = {}
    for name in chosen:
        print(f"{source.name}: {name}", file=sys.stderr, flush=True)
        before = os.getloadavg()
        numbers[name], figure = SCENARIOS[name](source)
        if source is REAL:  # the machine's load beside the numbers it shaped (1, 5, 15 min averages)
            loads = numbers.setdefault("load_average", {})
            loads[name] = {"start": [round(x, 2) for x in before], "end": [round(x, 2) for x in os.getloadavg()]}
        files[f"{source.name}-{name}.png"] = png_bytes(figure)
        # Written after each scenario: a long real run keeps what it measured if it is stopped.
        write_files(
            args.out, {**files, numbers_path.name: (json.dumps(numbers, indent=1, sort_keys=True) + "\n").encode()}
        )


if __name__ == "__main__":
    main()
