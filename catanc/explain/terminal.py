"""The explanation for a terminal: each block as rich renderables (``catanc explain``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import assert_never

from rich.console import Console, ConsoleOptions, RenderableType, RenderResult
from rich.measure import Measurement
from rich.padding import Padding
from rich.table import Table
from rich.text import Text

from catanc.explain.analysis import Explanation
from catanc.explain.blocks import Block, Bullets, Heading, Paragraph, Preformatted, TableBlock, report_blocks


def _rich_parts(block: Block) -> list[RenderableType]:
    """One block for a terminal: a blank line before each section, tables boxed, notes indented."""
    if isinstance(block, Heading):
        return [Text(""), Text(block.text, style="bold")]
    if isinstance(block, Paragraph):
        return [Text(block.text, style="bold" if block.strong else "")]
    if isinstance(block, Preformatted):
        return [Text("\n".join(f"  {line}" for line in block.text.splitlines()))]
    if isinstance(block, Bullets):  # a hanging indent: a wrapped item stays clear of the dashes
        items = Table.grid(padding=(0, 1, 0, 0))
        items.add_column(no_wrap=True)
        items.add_column()
        for item in block.items:
            items.add_row("-", Text(item))
        return [items]
    if isinstance(block, TableBlock):
        table = FittedTable(block)
        return [table] if block.footer is None else [table, Padding(Text(block.footer), (0, 0, 0, 2))]
    assert_never(block)


UNBOUNDED_WIDTH = 10_000
"""Room enough to measure the narrowest a table can be without cutting a word."""


@dataclass(frozen=True)
class FittedTable:
    """A table that fits the width it is given: one-line headers, or each header word on its own line if
    one-line headers would cut words short or if stacking them takes fewer lines (the text wraps less).

    Number columns are never wrapped or cut; text columns (names, chains, notes) wrap to fit.
    """

    block: TableBlock

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        flat, stacked = self._table(stacked=False), self._table(stacked=True)
        narrowest = Measurement.get(console, options.update_width(UNBOUNDED_WIDTH), flat).minimum
        if narrowest > options.max_width:  # one-line headers would cut words short
            yield stacked
        elif len(console.render_lines(stacked, options)) < len(console.render_lines(flat, options)):
            yield stacked  # taller headers, but the text wraps less: fewer lines in all
        else:
            yield flat

    def _table(self, *, stacked: bool) -> Table:
        block = self.block
        table = Table(title=block.title, title_justify="left")
        for index, column in enumerate(block.columns):
            if column.align == "right":
                header = column.header.replace(" ", "\n") if stacked else column.header
                widest = max((len(row[index]) for row in block.rows), default=0)
                table.add_column(header, justify="right", no_wrap=True, min_width=widest)
            else:  # text wraps between words, never inside one
                longest = max(
                    (
                        len(word)
                        for text in (column.header, *(row[index] for row in block.rows))
                        for word in text.split()
                    ),
                    default=0,
                )
                table.add_column(column.header, justify="left", min_width=longest)
        for row in block.rows:
            table.add_row(*row)
        return table


def render(explanation: Explanation) -> list[RenderableType]:
    """The explanation as rich renderables, in reading order."""
    return [part for block in report_blocks(explanation) for part in _rich_parts(block)]
