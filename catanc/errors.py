"""Errors, diagnostics and exit codes.

Every error catanc expects is a :class:`CatancError`; the CLI catches only
that root and maps it to an :class:`ExitCode`.  Anything else is a bug.
"""

from __future__ import annotations

import difflib
from collections.abc import Hashable, Iterable
from dataclasses import dataclass
from enum import IntEnum

FieldPath = tuple[Hashable, ...]
"""Where a value sits in a spec: ``("subchains", "local", 1)``."""


def format_path(path: FieldPath) -> str:
    """``("subchains", "local", 1)`` -> ``subchains.local[1]``."""
    text = ""
    for part in path:
        if isinstance(part, int) and not isinstance(part, bool):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


class ExitCode(IntEnum):
    """Process exit codes (documented in docs/reference/spec.md)."""

    OK = 0
    DRIFT = 1  # `compile --check` found stale output; `profile --check` a spec off its measurements
    BAD_INPUT = 2  # bad spec or bad command-line usage
    INFEASIBLE = 3  # no plan satisfies the spec's hard requirements
    NO_PRIVILEGE = 4  # SCHED_FIFO / affinity not permitted
    OUTPUT = 5  # output folder cannot be written or read
    OUTPUT_BLOCKED = 6  # a file, link or someone else's files where the output folder goes
    NOT_COMPILED = 7  # `compile --check` found no output folder
    MACHINE = 8  # `catanc doctor`: this machine lacks something the plan needs
    SAFETY = 9  # `catanc run` stopped because its safety net (the watchdog) died; every thread was put back
    INTERNAL = 70  # a bug in catanc (EX_SOFTWARE)


def close_matches(word: str, choices: Iterable[str]) -> list[str]:
    """The choices closest to a misspelt ``word`` (ties kept, in the given order)."""
    options = list(choices)
    scores = [difflib.SequenceMatcher(None, word, option).ratio() for option in options]
    best = max(scores, default=0.0)
    close = [option for option, score in zip(options, scores, strict=True) if score == best and best >= 0.5]
    same_start = [option for option in close if option[:1] == word[:1]]
    return same_start or close


def did_you_mean(word: str, choices: Iterable[str], *, listing: bool = False) -> str:
    """`` (did you mean 'LM'?)``, optionally listing the choices; empty if nothing fits."""
    options = list(choices)
    close = close_matches(word, options)
    parts = []
    if close:
        parts.append("did you mean " + " or ".join(repr(option) for option in close[:3]) + "?")
    if listing and options:
        parts.append("expected one of: " + ", ".join(options))
    return f" ({'; '.join(parts)})" if parts else ""


@dataclass(frozen=True, order=True)
class Location:
    """A place in a spec file (1-based line and column)."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


@dataclass(frozen=True)
class Diagnostic:
    """One problem (or warning) found in a spec, compiler style."""

    location: Location | None
    field: str  # dotted path, e.g. ``subchains.local[1]``; empty for the whole file
    message: str

    def __str__(self) -> str:
        where = f"{self.location}: " if self.location else ""
        what = f"{self.field}: " if self.field else ""
        return f"{where}{what}{self.message}"

    def sort_key(self) -> tuple[str, int, int, str]:
        if self.location is None:
            return ("", 0, 0, self.field)
        return (self.location.file, self.location.line, self.location.column, self.field)


class CatancError(Exception):
    """Root of every error catanc reports to a user."""

    exit_code = ExitCode.INTERNAL


class SpecError(CatancError):
    """A spec is malformed or inconsistent; carries one diagnostic per problem."""

    exit_code = ExitCode.BAD_INPUT

    def __init__(self, diagnostics: list[Diagnostic]) -> None:
        self.diagnostics = sorted(diagnostics, key=Diagnostic.sort_key)
        super().__init__("\n".join(str(d) for d in self.diagnostics))


class UsageError(CatancError):
    """The command line asks for something that cannot be done."""

    exit_code = ExitCode.BAD_INPUT


class MissingExtraError(CatancError):
    """A command needs an optional dependency that is not installed; the message names the extra."""

    exit_code = ExitCode.BAD_INPUT


class InfeasibleError(CatancError):
    """No plan satisfies the spec's hard requirements."""

    exit_code = ExitCode.INFEASIBLE


class PrivilegeError(CatancError):
    """The process may not use SCHED_FIFO or set affinities."""

    exit_code = ExitCode.NO_PRIVILEGE


class SchedError(CatancError):
    """A scheduling call failed for a reason other than privileges or a vanished thread."""


class LoopError(CatancError):
    """The compiled loop is not built here, or its object file does not link into this process."""

    exit_code = ExitCode.MACHINE


class OutputError(CatancError):
    """An output folder cannot be written or read."""

    exit_code = ExitCode.OUTPUT


class OutputBlockedError(CatancError):
    """Something that is not catanc's output sits where the output folder goes."""

    exit_code = ExitCode.OUTPUT_BLOCKED


class NotCompiledError(CatancError):
    """``compile --check`` found no output folder to compare with."""

    exit_code = ExitCode.NOT_COMPILED
