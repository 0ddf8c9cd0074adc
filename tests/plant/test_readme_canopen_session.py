"""The stock ``canopen`` master session of docs/canopen.md, run verbatim against
the plant node over udp_multicast (in the loopback-only namespace, on a test port)."""

from __future__ import annotations

import os
import re
import threading
import time
from pathlib import Path

import can
import numpy as np
import numpy.typing as npt
import pytest

from plant_emulator.canopen_node import (
    CanopenNode,
    NodeConfig,
    node_can_filters,
    run_node,
)
from protocol.can_map import ADC12, DAC12, NmtState

ROOT = Path(__file__).resolve().parents[2]
VOLTS = (1.0, -2.5, 9.9, -10.0)


def documented_session() -> str:
    text = (ROOT / "docs" / "canopen.md").read_text()
    section = text.split("## Driving the node with a stock CANopen master", 1)[1]
    match = re.search(r"```python\n(.*?)```", section, re.DOTALL)
    assert match, "the canopen session block of docs/canopen.md is missing"
    return match.group(1)


class App:
    def __init__(self) -> None:
        self.outputs: list[npt.NDArray[np.float64]] = []
        self.watchdog: list[bool] = []

    def on_sync(self, counter: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        return ADC12.quantize(VOLTS).counts, np.zeros(4, dtype=bool)

    def on_outputs(self, volts: npt.NDArray[np.float64]) -> None:
        self.outputs.append(np.array(volts))

    def on_watchdog(self, tripped: bool) -> None:
        self.watchdog.append(tripped)


@pytest.mark.timeout(60)
def test_the_readme_canopen_session_runs_against_the_node(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("msgpack", reason="udp_multicast needs msgpack")
    port = 47201 + os.getpid() % 10000 // 2 * 2
    try:
        bus = can.Bus(interface="udp_multicast", channel="239.74.163.2", port=port, can_filters=node_can_filters(1))
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    app = App()
    node = CanopenNode(app, NodeConfig())  # the plant's defaults: 0x1019 = 240, watchdog on
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(bus, node, stop), daemon=True)
    thread.start()
    monkeypatch.setenv("RALF_CAN_PORT", str(port))
    monkeypatch.chdir(ROOT)
    try:
        exec(compile(documented_session(), "docs/canopen.md", "exec"), {"__name__": "documented_session"})  # noqa: S102 - the documented block, verbatim
        deadline = time.monotonic() + 2.0  # the session's last NMT frame may still be on its way
        while node.state is not NmtState.PRE_OPERATIONAL and time.monotonic() < deadline:
            time.sleep(0.002)
    finally:
        stop.set()
        thread.join(2.0)
        bus.shutdown()
    name, inputs = capsys.readouterr().out.strip().splitlines()[-2:]
    assert name == NodeConfig().device_name
    np.testing.assert_allclose(eval(inputs), VOLTS, atol=ADC12.lsb_v)  # our own printed list
    c = node.counters
    assert c.tx["tpdo1"] >= 2 and c.malformed_total == 0 and c.sync_conflicts == 0
    assert c.rx["sync"] == c.sync_received  # every counter-less SYNC accepted
    assert any(abs(v[0] - 1.5) <= DAC12.lsb_v for v in app.outputs)  # the valve got its 1.5 V
    assert node.state is NmtState.PRE_OPERATIONAL and node.outputs_v.tolist() == [0.0, 0.0]
