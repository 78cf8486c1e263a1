"""Reading runtime.json back: the enforcer's starting point, and its errors."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from catanc.artifacts.runtime_table import load_table
from catanc.errors import SpecError
from catanc.model.build import build_problem
from catanc.model.load import load_spec

ROOT = Path(__file__).parents[2]
TABLES = sorted((ROOT / "out").glob("*/cores-*/runtime.json"))


def test_every_committed_table_loads_with_the_spec_it_was_compiled_from() -> None:
    assert TABLES
    for path in TABLES:
        table = load_table(path)
        spec_name = json.loads(path.read_text())["generated_by"]["spec"]
        original = load_spec(ROOT / "specs" / spec_name)
        assert table.app == original.app
        assert table.cores == int(path.parent.name.removeprefix("cores-"))
        assert build_problem(table.spec) == build_problem(original)


def test_a_good_table_loads_without_locating_its_fields(monkeypatch: pytest.MonkeyPatch) -> None:
    """Lines and columns cost a YAML parse of the whole table (~80 ms of every `catanc run`'s
    start-up): only a table with something to report pays for them."""

    def parse_yaml(*_args: object) -> None:
        raise AssertionError("a good table was parsed for its source locations")

    monkeypatch.setattr("catanc.artifacts.runtime_table.parse_yaml", parse_yaml)
    for path in TABLES:
        assert load_table(path).app == json.loads(path.read_text())["app"]


def broken(tmp_path: Path, edit: str, replacement: str) -> Path:
    text = TABLES[0].read_text()
    assert edit in text
    path = tmp_path / "runtime.json"
    path.write_text(text.replace(edit, replacement, 1))
    return path


def diagnostics(path: Path) -> list[str]:
    with pytest.raises(SpecError) as caught:
        load_table(path)
    return [str(d) for d in caught.value.diagnostics]


def line_of(path: Path, fragment: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if fragment in line)


def test_another_format_is_refused_naming_the_line(tmp_path: Path) -> None:
    path = broken(tmp_path, '"format": "catanc-runtime/1"', '"format": "catanc-runtime/9"')
    (message,) = diagnostics(path)
    assert message.startswith(f"{path}:{line_of(path, 'catanc-runtime/9')}:")
    assert "format: this table is in format 'catanc-runtime/9'" in message
    assert "catanc compile" in message


def test_not_json_names_line_and_column(tmp_path: Path) -> None:
    path = broken(tmp_path, '"cores": ', '"cores": ,')
    (message,) = diagnostics(path)
    line = line_of(path, '"cores": ,')
    assert message.startswith(f"{path}:{line}:")
    assert "not JSON" in message


def test_a_bad_spec_inside_names_the_spec_field_and_line(tmp_path: Path) -> None:
    text = TABLES[0].read_text()
    data = json.loads(text)
    first_node = next(iter(data["spec"]["nodes"]))
    path = broken(tmp_path, f'"{first_node}": {{', f'"{first_node}": {{\n        "colour": "red",')
    messages = diagnostics(path)
    assert any(f"spec.nodes.{first_node}.colour" in m and f":{line_of(path, 'colour')}:" in m for m in messages)


def test_a_missing_field_is_named(tmp_path: Path) -> None:
    data = json.loads(TABLES[0].read_text())
    del data["processes"]
    path = tmp_path / "runtime.json"
    path.write_text(json.dumps(data, indent=2))
    (message,) = diagnostics(path)
    assert "'processes'" in message


def test_every_package_ships() -> None:
    """setuptools installs only the packages listed: a forgotten sub-package breaks every non-editable install."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "catanc").rglob("__init__.py")}
    assert found | {"catanc.templates"} == listed
