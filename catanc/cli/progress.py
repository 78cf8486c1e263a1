"""Progress bars for commands that can take more than a couple of seconds, on stderr, only on a terminal.

A command wraps its long loop in :func:`progress` and says how far it got::

    from catanc.cli.progress import progress

    with progress("simulate", total=len(policies), quiet=quiet) as bar:
        for policy in policies:
            bar.start(policy)          # the previous item is done; this one runs now
            simulate(setup, policy)

    with progress("calibrate", total=duration_s, unit="s", quiet=quiet) as bar:
        while (elapsed := clock() - began) < duration_s:
            bar.update(elapsed, "measuring GL")  # how far, in the total's unit

:func:`tracked` does the first pattern for an iterable.

The bar is drawn only when stdout and stderr are both terminals and the
command was not given ``--quiet``; otherwise every method does nothing, so
piped output, ``--json`` and logs are byte for byte what they would be
without it.  It is drawn on stderr (never into stdout's tables or JSON) and
cleared when the loop ends.  rich decides what a terminal is, so
``TTY_COMPATIBLE=1`` or ``FORCE_COLOR=1`` in the environment force it on (as
the tests do) and ``TTY_COMPATIBLE=0`` forces it off.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sized
from contextlib import contextmanager
from typing import TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

T = TypeVar("T")


def shown(quiet: bool = False) -> bool:
    """Whether a progress bar would be drawn: not ``--quiet``, stdout and stderr both terminals."""
    return not quiet and Console().is_terminal and Console(stderr=True).is_terminal


class Bar:
    """How far a long loop got; a no-op when the bar is not shown."""

    def __init__(self, bar: Progress | None, task: TaskID | None, description: str, *, redraw: bool = False) -> None:
        self._bar = bar
        self._task = task
        self._description = description
        self._started = False
        self._redraw = redraw

    @property
    def shown(self) -> bool:
        return self._bar is not None

    def start(self, item: str) -> None:
        """Item by item: the item before (if any) is done, ``item`` runs now."""
        if self._bar is None or self._task is None:
            return
        self._bar.update(self._task, advance=1 if self._started else 0, description=self._label(item))
        self._bar.refresh()  # items are few and long: show each as it starts, not at the next tick
        self._started = True

    def update(self, completed: float, note: str | None = None) -> None:
        """By amount: ``completed`` of the total so far (seconds, runs, ...), with an optional note."""
        if self._bar is None or self._task is None:
            return
        self._bar.update(self._task, completed=completed, description=self._label(note))
        if self._redraw:
            self._bar.refresh()

    def _label(self, note: str | None) -> str:
        return f"{self._description}: {note}" if note else self._description

    def _finish(self) -> None:
        if self._bar is not None and self._task is not None and self._started:
            self._bar.update(self._task, advance=1)


@contextmanager
def progress(
    description: str, total: float | None, *, unit: str = "", quiet: bool = False, drawing_thread: bool = True
) -> Iterator[Bar]:
    """A bar for one long loop (``total`` steps, or None when unknown), cleared when the loop ends.

    ``drawing_thread=False``: no thread of rich's redraws the bar ten times a second; each
    :meth:`Bar.update` draws it (for a real-time loop that must not wait on another thread for the
    interpreter lock).
    """
    if not shown(quiet):
        yield Bar(None, None, description)
        return
    count = TextColumn(f"{{task.completed:.0f}}/{{task.total:.0f}} {unit}") if unit else MofNCompleteColumn()
    bar = Progress(
        TextColumn("{task.description}", markup=False),
        BarColumn(),
        count,
        TimeElapsedColumn(),
        console=Console(stderr=True),
        transient=True,
        auto_refresh=drawing_thread,
        redirect_stdout=False,  # stdout is the command's output, byte for byte: never routed through the bar
        redirect_stderr=False,
    )
    with bar:
        handle = Bar(bar, bar.add_task(description, total=total), description, redraw=not drawing_thread)
        yield handle
        handle._finish()


def tracked(
    items: Iterable[T], description: str, *, label: Callable[[T], str] = str, quiet: bool = False
) -> Iterator[T]:
    """Each of ``items``, with a bar naming the one running (sized iterables show a total)."""
    total = len(items) if isinstance(items, Sized) else None
    with progress(description, total, quiet=quiet) as bar:
        for item in items:
            bar.start(label(item))
            yield item
