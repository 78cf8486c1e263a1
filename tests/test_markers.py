"""The rules of tests/conftest.py that give the ``slow`` and ``serial`` markers name real modules: a renamed or
moved module would otherwise fall into the fast tier, or the parallel pass, unnoticed."""

from __future__ import annotations

import pytest

from tests.conftest import SLOW_MODULES, TESTS, TIMED_MODULES


@pytest.mark.parametrize(("name", "modules"), [("SLOW_MODULES", SLOW_MODULES), ("TIMED_MODULES", TIMED_MODULES)])
def test_every_module_a_marker_rule_names_exists(name: str, modules: frozenset[str]) -> None:
    missing = sorted(module for module in modules if not (TESTS / module).is_file())
    assert not missing, f"{name} names modules that are not in tests/: {missing}"
