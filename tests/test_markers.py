"""The rules of tests/conftest.py that give the ``slow`` marker name real modules: a renamed or moved module
would otherwise fall into the fast tier unnoticed."""

from __future__ import annotations

from tests.conftest import SLOW_MODULES, TESTS


def test_every_slow_module_exists() -> None:
    missing = sorted(module for module in SLOW_MODULES if not (TESTS / module).is_file())
    assert not missing, f"SLOW_MODULES names modules that are not in tests/: {missing}"
