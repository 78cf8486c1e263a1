"""YAML text to plain data, remembering where every value came from.

Only plain mappings, lists and scalars are built (safe loading: no tag ever
constructs a Python object).  The :class:`SourceMap` lets later stages point
an error at ``FILE:LINE:COL`` given a field path such as
``("subchains", "local", 1)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from catanc.errors import Diagnostic, FieldPath, Location, SpecError, format_path

MAX_VALUES = 100_000
"""Values a document may expand to (aliases included): stops alias bombs."""

MAX_DEPTH = 64

_PLAIN_MAP = "tag:yaml.org,2002:map"
_PLAIN_SEQ = "tag:yaml.org,2002:seq"
_MERGE = "tag:yaml.org,2002:merge"
_PLAIN_SCALARS = frozenset(f"tag:yaml.org,2002:{kind}" for kind in ("str", "int", "float", "bool", "null"))


@dataclass(frozen=True)
class SourceMap:
    """Positions of the values (and mapping keys) of one YAML document."""

    file: str
    values: Mapping[FieldPath, tuple[int, int]] = field(default_factory=dict)
    keys: Mapping[FieldPath, tuple[int, int]] = field(default_factory=dict)

    def locate(self, path: FieldPath, *, at_key: bool = False) -> Location:
        """Where ``path`` is written; falls back to the nearest enclosing field."""
        if at_key and path in self.keys:
            return Location(self.file, *self.keys[path])
        for length in range(len(path), 0, -1):
            prefix = path[:length]
            if prefix in self.values:
                return Location(self.file, *self.values[prefix])
        return Location(self.file, 1, 1)

    def has(self, path: FieldPath) -> bool:
        return path in self.values


def parse_yaml(text: str, file: str) -> tuple[Any, SourceMap, list[Diagnostic]]:
    """Parse one YAML document into plain data, its source map and non-fatal problems.

    Duplicate keys are returned as diagnostics (the first value is kept) so
    later checks still run; syntax errors, unsupported tags and documents
    that expand too far raise :class:`SpecError`.
    """
    loader: yaml.SafeLoader | None = None
    try:
        try:
            loader = yaml.SafeLoader(text)  # checks every character up front
            root = loader.get_single_node()
        except yaml.MarkedYAMLError as exc:
            raise SpecError([_syntax_diagnostic(exc, file)]) from None
        except yaml.reader.ReaderError as exc:
            line, column = _line_col(text, exc.position)
            message = f"unreadable character {chr(exc.character)!r}: {exc.reason}"
            raise SpecError([Diagnostic(Location(file, line, column), "", message)]) from None
        except yaml.YAMLError as exc:
            raise SpecError([Diagnostic(Location(file, 1, 1), "", f"YAML error: {exc}")]) from None
        if root is None:
            raise SpecError([Diagnostic(Location(file, 1, 1), "", "the file is empty; a spec starts with `catan: 1`")])
        builder = _Builder(loader, file)
        data = builder.build(root, ())
        return data, SourceMap(file, builder.values, builder.keys), builder.diagnostics
    finally:
        if loader is not None:
            loader.dispose()


def _line_col(text: str, position: int) -> tuple[int, int]:
    before = text[:position]
    return before.count("\n") + 1, position - (before.rfind("\n") + 1) + 1


def _mark(node: yaml.Node) -> tuple[int, int]:
    return node.start_mark.line + 1, node.start_mark.column + 1


def _yaml_kind(value: Any) -> str:
    return "null" if value is None else "a boolean"


def _syntax_diagnostic(exc: yaml.MarkedYAMLError, file: str) -> Diagnostic:
    mark = exc.problem_mark or exc.context_mark
    location = Location(file, mark.line + 1, mark.column + 1) if mark else Location(file, 1, 1)
    parts = [part for part in (exc.context, exc.problem) if part]
    return Diagnostic(location, "", "YAML syntax error: " + ", ".join(parts))


class _Builder:
    """Walks composed YAML nodes, building data and recording marks."""

    def __init__(self, loader: yaml.SafeLoader, file: str) -> None:
        self.loader = loader
        self.file = file
        self.values: dict[FieldPath, tuple[int, int]] = {}
        self.keys: dict[FieldPath, tuple[int, int]] = {}
        self.diagnostics: list[Diagnostic] = []
        self.count = 0
        self.merged_counts: dict[int, int] = {}  # id(mapping node) -> merged pairs in front
        self.reported_keys: set[int] = set()

    def _fail(self, node: yaml.Node, path: FieldPath, message: str) -> SpecError:
        return SpecError([Diagnostic(Location(self.file, *_mark(node)), format_path(path), message)])

    def build(self, node: yaml.Node, path: FieldPath) -> Any:
        self.count += 1
        if self.count > MAX_VALUES:
            raise self._fail(node, path, f"the document expands to more than {MAX_VALUES} values (alias bomb?)")
        if len(path) > MAX_DEPTH:
            raise self._fail(node, path, f"nested deeper than {MAX_DEPTH} levels")
        self.values.setdefault(path, _mark(node))
        if isinstance(node, yaml.ScalarNode):
            return self._scalar(node, path)
        if isinstance(node, yaml.SequenceNode):
            self._check_tag(node, path, _PLAIN_SEQ)
            return [self.build(item, (*path, index)) for index, item in enumerate(node.value)]
        if isinstance(node, yaml.MappingNode):
            self._check_tag(node, path, _PLAIN_MAP)
            return self._mapping(node, path)
        raise self._fail(node, path, "unsupported YAML node")  # pragma: no cover - composer makes only these

    def _check_tag(self, node: yaml.Node, path: FieldPath, plain: str) -> None:
        if node.tag != plain:
            raise self._fail(
                node, path, f"unsupported YAML tag {node.tag}: a spec uses plain mappings, lists and scalars"
            )

    def _scalar(self, node: yaml.ScalarNode, path: FieldPath) -> Any:
        if node.tag not in _PLAIN_SCALARS:
            raise self._fail(node, path, f"unsupported YAML tag {node.tag}: use a plain number, string or boolean")
        try:
            return self.loader.construct_object(node, deep=True)
        except yaml.MarkedYAMLError as exc:
            raise self._fail(node, path, f"cannot read value: {exc.problem}") from None

    def _mapping(self, node: yaml.MappingNode, path: FieldPath) -> dict[str, Any]:
        if id(node) not in self.merged_counts:  # an aliased mapping is flattened once
            explicit = sum(1 for key_node, _ in node.value if key_node.tag != _MERGE)
            try:
                self.loader.flatten_mapping(node)  # puts `<<` merged pairs first
            except yaml.MarkedYAMLError as exc:
                raise self._fail(node, path, f"bad merge key: {exc.problem}") from None
            self.merged_counts[id(node)] = len(node.value) - explicit
        merged_count = self.merged_counts[id(node)]
        pairs: dict[str, tuple[yaml.Node, yaml.Node]] = {}
        for key_node, value_node in node.value[:merged_count]:
            pairs[self._key(key_node, path)] = (key_node, value_node)  # later merges win, as in YAML
        first_seen: dict[str, yaml.Node] = {}
        for key_node, value_node in node.value[merged_count:]:
            key = self._key(key_node, path)
            if key in first_seen:
                line = _mark(first_seen[key])[0]
                self.diagnostics.append(
                    Diagnostic(
                        Location(self.file, *_mark(key_node)),
                        format_path((*path, key)),
                        f"duplicate key {key!r} (first given on line {line})",
                    )
                )
                continue
            first_seen[key] = key_node
            pairs[key] = (key_node, value_node)  # explicit keys override merged ones
        result: dict[str, Any] = {}
        for key, (key_node, value_node) in pairs.items():
            child: FieldPath = (*path, key)
            self.keys[child] = _mark(key_node)
            result[key] = self.build(value_node, child)
        return result

    def _key(self, key_node: yaml.Node, path: FieldPath) -> str:
        """A mapping key as text: every key of a spec is a name or a field."""
        if not isinstance(key_node, yaml.ScalarNode):
            raise self._fail(key_node, path, "mapping keys must be plain names")
        key = self._scalar(key_node, path)
        if isinstance(key, str):
            return key
        # A number is just an invalid name (later checks say so); a boolean or
        # null key is YAML 1.1 reading `on`, `no`, `null` as values: quoting fixes it.
        # (Reported once per key: an aliased mapping is visited more than once.)
        if (key is None or isinstance(key, bool)) and id(key_node) not in self.reported_keys:
            self.reported_keys.add(id(key_node))
            self.diagnostics.append(
                Diagnostic(
                    Location(self.file, *_mark(key_node)),
                    format_path((*path, key_node.value)),
                    f"YAML reads the key {key_node.value} as {_yaml_kind(key)}, not a name; "
                    f"quote it: '{key_node.value}'",
                )
            )
        return str(key_node.value)
