"""A one-process rig whose controller refuses its settings leaves nothing open:
no zenoh session or subscriber (their callback threads are not daemons and
would keep the process from ending), no CAN bus, no DSP service."""

from __future__ import annotations

import threading

import pytest

from protocol.errors import ConfigError
from workbench.composition import run_in_process

REFUSED = '{"can_errors": [{"identifier": "all", "count": 3}]}'  # needs a wire; the virtual bus has none


def test_a_refused_controller_leaves_no_thread_behind() -> None:
    before = {t.ident for t in threading.enumerate()}
    with pytest.raises(ConfigError, match="can_errors need"):
        run_in_process(controller={"duration_s": 0.2, "fault_scenario": REFUSED})
    left = [t.name for t in threading.enumerate() if t.ident not in before and t.is_alive()]
    assert left == []
