"""Wording shared by every report and message: counts with the right plural."""

from __future__ import annotations


def plural(count: int, word: str, many: str | None = None) -> str:
    """``1 subchain``, ``3 subchains``, ``0 chains`` (``many`` where adding an s is wrong)."""
    return f"{count} {word if count == 1 else many or word + 's'}"
