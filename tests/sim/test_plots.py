"""``catanc simulate --plot DIR``: what each figure draws (against hand-made results), and how the files are written.

The results here are built by hand, so every expected number (a CDF's steps,
a slot's bar, a bin's rate) is worked out from the input, not read back from
the code.  One CLI test runs a short real simulation.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle, StepPatch
from PIL import Image
from typer.testing import CliRunner

from catanc.cli import app
from catanc.control.schedule import CoreSchedule, RuntimeSchedule, Slot, SubchainRun
from catanc.errors import OutputError
from catanc.sim import plots
from catanc.sim.metrics import ChainResult, NodeResult, PolicyResult, Summary
from catanc.sim.plots import (
    FILES,
    RATES,
    RESPONSES,
    TIMELINE,
    chain_label,
    draw_figures,
    render_plots,
    write_plots,
)

ROOT = Path(__file__).resolve().parents[2]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TITLE = "demo, 2 cores, 2 s simulated"


def run(name: str, nodes: tuple[str, ...], cores: tuple[int, ...], *, shared: bool, period_ms: float) -> SubchainRun:
    return SubchainRun(name, nodes, cores, shared, period_ms, latency_ms=period_ms, runs=None, priority=1)


# Core 0: subchain "fast" dedicated, period 2.5 ms.  Core 1 shared, T = 10 ms, switch 0.5 ms:
# "slow" from 0.5 for 4 ms, switch at 4.5, "mid" from 5.0 for 3 ms; slack 8 -> 10.
SCHEDULE = RuntimeSchedule(
    cores=2,
    subchains={
        "fast": run("fast", ("a", "b"), (0,), shared=False, period_ms=2.5),
        "slow": run("slow", ("c",), (1,), shared=True, period_ms=20.0),
        "mid": run("mid", ("d",), (1,), shared=True, period_ms=10.0),
    },
    shared=(CoreSchedule(1, 10.0, 0.5, (Slot("slow", 0.5, 4.0), Slot("mid", 5.0, 3.0))),),
)


def chain(
    nodes: tuple[str, ...], responses: list[float], *, named: bool = True, model: float | None = None
) -> ChainResult:
    samples = np.array([(100.0 * (i + 1), r) for i, r in enumerate(responses)]).reshape(-1, 2)
    return ChainResult(nodes, named, Summary.of(np.array(responses)), model, samples)


def result(
    policy: str,
    chains: tuple[ChainResult, ...],
    done: dict[str, tuple[float, ...]],
    schedule: RuntimeSchedule | None,
) -> PolicyResult:
    nodes = {name: NodeResult(len(times) / 2.0, None) for name, times in done.items()}
    arrays = {name: np.array(times, dtype=np.float64) for name, times in done.items()}
    return PolicyResult(policy, 2.0, chains, nodes, (0.5, 0.5), 0, arrays, schedule)


def catan() -> PolicyResult:
    return result(
        "catan",
        (
            chain(("a", "b", "c"), [30.0, 10.0, 20.0], model=45.0),
            chain(("c", "d"), []),
            chain(("a", "d"), [5.0], named=False),
        ),
        {"a": (100.0, 200.0, 300.0, 1500.0), "c": (999.0,)},
        SCHEDULE,
    )


def baseline() -> PolicyResult:
    return result(
        "baseline",
        (chain(("a", "b", "c"), [50.0, 60.0]), chain(("c", "d"), []), chain(("a", "d"), [7.0], named=False)),
        {"a": (500.0, 1000.0, 1999.0), "c": ()},
        None,
    )


def panels(figure: Figure) -> list[Axes]:
    return [ax for ax in figure.axes if ax.get_visible()]


def xy(line: Line2D) -> tuple[list[float], list[float]]:
    return [float(x) for x in np.asarray(line.get_xdata())], [float(y) for y in np.asarray(line.get_ydata())]


def steps(ax: Axes) -> dict[str, tuple[list[float], list[float]]]:
    """Per label, the rates and bin edges of each stairs line."""
    return {
        str(p.get_label()): ([float(v) for v in p.get_data()[0]], [float(e) for e in p.get_data()[1]])
        for p in ax.patches
        if isinstance(p, StepPatch)
    }


def texts(ax: Axes) -> str:
    return " | ".join(text.get_text() for text in ax.texts)


def png_text_keys(data: bytes) -> list[bytes]:
    """The keywords of a PNG's text chunks (tEXt, zTXt, iTXt)."""
    keys = []
    at = len(PNG_MAGIC)
    while at < len(data):
        length = int.from_bytes(data[at : at + 4], "big")
        kind = data[at + 4 : at + 8]
        body = data[at + 8 : at + 8 + length]
        assert zlib.crc32(kind + body) == int.from_bytes(data[at + 8 + length : at + 12 + length], "big")
        if kind in (b"tEXt", b"zTXt", b"iTXt"):
            keys.append(body.split(b"\0", 1)[0])
        at += 12 + length
    return keys


