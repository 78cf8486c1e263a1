"""docs/results.md's tables are its JSON's: ``python -m benchmarks.scenarios --tables`` rewrites what stands between
``<!-- tables SOURCE KEY -->`` and ``<!-- end tables -->`` and keeps every other byte."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.scenarios import (
    OUT,
    RESULTS_MD,
    TABLES,
    TablesError,
    rewrite_tables,
    saved_numbers,
    tables_command,
)

LOADS = {"load_average": {"face": {"start": [0.5, 0.25, 1.0], "end": [2.0, 1.5, 1.25]}}}
"""A real.json with one scenario's load averages, whose table is written out by hand below."""

LOAD_TABLE = """\
| scenario | load average (1, 5, 15 min) at the start | at the end |
|---|---|---|
| face | 0.5, 0.25, 1.0 | 2.0, 1.5, 1.25 |"""

PAGE = """\
# Results

Prose before.

<!-- tables real load_average -->

| an old table | typed by hand |

<!-- end tables -->

Prose after, kept.
"""


def test_the_committed_page_holds_the_committed_numbers() -> None:
    text = RESULTS_MD.read_text()
    assert rewrite_tables(text, saved_numbers(OUT), "docs/results.md") == text, (
        "docs/results.md's tables differ from docs/results/*.json: python -m benchmarks.scenarios --tables"
    )


def test_every_saved_scenario_has_its_tables_on_the_page() -> None:
    text = RESULTS_MD.read_text()
    for source, numbers in saved_numbers(OUT).items():
        for key in numbers:
            assert f"<!-- tables {source} {key} -->" in text, f"{source}.json's {key!r} is on no table of the page"


def test_a_block_is_rewritten_and_the_prose_around_it_kept() -> None:
    expected = PAGE.replace("| an old table | typed by hand |", LOAD_TABLE)
    assert rewrite_tables(PAGE, {"real": LOADS}, "page.md") == expected
    assert rewrite_tables(expected, {"real": LOADS}, "page.md") == expected  # a second rewrite changes nothing


@given(
    st.lists(st.text(st.characters(blacklist_categories=["Cs"], blacklist_characters="\n\r<"), max_size=30), max_size=8)
)
def test_prose_without_markers_is_kept_byte_for_byte(prose: list[str]) -> None:
    text = "\n".join(prose)
    page = f"{text}\n<!-- tables real load_average -->\nold\n<!-- end tables -->\n{text}"
    rewritten = rewrite_tables(page, {"real": LOADS}, "page.md")
    assert rewritten == f"{text}\n<!-- tables real load_average -->\n\n{LOAD_TABLE}\n\n<!-- end tables -->\n{text}"


@pytest.mark.parametrize(
    ("page", "message"),
    [
        ("a\n<!-- tables sim face -->\n<!-- end tables -->\n", "page.md:2: <!-- tables sim face -->: no saved numbers"),
        (
            "<!-- tables real vr -->\n<!-- end tables -->\n",
            "page.md:1: <!-- tables real vr -->: real.json holds no 'vr'",
        ),
        ("\n\n<!-- tables real load_average -->\nold\n", "page.md:3: <!-- tables real load_average -->: no <!-- end"),
        ("a\n<!-- end tables -->\n", "page.md:2: <!-- end tables --> without"),
    ],
)
def test_a_marker_that_fits_no_numbers_is_an_error_at_its_line(page: str, message: str) -> None:
    with pytest.raises(TablesError) as caught:
        rewrite_tables(page, {"real": LOADS}, "page.md")
    assert str(caught.value).startswith(message)


def test_every_table_key_is_a_scenario_or_the_load_averages() -> None:
    from benchmarks.scenarios import SCENARIOS

    assert set(TABLES) == {*SCENARIOS, "load_average"}


def test_the_command_checks_rewrites_and_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "real.json").write_text(json.dumps(LOADS))
    page = tmp_path / "results.md"
    page.write_text(PAGE)
    assert tables_command(page, tmp_path, check=True) == 1
    assert page.read_text() == PAGE  # --check writes nothing
    assert tables_command(page, tmp_path, check=False) == 0
    assert page.read_text() == PAGE.replace("| an old table | typed by hand |", LOAD_TABLE)
    assert tables_command(page, tmp_path, check=True) == 0
    page.write_text("<!-- tables sim face -->\n")
    assert tables_command(page, tmp_path, check=False) == 2
    assert page.read_text() == "<!-- tables sim face -->\n"  # nothing written
    assert "results.md:1:" in capsys.readouterr().err
