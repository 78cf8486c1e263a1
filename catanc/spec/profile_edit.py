"""Rewriting values of a spec's YAML text in place, keeping everything else byte for byte.

``catanc profile --write`` changes a few numbers of a spec someone wrote by hand: its
comments, key order, flow or block style and spacing must stay.  So the text is edited
where the :class:`~catanc.spec.source.SourceMap` says each value starts, never re-dumped:

- a **scalar** (a number such as ``25`` or ``0.8``) is replaced by the new text;
- a **whole value** (:attr:`Edit.whole`: ``compute_ms`` from a number to modes or back)
  is replaced where it is a number or a flow collection (``{modes: [...]}``); a block-style
  collection spans lines whose layout is the author's, and is refused.

Anything else at a value's place (a quoted string, an alias that other fields share, two
edits of one span) is refused with a compiler-style error, and nothing is changed.  A comment
after an edited value on its line stays in its column where the spaces before it allow.

:func:`add_entries` adds keys to a mapping (``hops_ms`` gains a measured edge): inside a flow
mapping before its ``}``, in a block mapping on lines after its last key at the same indent, or,
for a top-level mapping the spec lacks, as a block at the end of the file.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass

from catanc.errors import Diagnostic, FieldPath, Location, SpecError, format_path
from catanc.spec.source import SourceMap

NUMBER = re.compile(r"[-+]?(?:\d[\d_]*)?(?:\.\d*)?(?:[eE][-+]?\d+)?")
"""A plain YAML number, as the specs write them (``25``, ``0.8``, ``1.5e3``)."""
PLAIN_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|'[^'\n]*'|\"[^\"\n]*\"")
OPENERS = {"{": "}", "[": "]"}
COMMENT_GAP = re.compile(r"( +)#")
"""The spaces before a line's comment (a value's edit keeps the comment in its column)."""


@dataclass(frozen=True)
class Edit:
    """Replace the value at ``path`` by the YAML text ``text``."""

    path: FieldPath
    text: str
    whole: bool = False  # the value may be a flow collection (replaced whole), not only a number


def apply_edits(text: str, source: SourceMap, edits: Sequence[Edit]) -> str:
    """``text`` with every edit applied; :class:`SpecError` (every refusal, at its line) if any cannot be."""
    starts = _line_starts(text)
    spans: list[tuple[int, int, Edit]] = []
    problems: list[Diagnostic] = []
    for edit in edits:
        try:
            start, end = _span(text, starts, source, edit)
        except _Refused as refused:
            problems.append(Diagnostic(refused.location, format_path(edit.path), refused.message))
            continue
        spans.append((start, end, edit))
    spans.sort(key=lambda span: span[0])
    for (_, end, first), (start, _, second) in itertools.pairwise(spans):
        if start < end:
            location = source.locate(second.path)
            message = f"shares its text with {format_path(first.path)} (a YAML alias?): edit it by hand"
            problems.append(Diagnostic(location, format_path(second.path), message))
    if problems:
        raise SpecError(problems)
    for start, end, edit in reversed(spans):
        text = _keep_comment_column(text, end, len(edit.text) - (end - start))
        text = text[:start] + edit.text + text[end:]
    return text


def add_entries(text: str, source: SourceMap, path: FieldPath, entries: Sequence[tuple[str, str]]) -> str:
    """``text`` with ``key: value`` (YAML texts) added to the mapping at ``path``, the rest byte for byte.

    A mapping the spec lacks is written only at the top level (``path`` of one key): a block at the end.
    :class:`SpecError` where the mapping is written in a way this cannot extend (edit it by hand).
    """
    if not entries:
        return text
    if path not in source.keys:
        if len(path) != 1:
            raise SpecError([Diagnostic(source.locate(path), format_path(path), "not written: add it by hand")])
        body = "".join(f"  {key}: {value}\n" for key, value in entries)
        return text + ("" if text.endswith("\n") or not text else "\n") + f"{path[0]}:\n{body}"
    starts = _line_starts(text)
    try:
        start, end = _span(text, starts, source, Edit(path, "", whole=True))
    except _Refused:  # written in block style: new lines after its last key, at its keys' indent
        children = [position for child, position in source.keys.items() if child[:-1] == path and len(child) > 0]
        if not children:
            raise SpecError(
                [Diagnostic(source.locate(path), format_path(path), "an empty block mapping: add the entries by hand")]
            ) from None
        last_line = max(line for line, _ in children)
        indent = " " * (min(column for _, column in children) - 1)
        at = starts[last_line] if last_line < len(starts) else len(text)
        lines = "".join(f"{indent}{key}: {value}\n" for key, value in entries)
        before = text[:at] if text[:at].endswith("\n") or not at else text[:at] + "\n"
        return before + lines + text[at:]
    if text[start] != "{":
        message = "not a mapping written {...} or in block style: add the entries by hand"
        raise SpecError([Diagnostic(source.locate(path), format_path(path), message)])
    inner = text[start + 1 : end - 1]
    added = ", ".join(f"{key}: {value}" for key, value in entries)
    if inner.strip():
        return text[: end - 1].rstrip() + ", " + added + ("}" if inner == inner.rstrip() else " }") + text[end:]
    return text[:start] + "{" + added + "}" + text[end:]


def _keep_comment_column(text: str, end: int, grown: int) -> str:
    """``text`` with the spaces before the comment that ends ``end``'s line widened or narrowed by ``grown``
    (at least one space stays), so that a value growing by ``grown`` characters leaves the comment where it was."""
    line_end = text.find("\n", end)
    line_end = len(text) if line_end < 0 else line_end
    gap = COMMENT_GAP.search(text, end, line_end)
    if gap is None or grown == 0:
        return text
    width = max(1, len(gap.group(1)) - grown)
    return text[: gap.start(1)] + " " * width + text[gap.end(1) :]


class _Refused(Exception):  # noqa: N818 - internal: becomes a Diagnostic
    def __init__(self, location: Location, message: str) -> None:
        super().__init__(message)
        self.location = location
        self.message = message


def _line_starts(text: str) -> list[int]:
    starts = [0]
    for index, char in enumerate(text):
        if char == "\n":
            starts.append(index + 1)
    return starts


def _span(text: str, starts: list[int], source: SourceMap, edit: Edit) -> tuple[int, int]:
    """Where the value of ``edit.path`` is written: ``[start, end)`` in ``text``."""
    position = source.values.get(edit.path)
    if position is None:
        raise _Refused(source.locate(edit.path), "not written in the spec: cannot be edited in place")
    line, column = position
    location = Location(source.file, line, column)
    offset = starts[line - 1] + column - 1
    key = source.keys.get(edit.path)
    if key is not None and key == position:  # a collection under a key is located at its key: step past it
        match = PLAIN_KEY.match(text, offset)
        colon = match.end() if match else offset
        while colon < len(text) and text[colon] in " \t":
            colon += 1
        if colon >= len(text) or text[colon] != ":":
            raise _Refused(location, "cannot find this key's value: edit it by hand")
        offset = colon + 1
        while offset < len(text) and text[offset] in " \t":
            offset += 1
    char = text[offset : offset + 1]
    if char in OPENERS:
        if not edit.whole:
            raise _Refused(location, "a collection where a number was expected: edit it by hand")
        return offset, _closing(text, offset, location)
    number = NUMBER.match(text, offset)
    if number is None or not number.group() or not _ends_plain(text, number.end()):
        if char in ("", "\n", "\r", "#"):
            why = "written in block style over several lines; catanc rewrites numbers and {...} values only"
        else:
            why = "not a plain number"
        raise _Refused(location, f"{why}: edit it by hand (to {edit.text})")
    return offset, number.end()


def _ends_plain(text: str, end: int) -> bool:
    """Whether a plain scalar may end at ``end`` (what follows is a separator, not more of the scalar)."""
    return end >= len(text) or text[end] in " \t\r\n,]}#"


def _closing(text: str, offset: int, location: Location) -> int:
    """The offset just after the bracket that closes the one at ``offset`` (quoted text skipped)."""
    depth = 0
    index = offset
    while index < len(text):
        char = text[index]
        if char in "'\"":
            close = text.find(char, index + 1)
            if close < 0:
                break
            index = close
        elif char in OPENERS:
            depth += 1
        elif char in "}]":
            depth -= 1
            if depth == 0:
                return index + 1
        elif char == "#" and text[index - 1] in " \t\n":
            newline = text.find("\n", index)
            index = len(text) if newline < 0 else newline
            continue
        index += 1
    raise _Refused(location, "this value's brackets do not close: edit it by hand")
