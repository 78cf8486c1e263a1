"""Spec text -> :class:`~catanc.spec.language.Spec`: the passes of syntax and shape.

Loading a spec has three passes, each reporting every problem it finds as a
compiler-style diagnostic: YAML syntax (:mod:`catanc.spec.source`), shape
(the pydantic models, here, with pydantic's errors mapped onto the YAML's
lines and fields) and meaning (:func:`catanc.model.build.build_problem`:
names, the DAG, paths).  :mod:`catanc.model.load` runs all three.
"""

from __future__ import annotations

import hashlib
import types
from collections.abc import Hashable
from pathlib import Path
from typing import Annotated, Any, Union, get_args, get_origin

from pydantic import BaseModel, Tag, ValidationError

from catanc.errors import Diagnostic, FieldPath, SpecError, close_matches, did_you_mean, format_path
from catanc.spec.language import ARROW_EDGE_PATTERN, SPEC_VERSIONS, Spec
from catanc.spec.source import SourceMap, parse_yaml, read_text

_TYPE_NAMES = {
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "an integer",
    "int_from_float": "an integer",
    "int_parsing": "an integer",
    "string_type": "a string",
    "bool_type": "true or false",
    "list_type": "a list",
    "dict_type": "a mapping",
    "model_type": "a mapping",
    "model_attributes_type": "a mapping",
}

_KIND_KEYS = ["chain", "chains", "node", "modes"]
"""Keys that pick the kind of an objective term, constraint or compute profile."""


def read_spec_text(path: str | Path) -> tuple[str, str]:
    """A spec file's text and the sha256 of its bytes (output headers name it); :class:`SpecError` if unreadable."""
    raw, text = read_text(path, "spec")
    return text, hashlib.sha256(raw).hexdigest()


def parse_shape(text: str, file: str) -> tuple[Spec, list[Diagnostic]]:
    """Spec text through the first two passes, syntax and shape; ``file`` is only used in messages.

    Raises :class:`SpecError` when the shape is wrong; else returns the spec and the syntax pass's
    problems that did not stop it (a duplicated key, say), to be reported with the meaning pass's.
    """
    parsed = parse_yaml(text, file)
    try:
        spec = validate_data(parsed.data, parsed.source)
    except SpecError as exc:
        raise SpecError(parsed.problems + exc.diagnostics) from None
    return spec, parsed.problems


def validate_data(data: Any, source: SourceMap) -> Spec:
    """Check the shape of plain data against the spec models; raise :class:`SpecError`."""
    if not isinstance(data, dict):
        message = f"a spec is a mapping with catan, app, nodes, edges, ...; this document is {_describe(data)}"
        raise SpecError([Diagnostic(source.locate(()), "", message)])
    version = data.get("catan")
    if isinstance(version, int) and not isinstance(version, bool) and version not in SPEC_VERSIONS:
        # An unknown version is reported alone: the rest may be a different language.
        known = ", ".join(str(v) for v in SPEC_VERSIONS)
        message = f"unknown spec version {version}; this catanc reads version {known}"
        raise SpecError([Diagnostic(source.locate(("catan",)), "catan", message)])
    try:
        spec = Spec.model_validate(data)
    except ValidationError as exc:
        raise SpecError(_diagnostics(exc, data, source)) from None
    spec._source = source
    return spec


def _diagnostics(exc: ValidationError, data: Any, source: SourceMap) -> list[Diagnostic]:
    errors = exc.errors(include_url=False)
    # A misspelt required key is one problem: its "unknown field" message
    # already suggests the right name, so the "missing" twin is dropped.
    misspelt = {
        (tuple(error["loc"][:-1]), suggestion)
        for error in errors
        if error["type"] == "extra_forbidden"
        for suggestion in close_matches(str(error["loc"][-1]), _allowed_fields(tuple(error["loc"][:-1])))
    }
    diagnostics = []
    for error in errors:
        loc = tuple(error["loc"])
        if error["type"] == "missing" and (loc[:-1], loc[-1]) in misspelt:
            continue
        path, rest = _data_path(loc, data)
        on_key = rest[-1:] == ("[key]",)
        message = _message(error, loc)
        location = source.locate(path, at_key=on_key or error["type"] == "extra_forbidden")
        diagnostics.append(Diagnostic(location, format_path(path), message))
    return diagnostics


def _data_path(loc: tuple[Hashable, ...], data: Any) -> tuple[FieldPath, tuple[Hashable, ...]]:
    """Split a pydantic ``loc`` into the part that exists in the data and the rest.

    Pydantic inserts union tags and validator names into ``loc``; those are not
    in the data and are skipped.
    """
    path: list[Hashable] = []
    rest: list[Hashable] = []
    node: Any = data
    for part in loc:
        found, child = _child(node, part)
        if found:
            path.append(part)
            node = child
        else:
            rest.append(part)
    return tuple(path), tuple(rest)


