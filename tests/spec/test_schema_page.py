"""``catanc schema --markdown``: docs/reference/spec-fields.md is the spec's models, field for field."""

from __future__ import annotations

import re
from pathlib import Path

from pydantic import BaseModel
from typer.testing import CliRunner

from catanc.cli.main import app
from catanc.spec import language
from catanc.spec.schema_page import schema_page

PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "spec-fields.md"


def test_the_committed_page_is_what_the_command_prints() -> None:
    printed = CliRunner().invoke(app, ["schema", "--markdown"]).stdout
    assert PAGE.read_text() == printed, "regenerate: catanc schema --markdown > docs/reference/spec-fields.md"


def sections(text: str) -> dict[str, set[str]]:
    """Each ``## Model`` section's fields, from the first column of its table."""
    found: dict[str, set[str]] = {}
    current = ""
    for line in text.splitlines():
        if line.startswith("## "):
            current = line[3:]
            found[current] = set()
        elif line.startswith("| `") and current:
            found[current].add(re.findall(r"`([^`]+)`", line)[0])
    return found


def test_every_model_of_the_spec_language_has_its_fields_on_the_page() -> None:
    on_page = sections(PAGE.read_text())
    models = {"Spec", *language.json_schema()["$defs"]}
    assert set(on_page) == models
    for name in models:
        model = getattr(language, name)
        assert isinstance(model, type)
        assert issubclass(model, BaseModel)
        fields = {info.alias or field for field, info in model.model_fields.items()}
        assert on_page[name] == fields, f"{name}: page {sorted(on_page[name])} against the model {sorted(fields)}"


SMALL = {
    "properties": {
        "period": {"type": "number", "exclusiveMinimum": 0, "maximum": 1e9, "description": "A | B."},
        "share": {"type": "number", "minimum": 0, "exclusiveMaximum": 1, "default": 0.05},
        "kind": {"anyOf": [{"enum": ["a", "b"]}, {"pattern": "^(?:[aA]|[bB])$"}], "default": "a", "type": "string"},
        "part": {"anyOf": [{"$ref": "#/$defs/Part"}, {"type": "null"}], "default": None},
        "edges": {
            "type": "array",
            "items": {"type": "array", "minItems": 2, "maxItems": 2, "items": {"type": "integer"}},
        },
    },
    "required": ["period"],
    "$defs": {"Part": {"description": "A part.", "properties": {"n": {"type": "integer", "minimum": 1}}}},
}


def test_a_small_schema_by_hand() -> None:
    page = schema_page(SMALL)
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    assert rows == [
        "| `period` | number > 0 | required | A \\| B. |",
        "| `share` | number >= 0, < 1 | `0.05` |  |",
        '| `kind` | `"a"` or `"b"` | `"a"` |  |',
        "| `part` | [Part](#part) | none | A part. |",
        "| `edges` | list of pair of integer | optional |  |",
        "| `n` | integer >= 1 | optional |  |",
    ]
    assert page.index("## Spec") < page.index("## Part")
