"""Local runs stay local and apart: one `up` per rig id per host, and CAN
multicast frames of a local run never leave the host (TTL 0)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.settings import CommonSettings, load_settings
from service_kit.can_udp import LoopFreeUdpMulticastBus
from service_kit.transport import open_can_bus
from workbench.cli import acquire_rig_lock


def test_second_up_on_the_same_rig_id_refuses(tmp_path: Path) -> None:
    held = acquire_rig_lock("lock-test", str(tmp_path))
    try:
        code = "import sys; from workbench.cli import acquire_rig_lock; acquire_rig_lock('lock-test', sys.argv[1])"
        proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60, check=False)
        assert proc.returncode == 2 and "already running" in proc.stderr and f"pid {os.getpid()}" in proc.stderr
        other = subprocess.run(
            [sys.executable, "-c", code.replace("lock-test", "other-rig"), str(tmp_path)], capture_output=True, text=True, timeout=60, check=False
        )
        assert other.returncode == 0
    finally:
        held.close()
    again = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60, check=False)
    assert again.returncode == 0  # released with the first run


def _ttl(bus: object) -> int:
    if isinstance(bus, LoopFreeUdpMulticastBus):
        return bus.multicast_ttl()
    sock: socket.socket = bus._multicast._socket  # type: ignore[attr-defined]
    return int(sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL))


@pytest.mark.parametrize("own_frame_filter", [True, False], ids=["loop-free-bus", "python-can-bus"])
@pytest.mark.parametrize(("setting", "ttl"), [(None, 0), ("1", 1)])
def test_can_multicast_ttl_keeps_local_runs_on_the_host(setting: str | None, ttl: int, own_frame_filter: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    for name in list(os.environ):
        if name.startswith("RALF_"):
            monkeypatch.delenv(name)
    overrides: dict[str, object] = {"can_port": 43999, "can_udp": f"own_frame_filter={str(own_frame_filter).lower()}"}
    if setting is not None:
        overrides["can_udp"] = f"{overrides['can_udp']},ttl={setting}"
    bus = open_can_bus(load_settings(CommonSettings, overrides))
    assert isinstance(bus, LoopFreeUdpMulticastBus) == own_frame_filter
    try:
        assert _ttl(bus) == ttl
    finally:
        bus.shutdown()
