"""Rewriting a spec's values in place: the edited value changes, every other byte stays."""

from __future__ import annotations

import pytest

from catanc.errors import SpecError
from catanc.spec.profile_edit import Edit, apply_edits
from catanc.spec.source import parse_yaml

TEXT = """# a comment that stays
nodes:
  a: {compute_ms: 5}     # five
  b:
    compute_ms: 2.5      # block style
  c: {compute_ms: {modes: [{share: 0.8, ms: 1}, {share: 0.2, ms: 12}]}}  # modal, flow
  d:
    compute_ms:
      modes:
        - {share: 0.5, ms: 3}
        - {share: 0.5, ms: 30}
  e: &shared {compute_ms: 7}
  f: *shared
"""


def edit(*edits: Edit) -> str:
    return apply_edits(TEXT, parse_yaml(TEXT, "x.yaml").source, edits)


def test_a_number_in_flow_style_changes_and_its_comment_keeps_its_column() -> None:
    assert edit(Edit(("nodes", "a", "compute_ms"), "5.25")) == TEXT.replace(
        "{compute_ms: 5}     # five", "{compute_ms: 5.25}  # five"
    )


def test_a_number_in_block_style_changes() -> None:
    assert edit(Edit(("nodes", "b", "compute_ms"), "3")) == TEXT.replace(
        "compute_ms: 2.5      #", "compute_ms: 3        #"
    )


def test_mode_values_change_one_by_one_in_flow_and_block_style() -> None:
    got = edit(
        Edit(("nodes", "c", "compute_ms", "modes", 1, "ms"), "12.5"),
        Edit(("nodes", "d", "compute_ms", "modes", 0, "share"), "0.4"),
        Edit(("nodes", "d", "compute_ms", "modes", 1, "share"), "0.6"),
    )
    want = TEXT.replace("{share: 0.2, ms: 12}]}}  #", "{share: 0.2, ms: 12.5}]}} #")
    want = want.replace("- {share: 0.5, ms: 3}", "- {share: 0.4, ms: 3}").replace(
        "- {share: 0.5, ms: 30}", "- {share: 0.6, ms: 30}"
    )
    assert got == want


def test_a_flow_collection_is_replaced_whole() -> None:
    got = edit(Edit(("nodes", "c", "compute_ms"), "4", whole=True))
    old = "{compute_ms: {modes: [{share: 0.8, ms: 1}, {share: 0.2, ms: 12}]}}  #"
    new = "{compute_ms: 4}" + " " * (len(old) - len("{compute_ms: 4}") - 1) + "#"  # the comment keeps its column
    assert got == TEXT.replace(old, new)


def test_a_number_becomes_modes() -> None:
    got = edit(Edit(("nodes", "a", "compute_ms"), "{modes: [{share: 0.5, ms: 1}, {share: 0.5, ms: 9}]}", whole=True))
    assert "  a: {compute_ms: {modes: [{share: 0.5, ms: 1}, {share: 0.5, ms: 9}]}} # five\n" in got
    assert parse_yaml(got, "x.yaml").data["nodes"]["a"]["compute_ms"]["modes"][1] == {"share": 0.5, "ms": 9}


def test_a_block_collection_is_refused_at_its_line() -> None:
    with pytest.raises(SpecError) as caught:
        edit(Edit(("nodes", "d", "compute_ms"), "4", whole=True))
    assert str(caught.value).startswith("x.yaml:8:5: nodes.d.compute_ms: written in block style")


def test_a_value_two_nodes_share_through_an_alias_is_refused() -> None:
    with pytest.raises(SpecError) as caught:
        edit(Edit(("nodes", "e", "compute_ms"), "8"), Edit(("nodes", "f", "compute_ms"), "9"))
    assert "shares its text with nodes.e.compute_ms (a YAML alias?)" in str(caught.value)


def test_a_value_not_written_is_refused() -> None:
    with pytest.raises(SpecError) as caught:
        edit(Edit(("nodes", "a", "threads"), "2"))
    assert "not written in the spec" in str(caught.value)
