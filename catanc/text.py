"""Wording shared by every report and message: counts with the right plural, rates."""

from __future__ import annotations


def plural(count: int, word: str, many: str | None = None) -> str:
    """``1 subchain``, ``3 subchains``, ``0 chains`` (``many`` where adding an s is wrong)."""
    return f"{count} {word if count == 1 else many or word + 's'}"


def hz(period_ms: float) -> str:
    """The rate of a period in milliseconds: ``25 ms`` -> ``40 Hz`` (4 significant digits)."""
    return f"{1000.0 / period_ms:.4g} Hz"
