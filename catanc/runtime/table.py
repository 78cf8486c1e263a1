"""Reading a runtime table (``runtime.json``) back: what the enforcer starts from.

The table carries the normalised spec, so the enforcer re-plans without
the YAML.  :func:`load_table` refuses a table of another ``format`` and
reports a broken one like a bad spec: file, line, field, what is wrong.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catanc.artifacts.emit import RUNTIME_FORMAT
from catanc.core.problem import build_problem
from catanc.errors import Diagnostic, FieldPath, Location, SpecError
from catanc.spec.language import Spec
from catanc.spec.load import validate_data
from catanc.spec.source import SourceMap, parse_yaml

REQUIRED = {"format": str, "app": str, "cores": int, "spec": dict, "plan": dict, "processes": list}


@dataclass(frozen=True)
class RuntimeTable:
    path: Path
    app: str
    cores: int
    spec: Spec
    plan: dict[str, Any]  # interfaces.md's ``plan``
    processes: tuple[dict[str, Any], ...]


def load_table(path: str | Path) -> RuntimeTable:
    """Read and check a runtime table; raise :class:`SpecError` naming the file, line and field."""
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise SpecError([Diagnostic(None, "", f"{file}: cannot read the runtime table: {reason}")]) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        location = Location(file, exc.lineno, exc.colno)
        raise SpecError([Diagnostic(location, "", f"not JSON: {exc.msg}")]) from None
    source = _source_map(text, file)

    def fail(field: FieldPath, message: str) -> SpecError:
        return SpecError([Diagnostic(source.locate(field), ".".join(map(str, field)), message)])

    if not isinstance(data, dict):
        raise fail((), "a runtime table is a JSON object (written by `catanc compile`)")
    found = data.get("format")
    if found != RUNTIME_FORMAT:
        what = "has no format" if found is None else f"is in format {found!r}"
        raise fail(
            ("format",),
            f"this table {what}; this catanc reads {RUNTIME_FORMAT!r}: regenerate it with `catanc compile`",
        )
    for key, kind in REQUIRED.items():
        value = data.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise fail((key,) if key in data else (), f"missing or not a {kind.__name__}: {key!r}")
    spec = _spec(data["spec"], source)
    if spec.app != data["app"]:
        raise fail(("app",), f"the table is for app {data['app']!r} but its spec is for {spec.app!r}")
    if data["cores"] < 1:
        raise fail(("cores",), "at least one core")
    return RuntimeTable(
        path=Path(path),
        app=data["app"],
        cores=data["cores"],
        spec=spec,
        plan=data["plan"],
        processes=tuple(data["processes"]),
    )


def _source_map(text: str, file: str) -> SourceMap:
    """Lines and columns of the table's fields (JSON is YAML); none if YAML cannot read it."""
    try:
        return parse_yaml(text, file).source
    except SpecError:
        return SourceMap(file)


def _spec(data: dict[str, Any], table: SourceMap) -> Spec:
    """The table's spec, checked as a spec file would be; diagnostics name ``spec.<field>``."""
    inner = SourceMap(
        table.file,
        values={path[1:]: where for path, where in table.values.items() if path[:1] == ("spec",)},
        keys={path[1:]: where for path, where in table.keys.items() if path[:1] == ("spec",)},
    )
    try:
        spec = validate_data(data, inner)
        build_problem(spec)
    except SpecError as exc:
        raise SpecError(
            [Diagnostic(d.location, f"spec.{d.field}" if d.field else "spec", d.message) for d in exc.diagnostics]
        ) from None
    return spec
