"""The controller's XCP link without a rig: off by default, and a port in use
or an unwritable A2L path refused in one line (the service then exits 2)."""

from __future__ import annotations

import socket
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from controller.config import build_trajectory, law_config
from controller.loop import ControlLaw
from controller.params import ParamPath
from controller.service import RECORD_COLUMNS
from controller.timing_counters import TimingCounters
from controller.xcp_link import XcpLink, make_xcp
from protocol.errors import ConfigError
from protocol.settings import ControllerSettings
from service_kit.runtime import LatencyTracker
from tests.xcp.rig_client import free_port


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def fake_service(**settings: Any) -> Any:
    s = ControllerSettings(**settings)
    law = ControlLaw(law_config(s), build_trajectory(s))
    return SimpleNamespace(
        settings=s,
        law=law,
        params=ParamPath(law, s.sample_period_s, []),
        tet=LatencyTracker(16),
        link=SimpleNamespace(counters=SimpleNamespace(deadline_misses=0)),
        timing=TimingCounters(),
        dsp=SimpleNamespace(config_changes=[], latest_interrupt=None),
        tick=0,
    )


def test_off_by_default() -> None:
    assert make_xcp(fake_service(), list(RECORD_COLUMNS)) is None


def test_a_port_in_use_is_one_line(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        with pytest.raises(ConfigError, match=rf"^xcp_udp_port {port} on 127\.0\.0\.1: Address already in use$"):
            XcpLink(fake_service(xcp_udp_port=port, xcp_a2l=str(tmp_path / "x.a2l")), list(RECORD_COLUMNS))
    assert not (tmp_path / "x.a2l").exists()


def test_an_unwritable_a2l_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "missing" / "x.a2l"
    with pytest.raises(ConfigError, match=rf"^xcp_a2l {path}: No such file or directory$"):
        XcpLink(fake_service(xcp_udp_port=free_udp_port(), xcp_a2l=str(path)), list(RECORD_COLUMNS))
