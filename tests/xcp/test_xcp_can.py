"""XCP on CAN: the controller's slave on a one-process lockstep rig's python-can
``virtual`` bus, measured and calibrated by pyxcp's CAN transport (a master
nobody here wrote): MAX_CTO = MAX_DTO = 8, a FLOAT64 gain written in two
DOWNLOADs, DAQ on the tick event in DTOs of at most 8 bytes."""

from __future__ import annotations

import struct
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from pyxcp.daq_stim import DaqList
from pyxcp.master.errorhandler import SystemExit as XcpError

from controller.service import RECORD_COLUMNS
from controller.xcp_link import XcpLink
from controller.xcp_table import A2L_MODULE, controller_layout, xcp_events
from protocol.errors import ConfigError
from service_kit.xcp.can import CanServer, check_identifiers
from service_kit.xcp.memory import ASAM_TYPES
from service_kit.xcp.slave import Slave, SlaveInfo
from service_kit.xcp.transports import on_can
from tests.xcp.rig_client import BackgroundRig, Collect, can_master, wait_for
from tests.xcp.test_xcp_link import fake_service

LAYOUT = controller_layout()
TS = 0.005
DAQ_NAMES = ("tick", "ai1_word", "ai2_word", "ai3_word", "ai4_word")


def address(name: str) -> int:
    return LAYOUT.by_name[name].address


def read_f64(x: Any, name: str) -> float:
    x.setMta(address(name), 0)
    return float(struct.unpack("<d", x.fetch(8))[0])  # two UPLOADs: 7 bytes, then 1


def refused_code(call: Any) -> int:
    with pytest.raises(XcpError) as info:
        call()
    return int(info.value.error_code)


def test_xcp_on_can(tmp_path: Path) -> None:
    channel = f"ralf-{uuid.uuid4().hex[:8]}"
    a2l = tmp_path / "controller.a2l"
    rig = BackgroundRig({"duration_s": 3600.0, "xcp_can": True, "xcp_a2l": str(a2l)}, common={"can_channel": channel}).start()
    try:
        assert wait_for(a2l.exists, 120), "the controller did not come up"
        text = a2l.read_text()
        assert "/begin XCP_ON_CAN 0x0104 CAN_ID_MASTER 0x7E0 CAN_ID_SLAVE 0x7E1" in text and "XCP_ON_UDP_IP" not in text
        daq = DaqList(
            name="tick",
            event_num=0,
            stim=False,
            enable_timestamps=True,
            measurements=[(n, address(n), 0, ASAM_TYPES[LAYOUT.by_name[n].datatype][1]) for n in DAQ_NAMES],
            priority=0,
            prescaler=1,
        )
        policy = Collect([daq])
        with can_master(channel, 0x7E0, 0x7E1, policy) as x:
            assert (x.slaveProperties.maxCto, x.slaveProperties.maxDto) == (8, 8)
            assert x.identifier(0) == A2L_MODULE
            assert x.identifier(2) == str(a2l)  # longer than a frame: fetched in parts
            assert read_f64(x, "kp1") == 7.5
            # kp1 in two DOWNLOADs: the first six bytes are held, the map unchanged until the last two arrive
            new = struct.pack("<d", 9.25)
            x.setMta(address("kp1"), 0)
            x.download(new[:6])
            assert read_f64(x, "kp1") == 7.5
            x.setMta(address("kp1") + 6, 0)
            x.download(new[6:])
            assert wait_for(lambda: read_f64(x, "kp1") == 9.25, 60)  # in the map from the tick that applies it
            # checked as a whole once complete: a negative gain is refused on its last part
            bad = struct.pack("<d", -1.0)
            x.setMta(address("kp2"), 0)
            x.download(bad[:6])
            assert refused_code(lambda: x.download(bad[6:])) == 0x22  # ERR_OUT_OF_RANGE
            # a first part, then a write elsewhere: the part is dropped (counted), kp2 unchanged
            x.setMta(address("kp2"), 0)
            x.download(struct.pack("<d", 1.0)[:6])
            x.setMta(address("ki1"), 0)
            x.download(struct.pack("<d", 0.5)[:6])
            x.download(struct.pack("<d", 0.5)[6:])
            assert wait_for(lambda: read_f64(x, "ki1") == 0.5, 60)
            assert read_f64(x, "kp2") == 6.25
            # the last bytes of a parameter with nothing held for it: refused, as on Ethernet
            x.setMta(address("ki2") + 6, 0)
            assert refused_code(lambda: x.download(b"\0\0")) == 0x24  # ERR_ACCESS_DENIED
            assert refused_code(lambda: x.shortUpload(7, LAYOUT.end)) == 0x24  # outside the map

            policy.setup()
            policy.start()
            assert wait_for(lambda: len(policy.samples) >= 300, 120), f"{len(policy.samples)} DAQ samples"
            policy.stop()
        run = rig.stop()
    finally:
        rig.stop_event.set()

    counters = run.result.counters
    assert counters["xcp_can_partial_writes_held"] == 4
    assert counters["xcp_can_partial_writes_dropped"] == 1
    assert counters["xcp_can_writes_refused"] == 3
    assert counters["xcp_can_snapshots_dropped"] == 0 and counters["xcp_can_daq_overloads"] == 0
    assert counters["xcp_calibrations_applied"] == 2
    changes = [c.fields for c in run.result.config_changes if c.kind == "xcp"]
    assert changes == [{"kp1": 9250.0}, {"ki1": 500.0}]

    headers = [h[0] for h in daq.headers]
    rows = [dict(zip(headers, values, strict=True)) for _, _, values in policy.samples]
    ticks = np.array([r["tick"] for r in rows])
    assert np.array_equal(ticks, np.arange(ticks[0], ticks[0] + len(ticks)))  # every tick once, in order
    stamps = np.array([ts for _, ts, _ in policy.samples])
    assert np.array_equal(stamps - stamps[0], (np.round(ticks * TS * 1e6).astype(np.int64) - round(ticks[0] * TS * 1e6)) * 1000)
    record = run.controller.record
    index = np.searchsorted(record.column("tick"), ticks)
    for name in DAQ_NAMES:
        assert np.array_equal(np.array([r[name] for r in rows]), record.column(name)[index].astype(np.int64)), name
    # the DTOs were 8 bytes at most: more than one ODT a sample
    assert counters["xcp_can_dtos_sent"] >= 2 * len(ticks)


