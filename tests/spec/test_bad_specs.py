"""A catalogue of bad specs: each must be rejected with exactly the diagnostics it lists.

Every ``tests/bad_specs/<case>.yaml`` starts with header comment lines:

- ``# expect: LINE: FIELD: FRAGMENT``, one per diagnostic the loader must
  report: the 1-based LINE it points at, the exact dotted FIELD path it names
  (empty for whole-file errors: ``# expect: 1: : fragment``) and a FRAGMENT
  that must appear, case-sensitive, in its message.  The case lists *every*
  error its spec has: no other diagnostic may appear.
- ``# xfail: REASON`` (optional): the loader is known to get this case wrong;
  the test is a strict xfail, so it starts failing once the loader is fixed.
- any other ``# ...`` line: what the case is about.

Every load must never run a command (YAML python tags). Alias and merge-key
bombs must be rejected by the loader's expansion limit (their cases expect
that message), so no case relies on a clock.

Expectations come from what a user needs to see, not from what the loader
happens to print; a case the loader gets wrong stays, marked xfail.
"""

from __future__ import annotations

import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from catanc.errors import Diagnostic, SpecError
from catanc.model.load import load_spec

CASES_DIR = Path(__file__).parent / "bad_specs"

EXPECT_RE = re.compile(r"^# expect: (?P<line>\d+): (?P<field>(?:[^\s:]| -> | to )*): (?P<fragment>\S.*?)\s*$")
"""A field may name an edge 'a -> b' (``hops_ms.cam -> det``)."""
XFAIL_RE = re.compile(r"^# xfail: (?P<reason>\S.*?)\s*$")

REQUIRED_CATEGORIES = [
    # executors (nodes sharing one thread)
    "executor_unknown_node",
    "executor_node_in_two",
    "executor_unscheduled_node",
    "executor_one_node",
    "executor_overload",
    # processes whose nodes share one thread (catanc.spec.executors), against the executors: entries
    "process_executor_joins_two_processes",
    "process_executor_reaches_outside",
    "process_two_executors_split_one_thread",
    "process_overload",
    # YAML itself
    "yaml_syntax_indent",
    "yaml_syntax_unclosed_bracket",
    "yaml_python_tag",
    "alias_bomb",
    "empty_file",
    "not_mapping",
    # shape
    "unknown_key_top",
    "unknown_key_nested",
    "duplicate_key",
    "wrong_type",
    "version_unknown",
    "version_missing",
    "nonpositive_compute",
    "nonpositive_rate_node",
    "nonpositive_rate_constraint",
    "nonpositive_rate_baseline",
    "nonpositive_rate_batch",
    "negative_weight",
    "contradictory_rate_one_constraint",
    "contradictory_rate_across_constraints",
    # rates a driver offers
    "offered_rates_empty",
    "offered_rates_unsorted",
    "offered_rates_non_positive",
    "offered_rates_above_cap",
    "offered_rates_outside_other_bound",
    "speedup",
    "mode_shares",
    "scheduled_without_compute",
    "rate_hz_on_scheduled",
    "workload_negative_cv",
    "workload_normal_cv_too_large",
    "workload_unknown_dist",
    "workload_growth_nonpositive",
    "workload_spikes_nonpositive",
    "workload_unscheduled",
    "workload_unknown_key",
    # measured hops (docs/explanation/model.md section 5)
    "hops_negative",
    "hops_not_finite",
    "hops_unknown_edge",
    # measured dispatches of heads (docs/explanation/model.md section 5)
    "dispatch_negative_or_not_finite",
    "dispatch_not_a_head",
    # meaning
    "unknown_node_edge",
    "unknown_node_subchain",
    "unknown_node_objective_chain",
    "unknown_node_objective_node",
    "unknown_node_selector",
    "unknown_node_constraint",
    "unknown_node_baseline",
    "baseline_priorities_unknown_subchain",
    "baseline_priorities_not_integer",
    "baseline_priorities_negative",
    "unknown_node_deploy",
    "deploy_callback_group",
    "cycle",
    "cycle_self_loop",
    "subchain_not_path",
    "subchain_node_twice",
    "subchain_missing_node",
    "subchain_unscheduled_node",
    "selector_no_path",
    "objective_chain_not_path",
    "yaml_boolean_key",
]


@dataclass(frozen=True)
class Expectation:
    """One diagnostic a case requires."""

    line: int
    field: str
    fragment: str

    def matches(self, diagnostic: Diagnostic) -> bool:
        return (
            diagnostic.location is not None
            and diagnostic.location.line == self.line
            and diagnostic.field == self.field
            and self.fragment in diagnostic.message
        )

    def __str__(self) -> str:
        return f"line {self.line}: {self.field}: ...{self.fragment}..."


