"""Suite-wide test configuration.

Markers (registered in pyproject.toml):

- ``rig``: the test starts services (processes, zenoh sessions, a CAN bus
  between processes); every test under ``tests/rig/`` carries it.
- ``slow``: the test runs a whole rig or an experiment (seconds each).

CI runs everything; ``pytest -m "not rig"`` is the quick inner loop.
"""

from __future__ import annotations

from pathlib import Path

import pytest

_RIG_DIR = Path(__file__).parent / "rig"
_SLOW_MODULES = {
    "test_deadlines",
    "test_end_to_end",
    "test_experiments_offline",
    "test_experiments_onrig",
    "test_lockstep_determinism",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if _RIG_DIR in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.rig)
        if Path(str(item.fspath)).stem in _SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
