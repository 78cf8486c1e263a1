"""The explanation as GitHub Markdown, for a committed ``PLAN.md``: deterministic, whatever the terminal."""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import assert_never

from catanc.explain.analysis import Explanation
from catanc.explain.blocks import Block, Bullets, Heading, Paragraph, Preformatted, TableBlock, report_blocks

_MARKDOWN_INLINE = re.compile(
    r"[\\`*]"  # escapes, code spans, emphasis
    r"|(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])"  # emphasis (an underscore inside a word is not)
    r"|\](?=[(\[:])"  # links: inline, reference, definition
    r"|<(?=[A-Za-z/!?])|&(?=#?\w+;)"  # HTML tags, entities
)
_MARKDOWN_BLOCK_START = re.compile(r"^(?:[#>+-]|\d+[.)])")


def _markdown_inline(text: str) -> str:
    """``text`` as literal Markdown on one line, for a heading or a table cell.

    Backslash-escapes only what could start markup, so that the file reads
    well raw: ``face_tracking``, ``objective[2]`` and ``f <= 1`` stay as
    they are.
    """
    return _MARKDOWN_INLINE.sub(lambda match: "\\" + match.group(0), " ".join(text.splitlines()).strip())


def _markdown_text(text: str) -> str:
    """``text`` as a literal paragraph or list item: also not a heading, quote, list or rule."""
    return _MARKDOWN_BLOCK_START.sub(
        lambda match: match.group(0)[:-1] + "\\" + match.group(0)[-1], _markdown_inline(text)
    )


def _markdown_cell(text: str) -> str:
    return _markdown_inline(text).replace("|", "\\|")


def _markdown_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _markdown_lines(block: Block) -> list[str]:
    """One block as GitHub Markdown lines (no blank line before or after it)."""
    if isinstance(block, Heading):
        return [f"## {_markdown_inline(block.text)}"]
    if isinstance(block, Paragraph):
        text = _markdown_text(block.text)
        return [f"**{text}**" if block.strong and text else text]
    if isinstance(block, Preformatted):
        lines = [line.rstrip() for line in block.text.splitlines()]
        ticks = max((len(run) for run in re.findall(r"`+", block.text)), default=0)
        fence = "`" * max(3, ticks + 1)
        return [fence, *lines, fence]
    if isinstance(block, Bullets):
        return [f"- {_markdown_text(item)}" for item in block.items]
    if isinstance(block, TableBlock):
        lines = [] if block.title is None else [f"**{_markdown_inline(block.title)}**", ""]
        lines.append(_markdown_row([_markdown_cell(column.header) for column in block.columns]))
        lines.append(_markdown_row(["---:" if column.align == "right" else "---" for column in block.columns]))
        lines += [_markdown_row([_markdown_cell(cell) for cell in row]) for row in block.rows]
        if block.footer is not None:
            lines += ["", _markdown_text(block.footer)]
        return lines
    assert_never(block)


def blocks_markdown(blocks: Sequence[Block]) -> str:
    """Blocks as one Markdown document: a blank line between blocks, ``\\n`` endings, one final newline."""
    chunks = ["\n".join(lines) for lines in map(_markdown_lines, blocks) if any(lines)]
    return "\n\n".join(chunks) + "\n"


def render_markdown(explanation: Explanation) -> str:
    """The same report as :func:`render`, as GitHub Markdown (for a committed ``PLAN.md``); no file header."""
    return blocks_markdown(report_blocks(explanation))