# --------------------------------------------------------------------------- what is drawn


def test_chain_labels_break_between_nodes() -> None:
    assert chain_label(("scan", "LM", "LP")) == "scan -> LM -> LP"
    assert chain_label(("a" * 10, "b" * 10, "c" * 10), width=26) == f"{'a' * 10} -> {'b' * 10} ->\n{'c' * 10}"
    assert chain_label(("x" * 40, "y"), width=10) == f"{'x' * 40} ->\ny"  # a long name is never cut


def test_the_cdf_has_one_panel_per_named_chain_and_steps_through_the_sorted_responses() -> None:
    figure = draw_figures([catan(), baseline()], title=TITLE)[RESPONSES]
    axes = panels(figure)
    assert [ax.get_title() for ax in axes] == ["a -> b -> c", "c -> d"]  # the unnamed a -> d is not drawn
    lines = {line.get_label(): line for line in axes[0].get_lines()}
    assert set(lines) == {"catan", "catan: R", "baseline"}
    assert xy(lines["catan"])[0] == [10.0, 10.0, 20.0, 30.0]
    assert xy(lines["catan"])[1] == pytest.approx([0.0, 1 / 3, 2 / 3, 1.0])
    assert xy(lines["baseline"]) == ([50.0, 50.0, 60.0], [0.0, 0.5, 1.0])
    assert xy(lines["catan: R"])[0] == [45.0, 45.0]
    assert lines["catan"].get_color() != lines["baseline"].get_color()
    assert TITLE in figure.get_suptitle()
    assert not axes[1].get_lines()
    assert "no output reached the end of this chain" in texts(axes[1])


def test_a_policy_without_outputs_on_a_chain_is_named_in_its_panel() -> None:
    silent = result("fifo-static", (chain(("a", "b", "c"), []),), {}, None)
    ax = panels(draw_figures([catan(), silent], title=TITLE)[RESPONSES])[0]
    assert "no outputs: fifo-static" in texts(ax)
    assert {line.get_label() for line in ax.get_lines()} == {"catan", "catan: R"}


def bars(ax: Axes) -> set[tuple[float, float, float]]:
    """``(row, left, width)`` of every bar, rounded."""
    return {
        (round(p.get_y() + p.get_height() / 2, 3), round(p.get_x(), 3), round(p.get_width(), 3))
        for p in ax.patches
        if isinstance(p, Rectangle)
    }


def test_the_timeline_draws_slots_switches_slack_and_dedicated_cores_for_each_planned_policy() -> None:
    static = result("static-20s", (), {}, SCHEDULE)
    figure = draw_figures([catan(), baseline(), static], title=TITLE)[TIMELINE]
    axes = panels(figure)
    assert [ax.get_title(loc="left").split(" ")[0] for ax in axes] == ["catan", "static-20s"]
    assert "no slot schedule: baseline" in figure.get_suptitle()
    ax = axes[0]
    assert bars(ax) == {
        (0.0, 0.0, 10.0),  # core 0, dedicated: the whole period
        (1.0, 0.0, 0.5),  # switch to slow
        (1.0, 0.5, 4.0),  # slow
        (1.0, 4.5, 0.5),  # switch to mid
        (1.0, 5.0, 3.0),  # mid
        (1.0, 8.0, 2.0),  # slack
    }
    assert ax.get_xlim() == (0.0, 10.0)
    assert [label.get_text() for label in ax.get_yticklabels()] == ["core 0", "core 1"]
    assert "fast (a, b): dedicated, period 2.50 ms (400 Hz)" in texts(ax)
    ticks = [
        float(segment[0][0])
        for collection in ax.collections
        if isinstance(collection, LineCollection)
        for segment in collection.get_segments()
    ]
    assert sorted(ticks) == pytest.approx([2.5, 5.0, 7.5, 10.0])  # one mark per period of "fast"
    assert "T = 10.00 ms" in ax.get_title(loc="left")


def test_without_any_schedule_the_timeline_says_so() -> None:
    figure = draw_figures([baseline()], title=TITLE)[TIMELINE]
    (ax,) = panels(figure)
    assert not ax.patches
    assert "no slot schedule to draw: baseline" in texts(ax)


