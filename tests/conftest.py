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


LEFT_THREAD_GRACE_S = 10.0
"""How long the session waits, at its end, for threads a test left running to end by themselves."""


def pytest_unconfigure(config: pytest.Config) -> None:
    """A thread that is not a daemon and still runs when the session ends would keep the
    interpreter from exiting (a zenoh session or subscriber left open, a service not
    closed): the run would stall instead of ending. Name them and end with a failure."""
    import os
    import sys
    import threading
    import time

    deadline = time.monotonic() + LEFT_THREAD_GRACE_S
    left = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    for t in left:
        t.join(timeout=max(0.0, deadline - time.monotonic()))
    left = [t for t in left if t.is_alive()]
    if left:
        names = ", ".join(sorted({t.name for t in left}))
        print(f"\nthe tests left {len(left)} non-daemon thread(s) running ({names}): a session, bus or service was not closed", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(3)
