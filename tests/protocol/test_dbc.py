"""protocol/ralf.dbc: agrees with protocol/can_map.py, and decodes a recorded
bus session of the plant node (frames both ways) to the values that were sent."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig
from protocol.can_map import (
    DAC12,
    DEFAULT_NODE_ID,
    WORD16_VOLTS_PER_LSB,
    WORD32_VOLTS_PER_LSB,
    ConverterScale,
    EmcyCode,
    NmtCommand,
    NmtState,
    cob_ids,
    encode_nmt,
    encode_sync,
    volts_to_output_frame,
)

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "protocol" / "ralf.dbc"


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    return cantools.database.load_file(str(DBC), strict=True)


def test_dbc_agrees_with_can_map(db: cantools.database.can.Database) -> None:
    ids = cob_ids(DEFAULT_NODE_ID)
    by_frame = {
        "nmt": "NMT",
        "sync": "SYNC",
        "emcy": "EMCY_Plant",
        "tpdo1": "TPDO1_AnalogInputs16",
        "tpdo2": "TPDO2_AnalogInputs32",
        "tpdo3": "TPDO3_AnalogInputs32",
        "rpdo1": "RPDO1_AnalogOutputs16",
        "sdo_tx": "SDO_Tx_Plant",
        "sdo_rx": "SDO_Rx_Plant",
        "heartbeat": "Heartbeat_Plant",
    }
    assert {m.name for m in db.messages} == set(by_frame.values())
    for key, name in by_frame.items():
        assert db.get_message_by_name(name).frame_id == ids[key], name
    lengths = {"NMT": 2, "SYNC": 1, "RPDO1_AnalogOutputs16": 4, "Heartbeat_Plant": 1}
    for m in db.messages:
        assert m.length == lengths.get(m.name, 8), m.name
        assert m.comment, m.name
        for s in m.signals:
            assert s.comment, (m.name, s.name)
    for name, n, scale in (
        ("TPDO1_AnalogInputs16", 4, WORD16_VOLTS_PER_LSB),
        ("RPDO1_AnalogOutputs16", 2, WORD16_VOLTS_PER_LSB),
        ("TPDO2_AnalogInputs32", 2, WORD32_VOLTS_PER_LSB),
        ("TPDO3_AnalogInputs32", 2, WORD32_VOLTS_PER_LSB),
    ):
        sigs = db.get_message_by_name(name).signals
        assert len(sigs) == n
        for s in sigs:
            assert s.is_signed and s.unit == "V" and s.scale == scale and s.byte_order == "little_endian"
    emcy = db.get_message_by_name("EMCY_Plant").get_signal_by_name("EMCY_ErrorCode")
    assert {int(k): str(v) for k, v in emcy.choices.items()} == {int(c): c.name for c in EmcyCode}
    nmt = db.get_message_by_name("NMT").get_signal_by_name("NMT_Command")
    assert {int(k): str(v) for k, v in nmt.choices.items()} == {int(c): c.name for c in NmtCommand}
    hb = db.get_message_by_name("Heartbeat_Plant").get_signal_by_name("HB_State")
    assert {int(k): str(v) for k, v in hb.choices.items()} == {int(c): c.name for c in NmtState}


class RampApp:
    """Inputs that change every sample, quantized by the current A/D."""

    def __init__(self) -> None:
        self.bits = 12
        self.k = 0
        self.sent_volts: list[np.ndarray] = []
        self.outputs: list[np.ndarray] = []

    def on_sync(self, counter: int) -> tuple[np.ndarray, np.ndarray]:
        self.k += 1
        v = np.array([-9.0 + 0.37 * self.k, 4.0 - 0.123 * self.k, 0.001 * self.k, -0.4321])
        self.sent_volts.append(v)
        q = ConverterScale(self.bits).quantize(v)
        return q.counts, q.saturated

    def on_outputs(self, volts: np.ndarray) -> None:
        self.outputs.append(np.array(volts))

    def on_watchdog(self, tripped: bool) -> None:
        pass

    def on_adc_bits(self, bits: int) -> None:
        self.bits = bits


def record_session(path: Path) -> tuple[RampApp, list[np.ndarray], int]:
    """A short master/node session through the pure node, every frame logged."""
    app = RampApp()
    node = CanopenNode(app, NodeConfig(watchdog_periods=0))
    logger = can.Logger(str(path))
    t = 0.0
    commanded: list[np.ndarray] = []
    n = 0

    def log_all(frames: list[can.Message]) -> None:
        nonlocal n
        for f in frames:
            f.timestamp = t
            logger(f)
            n += 1

    def master(cob_id: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, timestamp=t)
        log_all([msg])
        log_all(node.handle(msg, t))

    log_all(node.poll(t))
    master(0x000, encode_nmt(NmtCommand.START, 1))
    master(0x601, struct.pack("<BHBf", 0x23, 0x2002, 0, 6.0))  # valve limit 6 V by SDO
    for k in range(1, 31):
        t += 0.005
        if k == 16:  # switch to 20 bits by SDO half way
            master(0x601, struct.pack("<BHB4x", 0x2F, 0x2001, 0)[:4] + bytes([20, 0, 0, 0]))
        master(0x080, encode_sync(k))
        volts = np.array([np.sin(k / 3) * 7.0, -0.01 * k])  # exceeds 6 V now and then: EMCY
        commanded.append(volts)
        master(0x201, volts_to_output_frame(volts)[0])
        log_all(node.poll(t))
    logger.stop()
    return app, commanded, n


@pytest.mark.parametrize("suffix", [".asc", ".log", ".blf"])
def test_recorded_session_decodes_to_the_sent_values(db: cantools.database.can.Database, tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"session{suffix}"
    app, commanded, n_frames = record_session(path)
    frames = list(can.LogReader(str(path)))
    assert len(frames) == n_frames
    decoded = [(f.arbitration_id, db.decode_message(f.arbitration_id, f.data)) for f in frames]

    syncs = [d["SYNC_Counter"] for i, d in decoded if i == 0x080]
    assert syncs == list(range(1, 31))
    assert [d["NMT_Command"] for i, d in decoded if i == 0x000] == ["START"]
    states = [str(d["HB_State"]) for i, d in decoded if i == 0x701]
    assert states[0] == "BOOT_UP"

    tpdo1 = np.array([[d[f"AI{c}"] for c in range(1, 5)] for i, d in decoded if i == 0x181])
    sent = np.array(app.sent_volts)
    assert tpdo1.shape == (30, 4)
    np.testing.assert_allclose(tpdo1[:15], sent[:15], atol=ConverterScale(12).lsb_v / 2)
    np.testing.assert_allclose(tpdo1[15:], sent[15:], atol=20.0 / 2**16)  # 16 MSBs of a 20-bit code
    wide = np.hstack(
        [
            np.array([[d["AI1_32"], d["AI2_32"]] for i, d in decoded if i == 0x281]),
            np.array([[d["AI3_32"], d["AI4_32"]] for i, d in decoded if i == 0x381]),
        ]
    )
    assert wide.shape == (15, 4)
    np.testing.assert_allclose(wide, sent[15:], atol=ConverterScale(20).lsb_v / 2)

    rpdo = np.array([[d["AO1"], d["AO2"]] for i, d in decoded if i == 0x201])
    np.testing.assert_allclose(rpdo, np.array(commanded), atol=DAC12.lsb_v / 2)
    applied = np.array(app.outputs)
    np.testing.assert_allclose(applied, np.clip(rpdo, -6.0, 6.0), atol=DAC12.lsb_v)

    emcy = [(d["EMCY_ErrorCode"], d["EMCY_ErrorRegister"]) for i, d in decoded if i == 0x081]
    assert emcy and emcy[0] == ("OUTPUT_CLIPPED", 0x03)
    assert [str(c) for c, _ in emcy] == ["OUTPUT_CLIPPED", "NO_ERROR"] * (len(emcy) // 2) + (["OUTPUT_CLIPPED"] if len(emcy) % 2 else [])
    sdo = [d for i, d in decoded if i in (0x581, 0x601)]
    assert [str(d.get("SDO_Rx_Command", d.get("SDO_Tx_Command"))) for d in sdo] == [
        "DOWNLOAD_EXPEDITED_4",
        "DOWNLOAD_INITIATE_RESPONSE",
        "DOWNLOAD_EXPEDITED_1",
        "DOWNLOAD_INITIATE_RESPONSE",
    ]


def test_cantools_cli_decodes_a_candump_log(tmp_path: Path) -> None:
    path = tmp_path / "session.log"
    record_session(path)
    with path.open() as log:
        out = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DBC)], stdin=log, capture_output=True, text=True, timeout=60, check=True).stdout
    assert out.count("TPDO1_AnalogInputs16(") == 30
    assert "EMCY_ErrorCode: OUTPUT_CLIPPED" in out and "HB_State: BOOT_UP" in out
    assert "Unknown" not in out


def test_cantools_cli_decodes_sync_with_and_without_counter() -> None:
    """The controller's SYNC (counter byte) and a stock master's (``canopen``'s
    ``network.sync.start``: no data) through ``python -m cantools decode``.
    A DBC message has one length, so the counter-less SYNC needs cantools'
    ``--no-strict`` (its allow_truncated); the counter form decodes either way."""
    frames = "  vcan0  080   [0]\n  vcan0  080   [1]  05\n  vcan0  081   [8]  30 81 11 01 07 01 04 00\n"

    def decode(*flags: str) -> list[str]:
        run = subprocess.run(
            [sys.executable, "-m", "cantools", "decode", "--single-line", *flags, str(DBC)],
            input=frames,
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
        return run.stdout.strip().splitlines()

    without, with_counter, emcy = decode("--no-strict")
    assert without.endswith(":: SYNC()")
    assert with_counter.endswith(":: SYNC(SYNC_Counter: 5)")
    assert "EMCY_ErrorCode: SYNC_TIMEOUT" in emcy  # 0x8130, CiA 301's life guard / heartbeat error
    strict = decode()
    assert strict[1].endswith(":: SYNC(SYNC_Counter: 5)")
    assert "Wrong data size: 0 instead of 1 bytes" in strict[0]  # strict checks the DBC's one length
