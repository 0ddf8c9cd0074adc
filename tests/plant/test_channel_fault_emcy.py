"""What the node itself reports of a channel fault, as a stock CANopen master sees it.

A real analog module sees only range violations: a fault that drives an A/D input to
its clip (a short to the sensors' supply, an open input floating to a rail) gives EMCY
INPUT_SATURATED (0x5010) with the channel mask, once, when it appears, and the error
reset EMCY (code 0x0000) when it goes away (CiA 301, the EMCY object); a short to
ground or any value inside the range gives nothing. The master is the ``canopen``
package (its ``Network`` and the node's ``EmcyConsumer``, ``node.emcy``) on python-can's
``virtual`` bus, with the shipped EDS; the node is the plant's, its real arm behind it.
"""

from __future__ import annotations

import json
import queue
import threading
import time
import uuid
from collections.abc import Callable

import can
import canopen

from plant_emulator.node import CanopenNode, run_node
from plant_emulator.service import PlantApplication, node_config
from protocol.can_map import EmcyCode
from protocol.settings import PlantSettings, load_settings
from tests.plant.support import EDS

FAULTS = [
    {"channel": "AI1", "kind": "short_ground"},  # the whole run: inside the range, unseen by the node
    {"channel": "AI3", "kind": "short_supply", "start_s": 0.02, "end_s": 0.05},  # samples 4..9 (5 ms each)
    {"channel": "AI2", "kind": "open", "value_v": -15.0, "start_s": 0.07, "end_s": 0.09},  # floats to the negative rail: samples 14..17
    {"channel": "AI4", "kind": "stuck", "start_s": 0.0},  # inside the range: unseen
]
SYNCS = 22
TOP, BOTTOM = 0x7FF0, -0x8000
"""The 12-bit converter's end codes, left-justified in TPDO1's 16-bit words."""


def _wait(pred: Callable[[], bool], timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return pred()


def test_a_fault_at_the_clip_gives_input_saturated_and_its_reset() -> None:
    settings = load_settings(PlantSettings, {"scenario": json.dumps({"channel_faults": FAULTS}), "clock": "lockstep"})
    app = PlantApplication(settings)
    node = CanopenNode(app, node_config(settings))
    app.set_fault = node.set_fault
    channel = f"ralf-fault-emcy-{uuid.uuid4().hex}"
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel, receive_own_messages=False)
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(node_bus, node, stop), name="node", daemon=True)
    words: list[list[int]] = []
    got: queue.Queue[None] = queue.Queue()
    emcys: list[tuple[int, int, int, bytes]] = []  # (samples received before it, code, register, vendor bytes)
    try:
        remote = network.add_node(1, str(EDS))
        thread.start()
        assert _wait(lambda: remote.nmt.state == "PRE-OPERATIONAL")
        remote.tpdo.read()
        remote.emcy.add_callback(lambda e: emcys.append((len(words), e.code, e.register, bytes(e.data))))

        def on_tpdo(message: canopen.pdo.base.PdoMap) -> None:
            words.append([int(v.raw) for v in message])
            got.put(None)

        remote.tpdo[1].add_callback(on_tpdo)
        remote.nmt.state = "OPERATIONAL"
        assert _wait(lambda: remote.nmt.state == "OPERATIONAL")
        register_during = history_during = None
        for k in range(1, SYNCS + 1):
            network.sync.transmit()  # canopen's SYNC without counter: one sample, 5 ms of the lockstep plant
            got.get(timeout=10.0)
            if k == 6:  # AI3 at the supply: the error is active in the node's dictionary
                register_during = remote.sdo["Error register"].raw
                history_during = remote.sdo[0x1003][1].raw
        assert _wait(lambda: len(emcys) >= 4)
        time.sleep(0.05)  # nothing more comes
    finally:
        stop.set()
        thread.join(10.0)
        network.disconnect()
        node_bus.shutdown()
    assert not thread.is_alive()

    saturated = int(EmcyCode.INPUT_SATURATED)
    assert emcys == [
        (4, saturated, 0x01, bytes([0b0100, 0, 0, 0, 0])),  # with the 4th sample (0.02 s): AI3
        (10, 0x0000, 0x00, saturated.to_bytes(2, "little") + bytes(3)),  # the 10th (0.05 s), the first after the fault: reset
        (14, saturated, 0x01, bytes([0b0010, 0, 0, 0, 0])),  # AI2 open at the negative rail
        (18, 0x0000, 0x00, saturated.to_bytes(2, "little") + bytes(3)),
    ]
    assert remote.emcy.active == []  # the master's consumer cleared it on the reset
    assert register_during == 0x01 and history_during == saturated | (0b0100 << 16)
    assert [w[2] for w in words[3:9]] == [TOP] * 6 and words[2][2] != TOP and words[9][2] != TOP
    assert [w[1] for w in words[13:17]] == [BOTTOM] * 4
    assert all(w[0] == 0 for w in words)  # AI1 shorted to ground reads 0 V all along: no EMCY for it
    assert len({w[3] for w in words}) == 1  # AI4 stuck: one value all along, no EMCY for it
