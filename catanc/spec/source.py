"""YAML text to plain data, remembering where every value came from.

Only plain mappings, lists and scalars are built (safe loading: no tag ever
constructs a Python object).  The :class:`SourceMap` lets later stages point
an error at ``FILE:LINE:COL`` given a field path such as
``("subchains", "local", 1)``.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from catanc.errors import Diagnostic, FieldPath, Location, SpecError, format_path

MAX_VALUES = 100_000
"""Values a document may expand to (aliases included): stops alias bombs."""

MAX_DEPTH = 64

MAX_FILE_BYTES = 4 * 1024 * 1024
"""The largest spec (or runtime table) read: a real one is a few kilobytes."""

_PLAIN_MAP = "tag:yaml.org,2002:map"
_PLAIN_SEQ = "tag:yaml.org,2002:seq"
_MERGE = "tag:yaml.org,2002:merge"
_PLAIN_SCALARS = frozenset(f"tag:yaml.org,2002:{kind}" for kind in ("str", "int", "float", "bool", "null"))


class UnreadableFile(OSError):  # noqa: N818 - an OSError like the ones it stands beside
    """A file refused before it is read (not a regular file, or too big)."""


def read_input(path: str | os.PathLike[str], limit: int = MAX_FILE_BYTES) -> bytes:
    """A regular file's bytes, at most ``limit`` of them; :class:`UnreadableFile` (an ``OSError``, with the reason
    as its ``strerror``) for a FIFO, a device such as /dev/zero, a folder or a bigger file, before reading it."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # a FIFO must not block the open
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            what = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file (a FIFO, a device?)"
            raise UnreadableFile(0, f"{what}: refusing to read it")
        if info.st_size > limit:
            raise UnreadableFile(0, f"{info.st_size} bytes; at most {limit} are read")
        chunks = []
        size = 0
        while chunk := os.read(fd, 1 << 16):
            size += len(chunk)
            if size > limit:  # it grew since fstat
                raise UnreadableFile(0, f"more than {limit} bytes; at most {limit} are read")
            chunks.append(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


@dataclass(frozen=True)
class SourceMap:
    """Positions of the values (and mapping keys) of one YAML document.

    A mapping or list written under a key is located at its key: that line
    names the field, while the collection itself may start lines below.
    """

    file: str
    values: Mapping[FieldPath, tuple[int, int]] = field(default_factory=dict)
    keys: Mapping[FieldPath, tuple[int, int]] = field(default_factory=dict)
    shadowed: Mapping[FieldPath, Any] = field(default_factory=dict)
    """Values of duplicate keys, dropped in favour of the first (already reported)."""

    def locate(self, path: FieldPath, *, at_key: bool = False) -> Location:
        """Where ``path`` is written; falls back to the nearest enclosing field."""
        if at_key and path in self.keys:
            return Location(self.file, *self.keys[path])
        for length in range(len(path), -1, -1):
            prefix = path[:length]
            if prefix in self.values:
                return Location(self.file, *self.values[prefix])
        return Location(self.file, 1, 1)


@dataclass(frozen=True)
class ParsedYaml:
    """A document's data, where each value came from, and its non-fatal problems."""

    data: Any
    source: SourceMap
    problems: list[Diagnostic]  # duplicate keys, keys YAML reads as booleans


def read_text(path: str | Path, what: str) -> tuple[bytes, str]:
    """A file's bytes and their UTF-8 text; a :class:`SpecError` naming the file (and where the bad byte is)."""
    file = str(path)
    try:
        raw = read_input(path)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise SpecError([Diagnostic(None, "", f"{file}: cannot read {what}: {reason}")]) from None
    try:
        return raw, raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        location = Location(file, line, exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1)
        raise SpecError([Diagnostic(location, "", "the file is not UTF-8 text")]) from None


def parse_yaml(text: str, file: str) -> ParsedYaml:
    """Parse one YAML document into plain data and its source map.

    Duplicate keys are reported as problems (the first value is kept) so
    later checks still run; syntax errors, unsupported tags and documents
    that expand too far raise :class:`SpecError`.
    """
    loader: _Loader | None = None
    try:
        try:
            loader = _Loader(text, file)  # checks every character up front
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
        source = SourceMap(file, builder.values, builder.keys, builder.shadowed)
        return ParsedYaml(data, source, builder.problems)
    finally:
        if loader is not None:
            loader.dispose()


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, with a :class:`SpecError` at the first collection nested deeper than :data:`MAX_DEPTH`.

    PyYAML's composer recurses once per level; the parser's events are
    counted as the composer takes them, so a document of a thousand ``[`` is
    an error and not a crash, in the same one pass over the text.
    """

    def __init__(self, text: str, file: str) -> None:
        super().__init__(text)
        self.file = file
        self.depth = 0

    def get_event(self) -> yaml.Event:
        event: yaml.Event = super().get_event()  # type: ignore[no-untyped-call]
        if isinstance(event, yaml.CollectionStartEvent):
            self.depth += 1
            if self.depth > MAX_DEPTH:
                mark = event.start_mark
                line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
                message = f"nested deeper than {MAX_DEPTH} levels (a spec needs a handful)"
                raise SpecError([Diagnostic(Location(self.file, line, column), "", message)])
        elif isinstance(event, yaml.CollectionEndEvent):
            self.depth -= 1
        return event


def _line_col(text: str, position: int) -> tuple[int, int]:
    before = text[:position]
    return before.count("\n") + 1, position - (before.rfind("\n") + 1) + 1


def _mark(node: yaml.Node) -> tuple[int, int]:
    return node.start_mark.line + 1, node.start_mark.column + 1


_INDENT_HINTS = ("expected <block end>", "could not find expected ':'", "mapping values are not allowed here")


def _syntax_diagnostic(exc: yaml.MarkedYAMLError, file: str) -> Diagnostic:
    """PyYAML's error, pointed at the line a person has to fix."""
    problem = exc.problem or "invalid YAML"
    context_mark, problem_mark = exc.context_mark, exc.problem_mark
    context = exc.context or ""
    if "flow" in context and context_mark and problem_mark and context_mark.line != problem_mark.line:
        # A [ or { left open: the parser notices lines later (or at the end of the file).
        opener = "[" if "sequence" in context else "{"
        message = (
            f"YAML syntax error: the '{opener}' opened here is not closed ({problem} on line {problem_mark.line + 1})"
        )
        return Diagnostic(Location(file, context_mark.line + 1, context_mark.column + 1), "", message)
    mark = problem_mark or context_mark
    location = Location(file, mark.line + 1, mark.column + 1) if mark else Location(file, 1, 1)
    message = "YAML syntax error: " + ", ".join(part for part in (context, problem) if part)
    if any(hint in problem for hint in _INDENT_HINTS):
        message += " (check this line's indentation: keys of one mapping must line up, values need a space after ':')"
    return Diagnostic(location, "", message)


class _Builder:
    """Walks composed YAML nodes, building data and recording marks."""

    def __init__(self, loader: yaml.SafeLoader, file: str) -> None:
        self.loader = loader
        self.file = file
        self.values: dict[FieldPath, tuple[int, int]] = {}
        self.keys: dict[FieldPath, tuple[int, int]] = {}
        self.problems: list[Diagnostic] = []
        self.shadowed: dict[FieldPath, Any] = {}
        self.count = 0
        self.visited: set[int] = set()  # ids of nodes built once: a second visit is an alias
        self.stack: list[tuple[FieldPath, bool]] = []  # (path, reached through an alias)
        self.resolved: dict[int, dict[str, tuple[yaml.Node, yaml.Node]]] = {}  # mapping id -> its pairs
        self.resolving: set[int] = set()

    def _fail(self, node: yaml.Node, path: FieldPath, message: str) -> SpecError:
        return SpecError([Diagnostic(Location(self.file, *_mark(node)), format_path(path), message)])

    def _bomb(self, node: yaml.Node) -> SpecError:
        """Blame the field whose value an alias first made too big."""
        for index, (_, aliased) in enumerate(self.stack):
            if aliased and index > 0:
                field_path = self.stack[index - 1][0]
                location = Location(self.file, *self.values.get(field_path, _mark(node)))
                message = f"expands to more than {MAX_VALUES} values through YAML aliases (an alias bomb?)"
                return SpecError([Diagnostic(location, format_path(field_path), message)])
        return self._fail(node, self.stack[-1][0], f"the document has more than {MAX_VALUES} values")

    def build(
        self, node: yaml.Node, path: FieldPath, key_mark: tuple[int, int] | None = None, *, record: bool = True
    ) -> Any:
        self.count += 1
        aliased = id(node) in self.visited
        self.visited.add(id(node))
        self.stack.append((path, aliased))
        try:
            if self.count > MAX_VALUES:
                raise self._bomb(node)
            if len(path) > MAX_DEPTH:
                raise self._fail(node, path, f"nested deeper than {MAX_DEPTH} levels")
            is_collection = isinstance(node, (yaml.MappingNode, yaml.SequenceNode))
            if record:
                self.values.setdefault(path, key_mark if key_mark and is_collection else _mark(node))
            if isinstance(node, yaml.ScalarNode):
                return self._scalar(node, path)
            if isinstance(node, yaml.SequenceNode):
                self._check_tag(node, path, _PLAIN_SEQ)
                return [self.build(item, (*path, i), record=record) for i, item in enumerate(node.value)]
            if isinstance(node, yaml.MappingNode):
                self._check_tag(node, path, _PLAIN_MAP)
                result: dict[str, Any] = {}
                for key, (key_node, value_node) in self._pairs(node, path).items():
                    child: FieldPath = (*path, key)
                    if record:
                        self.keys.setdefault(child, _mark(key_node))
                    result[key] = self.build(value_node, child, _mark(key_node), record=record)
                return result
            raise self._fail(node, path, "unsupported YAML node")  # pragma: no cover - composer makes only these
        finally:
            self.stack.pop()

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

    def _pairs(self, node: yaml.MappingNode, path: FieldPath) -> dict[str, tuple[yaml.Node, yaml.Node]]:
        """A mapping's key -> (key node, value node), with ``<<`` merges resolved.

        Explicit keys override merged ones; among merged mappings the first
        listed wins (YAML's merge-key rules).  Resolved once per node, so
        merges that repeat a mapping cost nothing extra (no merge bombs).
        """
        if id(node) in self.resolved:
            return self.resolved[id(node)]
        if id(node) in self.resolving:
            raise self._fail(node, path, "a mapping merges itself through `<<`")
        self.resolving.add(id(node))
        merged: dict[str, tuple[yaml.Node, yaml.Node]] = {}
        explicit: dict[str, tuple[yaml.Node, yaml.Node]] = {}
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE:
                for source in self._merge_sources(value_node, path):
                    for key, pair in self._pairs(source, path).items():
                        merged.setdefault(key, pair)
                continue
            key = self._key(key_node, path)
            if key in explicit:
                self._duplicate(key, key_node, value_node, explicit[key][0], path)
                continue
            explicit[key] = (key_node, value_node)
        self.resolving.discard(id(node))
        self.resolved[id(node)] = pairs = {**merged, **explicit}
        return pairs

    def _merge_sources(self, value: yaml.Node, path: FieldPath) -> list[yaml.MappingNode]:
        if isinstance(value, yaml.MappingNode):
            return [value]
        if isinstance(value, yaml.SequenceNode) and all(isinstance(item, yaml.MappingNode) for item in value.value):
            return list(value.value)
        raise self._fail(value, path, "a merge key `<<` takes a mapping or a list of mappings")

    def _duplicate(
        self, key: str, key_node: yaml.Node, value_node: yaml.Node, first: yaml.Node, path: FieldPath
    ) -> None:
        child: FieldPath = (*path, key)
        message = f"duplicate key {key!r} (first given on line {_mark(first)[0]})"
        self.problems.append(Diagnostic(Location(self.file, *_mark(key_node)), format_path(child), message))
        self.shadowed.setdefault(child, self.build(value_node, child, record=False))

    def _key(self, key_node: yaml.Node, path: FieldPath) -> str:
        """A mapping key as text: every key of a spec is a name or a field."""
        if not isinstance(key_node, yaml.ScalarNode):
            raise self._fail(key_node, path, "mapping keys must be plain names")
        key = self._scalar(key_node, path)
        if isinstance(key, str):
            return key
        # A number is just an invalid name (later checks say so); a boolean or
        # null key is YAML 1.1 reading `on`, `no`, `null` as values: quoting fixes it.
        if key is None or isinstance(key, bool):
            kind = "null" if key is None else "a boolean"
            self.problems.append(
                Diagnostic(
                    Location(self.file, *_mark(key_node)),
                    format_path((*path, key_node.value)),
                    f"YAML reads the key {key_node.value} as {kind}, not a name; quote it: '{key_node.value}'",
                )
            )
        return str(key_node.value)
