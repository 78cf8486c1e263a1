"""Loading a spec: a file or text -> its checked :class:`Spec` and its :class:`Problem`, built once.

The three passes (syntax, shape: :mod:`catanc.spec.parse`; meaning:
:func:`catanc.model.build.build_problem`) report every problem they find
together.  The meaning pass builds the planning problem, so a command that
needs both takes them from one :class:`SpecFile` instead of building the
problem again.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from catanc.errors import SpecError
from catanc.model.build import build_problem
from catanc.model.problem import Problem
from catanc.spec.language import Spec
from catanc.spec.parse import parse_shape, read_spec_text


@dataclass(frozen=True)
class SpecFile:
    """A checked spec, its planning problem, and the sha256 of the bytes it was read from."""

    spec: Spec
    problem: Problem
    sha256: str


def read_spec(path: str | Path) -> SpecFile:
    """Read, parse and check a spec file, and build its problem; raise :class:`SpecError` on any problem."""
    text, sha256 = read_spec_text(path)
    spec, problem = check_text(text, str(path))
    return SpecFile(spec, problem, sha256)


def parse_spec_file(text: str, file: str = "<spec>") -> SpecFile:
    """:func:`read_spec` for text in memory (the digest is of its UTF-8 bytes)."""
    spec, problem = check_text(text, file)
    return SpecFile(spec, problem, hashlib.sha256(text.encode()).hexdigest())


def load_spec(path: str | Path) -> Spec:
    """Read, parse and check a spec file; raise :class:`SpecError` on any problem."""
    return read_spec(path).spec


def parse_spec(text: str, file: str = "<spec>") -> Spec:
    """Parse and check spec text; ``file`` is only used in messages."""
    return check_text(text, file)[0]


def check_text(text: str, file: str) -> tuple[Spec, Problem]:
    """All three passes over spec text: the spec and its problem, or one :class:`SpecError` with every problem."""
    spec, problems = parse_shape(text, file)
    try:
        problem = build_problem(spec)
    except SpecError as exc:
        raise SpecError(problems + exc.diagnostics) from None
    if problems:
        raise SpecError(problems)
    return spec, problem