def test_identifiers_the_rig_uses_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"^xcp: master identifier 0x601 is the CANopen sdo_rx COB-ID$"):
        check_identifiers({"xcp": (0x601, 0x7E1)}, 1)
    with pytest.raises(ValueError, match=r"^plant: slave identifier 0x7E1 is ctrl's slave identifier$"):
        check_identifiers({"ctrl": (0x7E0, 0x7E1), "plant": (0x7E2, 0x7E1)}, 1)
    with pytest.raises(ValueError, match=r"^xcp: master identifier 0x7E5 is the CANopen LSS COB-ID$"):
        check_identifiers({"xcp": (0x7E5, 0x7E1)}, 1)
    with pytest.raises(ValueError, match=r"^xcp: master and slave identifiers are both 0x7E0$"):
        check_identifiers({"xcp": (0x7E0, 0x7E0)}, 1)
    with pytest.raises(ValueError, match=r"^xcp: slave identifier 0x7E1 carries the CANopen node id 97 in its low 7 bits$"):
        check_identifiers({"xcp": (0x7E0, 0x7E1)}, 97)
    check_identifiers({"ctrl": (0x7E0, 0x7E1), "plant": (0x7E2, 0x7E3)}, 127)
    check_identifiers({"ctrl": (0x7E0, 0x7E1), "plant": (0x7E2, 0x7E3)}, 1)
    # the controller refuses its settings in one line, before it opens anything
    service = fake_service(xcp_can=True, xcp_can_id_slave=0x181, can_interface="virtual", can_channel="x", xcp_a2l=str(tmp_path / "x.a2l"))
    with pytest.raises(ConfigError, match=r"^xcp_can_id_master/xcp_can_id_slave: slave identifier 0x181 is the CANopen tpdo1 COB-ID$"):
        XcpLink(service, list(RECORD_COLUMNS))
    assert not (tmp_path / "x.a2l").exists()


def test_frames_not_for_the_slave_are_ignored() -> None:
    """Frames on other identifiers, extended or remote frames: not commands (a virtual bus hands every frame over)."""
    channel = f"ralf-{uuid.uuid4().hex[:8]}"
    slave = Slave(LAYOUT, on_can(SlaveInfo("TEST", "/x/test.a2l", xcp_events(TS))), lambda changes: None, bytes(LAYOUT.size))
    server = CanServer(slave, can.Bus(interface="virtual", channel=channel), 0x7E0, 0x7E1)
    server.start()
    with can.Bus(interface="virtual", channel=channel) as master:
        try:
            master.send(can.Message(arbitration_id=0x7E0, data=b"\xff\x00", is_extended_id=True))
            master.send(can.Message(arbitration_id=0x181, data=b"\xff\x00", is_extended_id=False))
            master.send(can.Message(arbitration_id=0x7E0, is_remote_frame=True, dlc=2, is_extended_id=False))
            master.send(can.Message(arbitration_id=0x7E0, data=b"\xff\x00\x55\x55\x55\x55\x55\x55", is_extended_id=False))  # padded CONNECT
            reply = master.recv(5.0)
            assert reply is not None and reply.arbitration_id == 0x7E1 and reply.data[0] == 0xFF and reply.data[3] == 8
            assert master.recv(0.2) is None
        finally:
            server.close()
    assert slave.counters.commands == 1 and slave.counters.malformed == 1