@dataclass(frozen=True)
class Case:
    """A bad spec and what loading it must report."""

    path: Path
    expectations: tuple[Expectation, ...]
    xfail_reason: str | None
    malformed: tuple[str, ...]  # header lines that look like, but are not, expect/xfail lines


def header_lines(path: Path) -> list[str]:
    """The comment lines the file starts with (the body may be deliberately broken, even non-UTF-8)."""
    lines = []
    for raw in path.read_bytes().splitlines():
        if not raw.startswith(b"#"):
            break
        lines.append(raw.decode("utf-8"))
    return lines


def read_case(path: Path) -> Case:
    expectations = []
    reasons = []
    malformed = []
    for line in header_lines(path):
        expect = EXPECT_RE.match(line)
        xfail = XFAIL_RE.match(line)
        if expect is not None:
            expectations.append(Expectation(int(expect["line"]), expect["field"], expect["fragment"]))
        elif xfail is not None:
            reasons.append(xfail["reason"])
        elif re.match(r"#\s*(expect|xfail)", line, re.IGNORECASE):
            # A near miss (``#expect:``, ``# expect: 3 field``) must not silently drop an expectation.
            malformed.append(line)
    return Case(path, tuple(expectations), " ".join(reasons) or None, tuple(malformed))


def case_paths() -> list[Path]:
    return sorted(CASES_DIR.glob("*.yaml"))


def case_params() -> list[Any]:
    params = []
    for path in case_paths():
        case = read_case(path)
        marks = [pytest.mark.xfail(strict=True, reason=case.xfail_reason)] if case.xfail_reason else []
        params.append(pytest.param(case, id=path.stem, marks=marks))
    return params


def match_all(expectations: tuple[Expectation, ...], diagnostics: list[Diagnostic]) -> bool:
    """Whether expectations and diagnostics pair up one to one."""
    if len(expectations) != len(diagnostics):
        return False
    if not expectations:
        return True
    first, rest = expectations[0], expectations[1:]
    for index, diagnostic in enumerate(diagnostics):
        if first.matches(diagnostic) and match_all(rest, diagnostics[:index] + diagnostics[index + 1 :]):
            return True
    return False


@pytest.fixture
def no_shell(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Record (and refuse) any attempt to run a command while a spec loads."""
    calls: list[str] = []

    def refuse(*args: object, **kwargs: object) -> Any:
        calls.append(repr(args))
        raise AssertionError(f"loading a spec tried to run a command: {args!r}")

    monkeypatch.setattr(os, "system", refuse)
    monkeypatch.setattr(os, "popen", refuse)
    monkeypatch.setattr(subprocess, "Popen", refuse)
    return calls


@pytest.mark.parametrize("case", case_params())
def test_bad_spec(case: Case, no_shell: list[str]) -> None:
    with pytest.raises(SpecError) as caught:
        load_spec(case.path)
    assert no_shell == []
    diagnostics = caught.value.diagnostics
    got = "\n".join(f"  line {d.location.line if d.location else '?'}: {d.field}: {d.message}" for d in diagnostics)
    wanted = "\n".join(f"  {e}" for e in case.expectations)
    assert match_all(case.expectations, diagnostics), f"expected:\n{wanted}\ngot:\n{got}"
    for diagnostic in diagnostics:  # compiler style: FILE:LINE:COL: field: message
        assert diagnostic.location is not None
        assert diagnostic.location.file == str(case.path)
        where = f"{case.path}:{diagnostic.location.line}:{diagnostic.location.column}: "
        assert str(diagnostic) == where + (f"{diagnostic.field}: " if diagnostic.field else "") + diagnostic.message


@pytest.mark.parametrize("path", case_paths(), ids=lambda path: path.stem)
def test_case_states_expectations(path: Path) -> None:
    case = read_case(path)
    assert case.expectations, f"{path.name} has no '# expect: LINE: FIELD: FRAGMENT' header line"
    assert not case.malformed, f"{path.name}: malformed header lines {list(case.malformed)}"


@pytest.mark.parametrize("category", REQUIRED_CATEGORIES)
def test_catalogue_covers(category: str) -> None:
    names = [path.stem for path in case_paths()]
    assert any(name.startswith(category) for name in names), f"no case tests/bad_specs/{category}*.yaml"


@pytest.mark.parametrize("text", ["", "\n\n", "   \n"], ids=["no-bytes", "blank-lines", "spaces"])
def test_truly_empty_file(tmp_path: Path, text: str) -> None:
    """A case file needs a header, so files without a single comment are checked here."""
    path = tmp_path / "empty.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SpecError) as caught:
        load_spec(path)
    [diagnostic] = caught.value.diagnostics
    assert diagnostic.location is not None
    assert (diagnostic.location.line, diagnostic.field) == (1, "")
    assert "empty" in diagnostic.message