def _child(node: Any, part: Hashable) -> tuple[bool, Any]:
    """``(True, node[part])`` when ``part`` names a key or index of ``node``."""
    if isinstance(node, dict) and part in node:
        return True, node[part]
    if isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
        return True, node[part]
    return False, None


def _describe(value: Any) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "nothing (null)"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _message(error: Any, loc: tuple[Hashable, ...]) -> str:
    kind: str = error["type"]
    ctx: dict[str, Any] = error.get("ctx") or {}
    value = error.get("input")
    if kind == "missing":
        name = loc[-1]
        hint = " (add `catan: 1` as the first line)" if loc == ("catan",) else ""
        return f"missing required field {name!r}{hint}"
    if kind == "extra_forbidden":
        allowed = _allowed_fields(loc[:-1])
        return f"unknown field {loc[-1]!r}" + did_you_mean(str(loc[-1]), allowed, listing=True)
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()))
        return f"must be {op} {bound:g}, got {_describe(value)}"
    if kind == "finite_number":
        return f"must be a finite number, got {_describe(value)}"
    if kind == "string_pattern_mismatch" and ctx.get("pattern") == ARROW_EDGE_PATTERN:
        return f"expected an edge as 'a -> b' (or [a, b]) between two node names, got {_describe(value)}"
    if kind == "string_pattern_mismatch":
        return f"{_describe(value)} is not a valid name: use letters, digits and _, not starting with a digit"
    if kind in ("too_short", "too_long") and loc[:1] == ("edges",):
        count = len(value) if isinstance(value, list) else 0
        return f"an edge is [a, b]: two node names, got {count} (write a longer path as one edge per pair)"
    if kind == "too_short" and loc[:1] == ("executors",):
        return "an executor lists at least 2 nodes (one node alone never overlaps itself: remove the entry)"
    if kind == "too_short":
        return "must not be empty" if ctx.get("min_length") == 1 else error["msg"].lower()
    if kind == "too_long":
        return f"{error['msg'].lower()}"
    if kind in _TYPE_NAMES:
        hint = ""
        if kind == "string_type" and (value is None or isinstance(value, bool)):
            hint = " (YAML reads unquoted yes/no/on/off/true/false/null that way: quote the name)"
        return f"expected {_TYPE_NAMES[kind]}, got {_describe(value)}{hint}"
    text: str = error["msg"]
    if isinstance(value, dict) and kind.endswith("_kind"):
        keys = [str(key) for key in value]
        return f"{text}; got keys {', '.join(keys) or '(none)'}" + did_you_mean(keys[0], _KIND_KEYS) if keys else text
    return f"{text}, got {_describe(value)}" if value is not None else text


def _allowed_fields(loc: tuple[Hashable, ...]) -> list[str]:
    """Field names of the spec model found at ``loc`` (for unknown-key messages)."""
    annotation: Any = Spec
    for part in loc:
        annotation = _step(annotation, part)
        if annotation is None:
            return []
    model = _model_in(annotation) or _optional_model(annotation)
    if model is None:
        return []
    return [info.alias or name for name, info in model.model_fields.items()]


def _unwrap(annotation: Any) -> Any:
    while get_origin(annotation) is Annotated:
        annotation = get_args(annotation)[0]
    return annotation


def _model_in(annotation: Any) -> type[BaseModel] | None:
    annotation = _unwrap(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    return None


def _optional_model(annotation: Any) -> type[BaseModel] | None:
    """The model of an optional field (``Workload | None``), whose errors' locations name no union member."""
    bare = _unwrap(annotation)
    if get_origin(bare) not in (Union, types.UnionType):
        return None
    members = [member for member in get_args(bare) if member is not type(None)]
    return _model_in(members[0]) if len(members) == 1 else None


def _step(annotation: Any, part: Hashable) -> Any:
    bare = _unwrap(annotation)
    model = _model_in(bare)
    if model is not None:
        for name, info in model.model_fields.items():
            if part in (name, info.alias):
                return info.annotation
        return None
    origin = get_origin(bare)
    if origin in (Union, types.UnionType):
        members = get_args(bare)
        for member in members:
            tags = get_args(member)[1:] if get_origin(member) is Annotated else ()
            if any(isinstance(tag, Tag) and tag.tag == part for tag in tags):
                return member
        for member in members:
            found = _step(member, part)
            if found is not None:
                return found
        return None
    if origin is dict:
        return get_args(bare)[1]
    if origin is list:
        return get_args(bare)[0]
    return None