def test_rates_are_runs_per_second_bin_per_node_and_policy() -> None:
    figure = draw_figures([catan(), baseline()], title=TITLE, nodes=["a", "c"])[RATES]
    axes = panels(figure)
    assert [ax.get_title(loc="left") for ax in axes] == ["a", "c"]
    # catan's a: 100, 200, 300 ms in [0, 1) s, 1500 ms in [1, 2); baseline's: 500 | 1000, 1999.
    assert steps(axes[0]) == {"catan": ([3.0, 1.0], [0.0, 1.0, 2.0]), "baseline": ([1.0, 2.0], [0.0, 1.0, 2.0])}
    assert steps(axes[1]) == {"catan": ([1.0, 0.0], [0.0, 1.0, 2.0]), "baseline": ([0.0, 0.0], [0.0, 1.0, 2.0])}


def test_rates_default_to_every_node_with_completion_times() -> None:
    axes = panels(draw_figures([catan()], title=TITLE)[RATES])
    assert [ax.get_title(loc="left") for ax in axes] == ["a", "c"]


# --------------------------------------------------------------------------- the files


def test_writes_three_pngs_into_a_new_folder(tmp_path: Path) -> None:
    out = tmp_path / "new" / "plots"
    written = write_plots([catan(), baseline()], out, title=TITLE)
    assert written == [out / name for name in FILES]
    assert sorted(path.name for path in out.iterdir()) == sorted(FILES)
    for path in written:
        data = path.read_bytes()
        assert data.startswith(PNG_MAGIC)
        with Image.open(path) as image:
            image.load()
            assert 600 <= image.width <= 2000
            assert 150 <= image.height <= 2500
            assert len(image.getcolors(maxcolors=1 << 16) or range(1 << 16)) > 10  # not a blank canvas


def test_the_same_results_give_the_same_bytes_with_no_date_or_version() -> None:
    first = render_plots([catan(), baseline()], title=TITLE)
    again = render_plots([catan(), baseline()], title=TITLE)
    assert first == again
    other = render_plots([baseline(), catan()], title=TITLE)
    assert other[RESPONSES] != first[RESPONSES]  # the bytes do depend on the input
    for data in first.values():
        keys = png_text_keys(data)
        assert b"Software" not in keys
        assert b"Creation Time" not in keys


def test_a_failed_drawing_writes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / RESPONSES).write_bytes(b"old")

    def broken(*args: object) -> Figure:
        raise RuntimeError("boom")

    monkeypatch.setattr(plots, "_rates_figure", broken)  # the last one drawn
    with pytest.raises(RuntimeError, match="boom"):
        write_plots([catan()], tmp_path, title=TITLE)
    assert [path.name for path in tmp_path.iterdir()] == [RESPONSES]
    assert (tmp_path / RESPONSES).read_bytes() == b"old"


def test_a_failed_write_leaves_old_or_new_files_and_no_temporary_ones(tmp_path: Path) -> None:
    (tmp_path / TIMELINE).mkdir()  # a folder where the second file goes: its rename fails
    (tmp_path / RATES).write_bytes(b"old")
    with pytest.raises(OutputError, match=r"timeline\.png: cannot write the plot"):
        write_plots([catan()], tmp_path, title=TITLE)
    assert sorted(path.name for path in tmp_path.iterdir()) == sorted(FILES)  # no .partial files
    assert (tmp_path / RESPONSES).read_bytes().startswith(PNG_MAGIC)
    assert (tmp_path / TIMELINE).is_dir()
    assert (tmp_path / RATES).read_bytes() == b"old"


def test_a_file_where_the_folder_goes_is_an_output_error(tmp_path: Path) -> None:
    (tmp_path / "plots").write_text("not a folder")
    with pytest.raises(OutputError, match="not a folder"):
        write_plots([catan()], tmp_path / "plots", title=TITLE)


# --------------------------------------------------------------------------- the command


def test_simulate_plot_writes_the_files_and_keeps_json_on_stdout_clean(tmp_path: Path) -> None:
    out = tmp_path / "plots"
    args = ["simulate", str(ROOT / "specs" / "nav2d.yaml"), "-k", "1", "--duration", "2"]
    args += ["--policy", "catan", "--policy", "baseline", "--json", "--plot", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert set(json.loads(result.stdout)["policies"]) == {"catan", "baseline"}
    for name in FILES:
        assert (out / name).read_bytes().startswith(PNG_MAGIC)
        assert f"plot: {out / name}" in result.stderr
    assert sorted(path.name for path in out.iterdir()) == sorted(FILES)


def test_simulate_without_plot_never_imports_matplotlib() -> None:
    code = (
        "import sys\n"
        "import catanc.cli, catanc.sim.simulate, catanc.sim.plots\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
