"""The CANopen node as a pure state machine: frames and times in, frames out."""

from __future__ import annotations

import configparser
import logging
import struct
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plant_emulator.canopen_node import (
    CanopenNode,
    NodeConfig,
    error_register_bits,
    object_table,
    render_eds,
)
from plant_emulator.canopen_node.eds import UNITS_FILE, real32_bits, render_units
from plant_emulator.canopen_node.node import CONFLICT_CLEAR_PERIODS
from plant_emulator.canopen_node.od import DataType, SdoAbortCode
from plant_emulator.canopen_node.sdo_server import SdoServer
from protocol.can_map import (
    ADC12,
    DAC12,
    EmcyCode,
    NmtCommand,
    NmtState,
    decode_analog_inputs_16,
    decode_analog_inputs_32,
    decode_emcy,
    encode_analog_outputs,
    encode_nmt,
    volts_to_output_frame,
)
from protocol.errors import ConfigError
from tests.plant.support import EDS, FakeApp

ROOT = Path(__file__).resolve().parents[2]

NMT, SYNC, EMCY, TPDO1, TPDO2, TPDO3, RPDO1, SDO_TX, SDO_RX, HB = (0x000, 0x080, 0x081, 0x181, 0x281, 0x381, 0x201, 0x581, 0x601, 0x701)


def frame(cob_id: int, data: bytes | list[int] = b"", **kw: object) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=bytes(data), is_extended_id=False, **kw)  # type: ignore[arg-type]


def ids(frames: list[can.Message]) -> list[int]:
    return [f.arbitration_id for f in frames]


def of(frames: list[can.Message], cob_id: int) -> list[can.Message]:
    return [f for f in frames if f.arbitration_id == cob_id]


class Rig:
    """A node, its fake app and a manual clock."""

    def __init__(self, cfg: NodeConfig | None = None, app: FakeApp | None = None) -> None:
        self.app = app or FakeApp()
        self.node = CanopenNode(self.app, cfg or NodeConfig())
        self.t = 0.0
        self.boot = self.node.poll(self.t)
        self.sync_counter = 0

    def send(self, cob_id: int, data: bytes | list[int] = b"", dt: float = 0.0, **kw: object) -> list[can.Message]:
        self.t += dt
        return self.node.handle(frame(cob_id, data, **kw), self.t)

    def nmt(self, command: NmtCommand, node_id: int = 1) -> list[can.Message]:
        return self.send(NMT, encode_nmt(command, node_id))

    def sync(self, counter: int | None = None, dt: float = 0.005) -> list[can.Message]:
        self.sync_counter = counter if counter is not None else self.sync_counter % 240 + 1
        return self.send(SYNC, [self.sync_counter], dt=dt)

    def run(self, until: float, step: float = 0.001) -> list[can.Message]:
        out: list[can.Message] = []
        while self.t + step <= until + 1e-12:
            self.t += step
            out += self.node.poll(self.t)
        return out

    def sdo(self, request: bytes) -> bytes:
        replies = of(self.send(SDO_RX, request), SDO_TX)
        assert len(replies) == 1
        return bytes(replies[0].data)

    def read(self, index: int, sub: int = 0) -> int:
        r = self.sdo(struct.pack("<BHB4x", 0x40, index, sub))
        assert r[0] & 0xE3 == 0x43, f"not an expedited upload: {r.hex()}"
        n = 4 - ((r[0] >> 2) & 3)
        return int.from_bytes(r[4 : 4 + n], "little", signed=False)

    def write(self, index: int, sub: int, data: bytes) -> bytes:
        cmd = 0x23 | ((4 - len(data)) << 2)
        return self.sdo(struct.pack("<BHB", cmd, index, sub) + data.ljust(4, b"\x00"))


def abort_code(reply: bytes) -> int | None:
    return struct.unpack_from("<I", reply, 4)[0] if reply[0] == 0x80 else None


def emcys(frames: list[can.Message]) -> list[tuple[int, int, bytes]]:
    out = []
    for f in of(frames, EMCY):
        e = decode_emcy(f.data)
        out.append((e.code, e.register, e.vendor))
    return out


# --- NMT and heartbeat --------------------------------------------------------------------


def test_boot_up_then_pre_operational() -> None:
    rig = Rig()
    assert ids(rig.boot) == [HB] and bytes(rig.boot[0].data) == b"\x00"
    assert rig.node.state is NmtState.PRE_OPERATIONAL


def test_heartbeat_period_follows_0x1017() -> None:
    rig = Rig()
    beats = of(rig.run(1.005), HB)
    times = np.array([b.timestamp for b in beats])
    assert len(beats) == 10
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1.5e-3)
    assert {bytes(b.data) for b in beats} == {bytes([NmtState.PRE_OPERATIONAL])}

    assert rig.write(0x1017, 0, (20).to_bytes(2, "little"))[0] == 0x60
    beats = of(rig.run(rig.t + 0.5), HB)
    np.testing.assert_allclose(np.diff([b.timestamp for b in beats]), 0.02, atol=1.5e-3)
    assert 24 <= len(beats) <= 25

    rig.write(0x1017, 0, b"\x00\x00")
    assert of(rig.run(rig.t + 0.5), HB) == []

    rig = Rig(NodeConfig(heartbeat_ms=50))
    assert len(of(rig.run(1.0), HB)) == 20


def test_nmt_transitions_and_pdo_only_when_operational() -> None:
    rig = Rig(NodeConfig(watchdog_periods=0))
    # no PDO before START
    assert rig.sync() == [] and rig.app.syncs == []
    assert rig.send(RPDO1, encode_analog_outputs([1600, 0])) == []
    assert rig.app.outputs == []
    assert rig.node.counters.malformed["rpdo_not_operational"] == 1

    # commands for other nodes are ignored; ours and broadcast act
    rig.nmt(NmtCommand.START, node_id=5)
    assert rig.node.state is NmtState.PRE_OPERATIONAL
    assert rig.node.counters.rx["nmt_other_node"] == 1
    rig.nmt(NmtCommand.START)
    assert rig.node.state is NmtState.OPERATIONAL
    assert ids(rig.sync()) == [TPDO1]
    assert of(rig.run(rig.t + 0.1), HB)[-1].data == bytes([NmtState.OPERATIONAL])

    rig.send(RPDO1, encode_analog_outputs([1600, -1600]))
    assert rig.app.outputs[-1].tolist() == [100 * DAC12.lsb_v, -100 * DAC12.lsb_v]

    # STOP (broadcast): valves to zero, no SYNC processing, no SDO, no EMCY
    rig.nmt(NmtCommand.STOP, node_id=0)
    assert rig.node.state is NmtState.STOPPED
    assert rig.app.outputs[-1].tolist() == [0.0, 0.0]
    assert rig.sync() == []
    assert rig.send(SDO_RX, struct.pack("<BHB4x", 0x40, 0x1000, 0)) == []
    # an SDO request in STOPPED is well formed: not answered (CiA 301), counted as such, not as malformed
    assert rig.node.counters.rx["sdo_stopped"] == 1 and "sdo_stopped" not in rig.node.counters.malformed
    assert rig.node.counters.malformed_total == 1  # the RPDO before START above, nothing more
    assert of(rig.run(rig.t + 0.1), HB)[-1].data == bytes([NmtState.STOPPED])

    rig.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    assert rig.node.state is NmtState.PRE_OPERATIONAL
    assert rig.read(0x1000) == 0x000C0191
    rig.nmt(NmtCommand.START)
    assert rig.node.state is NmtState.OPERATIONAL

    # RESET_COMMUNICATION: boot-up again, communication objects back to defaults
    rig.write(0x1017, 0, (40).to_bytes(2, "little"))
    rig.write(0x2003, 0, (9).to_bytes(2, "little"))
    out = rig.nmt(NmtCommand.RESET_COMMUNICATION)
    assert [(f.arbitration_id, bytes(f.data)) for f in out] == [(HB, b"\x00")]
    assert rig.node.state is NmtState.PRE_OPERATIONAL
    assert rig.read(0x1017) == 100
    assert rig.read(0x2003) == 9  # application area survives a communication reset

    # RESET_NODE: everything back to the configuration, the app told about the resolution
    rig.write(0x2001, 0, b"\x14")
    assert rig.app.adc_calls == [20]
    out = rig.nmt(NmtCommand.RESET_NODE)
    assert ids(out) == [HB] and out[0].data == b"\x00"
    assert rig.read(0x2003) == 0 and rig.read(0x2001) == 12  # the configured values
    assert rig.app.adc_calls == [20, 12]
    assert rig.read(0x1801, 1) & (1 << 31)


def test_tpdo1_carries_left_justified_codes_and_the_od_follows() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    out = rig.sync(counter=7)
    assert rig.app.syncs == [7]
    (tpdo,) = out
    words = decode_analog_inputs_16(tpdo.data)
    np.testing.assert_array_equal(words, ADC12.quantize(rig.app.volts).counts << 4)
    np.testing.assert_allclose(words * 10 / 32768, rig.app.volts, atol=ADC12.lsb_v / 2)
    for sub in range(1, 5):
        raw = rig.read(0x6401, sub)
        assert struct.unpack("<h", raw.to_bytes(2, "little"))[0] == words[sub - 1]


def test_wide_adc_adds_tpdo2_and_tpdo3() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    assert rig.read(0x1801, 1) == 0xC0000281  # not valid at 12 bits
    assert rig.write(0x2001, 0, bytes([20]))[0] == 0x60
    assert rig.app.adc_calls == [20] and rig.node.adc_bits == 20
    assert rig.read(0x1801, 1) == 0x40000281 and rig.read(0x1802, 1) == 0x40000381
    out = rig.sync()
    assert ids(out) == [TPDO1, TPDO2, TPDO3]
    codes20 = rig.app.codes
    w32 = np.concatenate([decode_analog_inputs_32(out[1].data), decode_analog_inputs_32(out[2].data)])
    np.testing.assert_array_equal(w32, codes20 << 12)
    np.testing.assert_array_equal(decode_analog_inputs_16(out[0].data), codes20 >> 4)
    np.testing.assert_allclose(w32 * 10 / 2**31, rig.app.volts, atol=20 / 2**20 / 2)

    assert abort_code(rig.write(0x2001, 0, bytes([14]))) == SdoAbortCode.INVALID_VALUE
    assert rig.write(0x2001, 0, bytes([16]))[0] == 0x60
    assert ids(rig.sync()) == [TPDO1]

    class NoResolutionApp(FakeApp):
        on_adc_bits = None  # type: ignore[assignment]

    rig = Rig(app=NoResolutionApp())
    assert abort_code(rig.write(0x2001, 0, bytes([16]))) == SdoAbortCode.CANNOT_STORE
    assert rig.node.adc_bits == 12


def test_sync_gaps_and_repeats_are_counted() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    for c in (1, 2, 5, 6, 100, 200, 240, 1, 3, 3):
        rig.sync(counter=c)
    c = rig.node.counters
    # gaps below half the counter range are lost SYNCs; 240 -> 1 is the wrap
    assert (c.sync_gaps, c.syncs_missed, c.sync_repeats) == (5, 2 + 93 + 99 + 39 + 1, 1)
    assert rig.app.syncs == [1, 2, 5, 6, 100, 200, 240, 1, 3, 3]
    assert rig.read(0x2010, 2) == 234


def test_a_second_sync_producer_raises_sync_conflict_until_clean_again() -> None:
    """Two producers interleaved (ours counting from 1, a foreign one from 100):
    every other counter jumps back, which one producer cannot do."""
    rig = Rig()
    rig.nmt(NmtCommand.START)
    out: list[can.Message] = []
    for k in range(4):
        out += rig.sync(counter=1 + k, dt=0.0025)
        out += rig.sync(counter=100 + k, dt=0.0025)
    (first,) = [e for e in emcys(out) if e[0] == EmcyCode.SYNC_CONFLICT]  # one EMCY per episode
    assert first[1] == 0x01 | 0x80  # manufacturer-specific bit
    assert rig.node.counters.sync_conflicts >= 3
    assert EmcyCode.SYNC_CONFLICT in rig.node.active_faults
    out = []
    for k in range(CONFLICT_CLEAR_PERIODS):
        out += rig.sync(counter=104 + k)
    assert emcys(out) == [(0, 0, struct.pack("<H", EmcyCode.SYNC_CONFLICT) + b"\x00" * 3)]
    # a repeated counter and counter / no counter mixed are conflicts too
    n = rig.node.counters.sync_conflicts
    rig.sync(counter=rig.sync_counter)
    rig.send(SYNC, b"", dt=0.005)
    assert rig.node.counters.sync_conflicts == n + 2


def test_sync_with_and_without_counter_both_accepted_by_default() -> None:
    """CiA 301: with 0x1019 > 1 a SYNC carries the counter, yet stock masters
    (canopen's SyncProducer) send it empty; both get TPDOs without a conflict."""
    rig = Rig()
    assert rig.read(0x1019) == 240
    rig.nmt(NmtCommand.START)
    for _ in range(3):
        assert ids(rig.send(SYNC, b"", dt=0.005)) == [TPDO1]
    assert rig.app.syncs == [0, 0, 0]
    assert rig.node.counters.malformed_total == 0 and rig.node.counters.sync_conflicts == 0
    rig.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    rig.nmt(NmtCommand.START)  # a new session may use the other form
    assert ids(rig.sync(counter=1)) == [TPDO1]
    assert rig.node.counters.sync_conflicts == 0


def test_sync_without_counter() -> None:
    rig = Rig()
    assert abort_code(rig.write(0x1019, 0, bytes([7]))) == SdoAbortCode.INVALID_VALUE
    assert rig.write(0x1019, 0, bytes([0]))[0] == 0x60
    rig.nmt(NmtCommand.START)
    assert ids(rig.send(SYNC, b"", dt=0.005)) == [TPDO1]
    assert rig.app.syncs == [0]
    assert rig.send(SYNC, b"\x01", dt=0.005) == []
    assert rig.node.counters.malformed["sync_dlc"] == 1


# --- watchdog ----------------------------------------------------------------------------


def test_watchdog_trips_after_five_periods_and_recovers_on_sync() -> None:
    rig = Rig()
    rig.run(0.05)  # no SYNC yet: not armed
    rig.nmt(NmtCommand.START)
    rig.run(0.2)
    assert rig.app.watchdog == []
    for _ in range(10):
        rig.sync()
    rig.send(RPDO1, encode_analog_outputs([3200, 0]))
    last_sync = rig.t
    out = rig.run(last_sync + 0.1)
    assert rig.app.watchdog == [True] and rig.node.watchdog_tripped
    (trip,) = of(out, EMCY)
    assert trip.timestamp - last_sync == pytest.approx(0.025, abs=1.5e-3)
    code, register, vendor = emcys([trip])[0]
    assert code == EmcyCode.SYNC_TIMEOUT and register == 0x01 | 0x10 and vendor[0] == rig.sync_counter
    assert rig.read(0x1001) == 0x11
    assert rig.node.outputs_v.tolist() == [0.0, 0.0]

    # outputs are held while tripped
    assert rig.send(RPDO1, encode_analog_outputs([3200, 0])) == []
    assert rig.node.counters.outputs_held == 1 and rig.node.outputs_v.tolist() == [0.0, 0.0]
    assert abort_code(rig.write(0x6411, 1, (160).to_bytes(2, "little"))) == SdoAbortCode.CANNOT_STORE_DEVICE_STATE

    out = rig.sync()
    assert rig.app.watchdog == [True, False] and not rig.node.watchdog_tripped
    assert emcys(out) == [(0, 0, struct.pack("<H", EmcyCode.SYNC_TIMEOUT) + b"\x00" * 3)]
    assert TPDO1 in ids(out)
    rig.send(RPDO1, encode_analog_outputs([3200, 0]))
    assert rig.node.outputs_v[0] == pytest.approx(200 * DAC12.lsb_v)
    assert (rig.node.counters.watchdog_trips, rig.node.counters.watchdog_recoveries) == (1, 1)
    assert rig.read(0x2010, 3) == 1


def test_watchdog_configurable_and_disabled() -> None:
    rig = Rig(NodeConfig(watchdog_periods=2, sample_period_s=0.010))
    rig.nmt(NmtCommand.START)
    rig.sync()
    t0 = rig.t
    out = rig.run(t0 + 0.05)
    assert of(out, EMCY)[0].timestamp - t0 == pytest.approx(0.020, abs=1.5e-3)

    rig = Rig(NodeConfig(watchdog_periods=0))
    rig.nmt(NmtCommand.START)
    rig.sync()
    rig.run(rig.t + 1.0)
    assert rig.app.watchdog == [] and rig.node.counters.watchdog_trips == 0


def test_the_watchdog_cannot_be_switched_off_over_the_bus() -> None:
    """Anyone on the bus can send an SDO: 0x2003 = 0 is refused in every state
    (abort 0x08000022) and counted; a longer time is still accepted."""
    rig = Rig()
    assert abort_code(rig.write(0x2003, 0, b"\x00\x00")) == SdoAbortCode.CANNOT_STORE_DEVICE_STATE
    rig.nmt(NmtCommand.START)
    rig.sync()
    assert abort_code(rig.write(0x2003, 0, b"\x00\x00")) == SdoAbortCode.CANNOT_STORE_DEVICE_STATE
    assert rig.read(0x2003) == 5 and rig.node.counters.watchdog_disable_refused == 2
    assert rig.write(0x2003, 0, (400).to_bytes(2, "little"))[0] == 0x60
    rig.run(rig.t + 0.1)
    assert rig.app.watchdog == []


def test_leaving_operational_ends_a_trip() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    rig.sync()
    rig.run(rig.t + 0.05)
    assert rig.app.watchdog == [True]
    out = rig.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    assert rig.app.watchdog == [True, False]
    assert [c for c, _, _ in emcys(out)] == [0]
    assert rig.node.error_register == 0


# --- outputs --------------------------------------------------------------------------


def test_outputs_quantized_and_clipped_with_one_emcy_per_episode() -> None:
    rig = Rig()
    assert rig.write(0x2002, 0, struct.pack("<f", 5.0))[0] == 0x60
    assert abort_code(rig.write(0x2002, 0, struct.pack("<f", 12.0))) == SdoAbortCode.VALUE_TOO_HIGH
    assert abort_code(rig.write(0x2002, 0, struct.pack("<f", -1.0))) == SdoAbortCode.VALUE_TOO_LOW
    assert abort_code(rig.write(0x2002, 0, struct.pack("<f", float("nan")))) == SdoAbortCode.INVALID_VALUE
    rig.nmt(NmtCommand.START)

    payload, _ = volts_to_output_frame([1.2345, -0.5])
    assert rig.send(RPDO1, payload) == []
    np.testing.assert_allclose(rig.app.outputs[-1], [1.2345, -0.5], atol=DAC12.lsb_v / 2)

    emitted = []
    for _ in range(5):
        emitted += rig.send(RPDO1, volts_to_output_frame([8.0, -1.0])[0])
        assert rig.app.outputs[-1][0] == 5.0
        assert rig.app.outputs[-1][1] == pytest.approx(-1.0, abs=DAC12.lsb_v / 2)
    assert emcys(emitted) == [(EmcyCode.OUTPUT_CLIPPED, 0x03, b"\x01\x00\x00\x00\x00")]
    assert rig.node.counters.clipped_outputs == 5
    out = rig.send(RPDO1, volts_to_output_frame([1.0, -6.0])[0])  # channel 2 now: still clipped
    assert out == [] and rig.app.outputs[-1][1] == -5.0
    out = rig.send(RPDO1, volts_to_output_frame([1.0, 1.0])[0])
    assert emcys(out) == [(0, 0, struct.pack("<H", EmcyCode.OUTPUT_CLIPPED) + b"\x00" * 3)]
    out = rig.send(RPDO1, volts_to_output_frame([-9.0, 1.0])[0])
    assert [c for c, _, _ in emcys(out)] == [EmcyCode.OUTPUT_CLIPPED]
    assert rig.app.outputs[-1][0] == -5.0
    # lowering the limit re-clips what the valves get now
    rig.send(RPDO1, volts_to_output_frame([4.0, 0.0])[0])
    rig.write(0x2002, 0, struct.pack("<f", 2.5))
    assert rig.app.outputs[-1][0] == 2.5


def test_sdo_write_of_outputs_applies_like_rpdo() -> None:
    rig = Rig()
    assert abort_code(rig.write(0x6411, 1, (1600).to_bytes(2, "little"))) == SdoAbortCode.CANNOT_STORE_DEVICE_STATE
    rig.nmt(NmtCommand.START)
    assert rig.write(0x6411, 2, (-1600).to_bytes(2, "little", signed=True))[0] == 0x60
    assert rig.app.outputs[-1].tolist() == [0.0, -100 * DAC12.lsb_v]
    assert rig.read(0x6411, 2) == 0x10000 - 1600


# --- malformed frames -------------------------------------------------------------------


def test_malformed_frames_counted_logged_once_and_ignored(caplog: pytest.LogCaptureFixture) -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    rig.sync()
    caplog.set_level(logging.WARNING, logger="plant_emulator.canopen_node.node")
    bad = [
        ("nmt_dlc", frame(NMT, [1])),
        ("nmt_command", frame(NMT, [0x03, 1])),
        ("nmt_node_id", frame(NMT, [0x01, 200])),
        ("sync_dlc", frame(SYNC, [1, 2])),
        ("sync_counter", frame(SYNC, [0])),
        ("sync_counter", frame(SYNC, [241])),
        ("rpdo_dlc", frame(RPDO1, [0, 0, 0])),
        ("unknown_cob_id", frame(0x301, [1, 2])),
        ("unknown_cob_id", frame(0x681, [])),
        ("rtr", frame(HB, is_remote_frame=True)),
        ("sdo_dlc", frame(SDO_RX, [0x40, 0, 0x10])),
    ]
    out: list[can.Message] = []
    for _ in range(3):
        for _, msg in bad:
            out += rig.node.handle(msg, rig.t)
    expected: dict[str, int] = {}
    for kind, _ in bad:
        expected[kind] = expected.get(kind, 0) + 3
    assert dict(rig.node.counters.malformed) == expected
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == len(expected)
    assert {k for k in expected if any(k in r.getMessage() for r in warnings)} == set(expected)
    # only the wrong-length RPDO answers, with one EMCY
    assert emcys(out) == [(EmcyCode.PDO_LENGTH, 0x11, b"\x03\x00\x00\x00\x00")]
    assert rig.node.state is NmtState.OPERATIONAL and rig.node.counters.internal_errors == 0
    assert rig.read(0x2010, 5) == sum(expected.values())
    # the next good RPDO clears the PDO length fault
    out = rig.send(RPDO1, encode_analog_outputs([0, 0]))
    assert emcys(out) == [(0, 0, struct.pack("<H", EmcyCode.PDO_LENGTH) + b"\x00" * 3)]
    # other nodes' traffic is not malformed, and neither are frames on our own COB-IDs, which on
    # this bus (no echoes) another node sent: those are impersonation (see test_frames_on_our_own_cob_ids_*)
    for cob_id in (0x182, 0x602, 0x702, 0x7E5, 0x100):
        assert rig.send(cob_id, [0] * 8) == []
    assert rig.node.counters.rx["foreign"] == 4 and rig.node.counters.impersonated_total == 0
    for cob_id in (TPDO1, EMCY, HB, SDO_TX):
        rig.send(cob_id, [0] * 8)
    assert rig.node.counters.impersonated_total == 4 and rig.node.counters.rx["own_cob_id"] == 0
    assert sum(rig.node.counters.malformed.values()) == sum(expected.values())


def test_app_failures_cost_a_sample_not_the_node(caplog: pytest.LogCaptureFixture) -> None:
    class Flaky(FakeApp):
        mode = "raise"

        def on_sync(self, counter: int) -> tuple[np.ndarray, np.ndarray]:
            if self.mode == "raise":
                raise RuntimeError("model diverged")
            if self.mode == "shape":
                return np.zeros(3, dtype=np.int64), np.zeros(4, dtype=bool)
            return np.array([5000, -5000, 0, 1]), np.zeros(4, dtype=bool)

    app = Flaky()
    rig = Rig(app=app)
    rig.nmt(NmtCommand.START)
    with caplog.at_level(logging.ERROR):
        assert rig.sync() == [] and rig.sync() == []
    app.mode = "shape"
    assert rig.sync() == []
    app.mode = "range"
    (tpdo,) = rig.sync()
    np.testing.assert_array_equal(decode_analog_inputs_16(tpdo.data), [2047 << 4, -2048 << 4, 0, 16])
    c = rig.node.counters
    assert (c.app_errors, c.app_codes_clipped, c.internal_errors) == (3, 1, 0)


def test_saturation_and_application_faults_raise_emcy() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    rig.app.saturated[:] = [False, False, True, False]
    out = rig.sync() + rig.sync()
    assert emcys(out) == [(EmcyCode.INPUT_SATURATED, 0x01, b"\x04\x00\x00\x00\x00")]
    rig.node.set_fault(EmcyCode.JOINT_LIMIT, True, b"\x02")
    assert emcys(rig.node.poll(rig.t)) == [(EmcyCode.JOINT_LIMIT, 0x81, b"\x02\x00\x00\x00\x00")]
    assert rig.read(0x1001) == 0x81
    rig.app.saturated[:] = False
    assert emcys(rig.sync())[0][:2] == (0, 0x81)
    rig.node.set_fault(EmcyCode.JOINT_LIMIT, False)
    assert emcys(rig.node.poll(rig.t)) == [(0, 0, b"\x01\xff\x00\x00\x00")]
    # the error history, newest first
    assert rig.read(0x1003, 0) == 2
    assert rig.read(0x1003, 1) == 0x0002FF01 and rig.read(0x1003, 2) == 0x00045010
    assert abort_code(rig.write(0x1003, 0, b"\x01")) == SdoAbortCode.INVALID_VALUE
    rig.write(0x1003, 0, b"\x00")
    assert rig.read(0x1003, 0) == 0 and rig.read(0x1003, 1) == 0
    # in STOPPED, EMCYs are counted, not sent
    rig.nmt(NmtCommand.STOP)
    rig.node.set_fault(EmcyCode.JOINT_LIMIT, True)
    assert rig.node.poll(rig.t) == [] and rig.node.counters.emcy_suppressed == 1
    assert error_register_bits(EmcyCode.OUTPUT_CLIPPED) == 0x02


# --- SDO ---------------------------------------------------------------------------------


def test_sdo_server_transfers_and_abort_codes() -> None:
    rig = Rig()
    cfg = rig.node.cfg
    # expedited uploads
    assert rig.read(0x1000) == 0x000C0191
    assert [rig.read(0x1018, s) for s in range(5)] == [4, cfg.vendor_id, cfg.product_code, cfg.revision, cfg.serial_number]
    assert rig.read(0x1014) == 0x81 and rig.read(0x1800, 1) == 0x40000181 and rig.read(0x1A00, 1) == 0x64010110
    # segmented upload of the device name
    r = rig.sdo(struct.pack("<BHB4x", 0x40, 0x1008, 0))
    assert r[0] == 0x41
    size = struct.unpack_from("<I", r, 4)[0]
    name, toggle = b"", 0
    while True:
        seg = rig.sdo(bytes([0x60 | toggle]) + bytes(7))
        assert seg[0] & 0x10 == toggle
        name += seg[1 : 8 - ((seg[0] >> 1) & 7)]
        toggle ^= 0x10
        if seg[0] & 1:
            break
    assert name.decode() == cfg.device_name and len(name) == size
    # aborts
    assert abort_code(rig.sdo(struct.pack("<BHB4x", 0x40, 0x5555, 0))) == SdoAbortCode.OBJECT_DOES_NOT_EXIST
    assert abort_code(rig.sdo(struct.pack("<BHB4x", 0x40, 0x6401, 9))) == SdoAbortCode.SUBINDEX_DOES_NOT_EXIST
    assert abort_code(rig.write(0x6401, 1, b"\x00\x01")) == SdoAbortCode.WRITE_READ_ONLY
    assert abort_code(rig.write(0x1008, 0, b"abc")) == SdoAbortCode.WRITE_READ_ONLY
    assert abort_code(rig.write(0x2001, 0, b"\x10\x00")) == SdoAbortCode.LENGTH_TOO_HIGH
    assert abort_code(rig.write(0x1017, 0, b"\x10")) == SdoAbortCode.LENGTH_TOO_LOW
    assert abort_code(rig.write(0x2000, 0, (50).to_bytes(4, "little"))) == SdoAbortCode.VALUE_TOO_LOW
    assert abort_code(rig.sdo(bytes([0x60]) + bytes(7))) == SdoAbortCode.INVALID_COMMAND  # no upload open
    assert abort_code(rig.sdo(bytes([0xA4]) + bytes(7))) == SdoAbortCode.INVALID_COMMAND  # block upload
    assert abort_code(rig.sdo(bytes([0xC2]) + bytes(7))) == SdoAbortCode.INVALID_COMMAND  # block download
    # toggle error in a segmented upload
    rig.sdo(struct.pack("<BHB4x", 0x40, 0x1008, 0))
    r = rig.sdo(bytes([0x70]) + bytes(7))
    assert abort_code(r) == SdoAbortCode.TOGGLE_NOT_ALTERNATED and r[1:4] == b"\x08\x10\x00"
    # a client abort closes an open transfer silently
    rig.sdo(struct.pack("<BHB4x", 0x40, 0x1008, 0))
    assert rig.send(SDO_RX, bytes([0x80]) + bytes(7)) == []
    assert not rig.node.sdo.busy
    # expedited download without size indicated, segmented download with size
    assert rig.sdo(struct.pack("<BHB", 0x22, 0x1017, 0) + (250).to_bytes(4, "little"))[0] == 0x60
    assert rig.read(0x1017) == 250
    assert rig.sdo(struct.pack("<BHBI", 0x21, 0x2000, 0, 4))[0] == 0x60
    assert rig.sdo(bytes([0x00 | (3 << 1) | 1]) + (2500).to_bytes(4, "little") + bytes(3)) == bytes([0x20]) + bytes(7)
    assert rig.read(0x2000) == 2500 and rig.node.sample_period_s == pytest.approx(0.0025)
    assert abort_code(rig.sdo(struct.pack("<BHBI", 0x21, 0x2000, 0, 3))) == SdoAbortCode.LENGTH_TOO_LOW
    c = rig.node.counters.as_dict()
    assert c["sdo_aborts"] == 12 and c["sdo_abort_0x06020000"] == 1 and c["sdo_client_aborts"] == 1


# --- object dictionary <-> EDS ------------------------------------------------------------


def test_shipped_eds_is_rendered_from_the_table() -> None:
    assert EDS.read_text() == render_eds(), "regenerate: python -m plant_emulator.canopen_node --write protocol"
    assert EDS.with_name(UNITS_FILE).read_text() == render_units(), "regenerate: python -m plant_emulator.canopen_node --write protocol"


def test_eds_loads_in_canopen_and_agrees_with_the_running_dictionary() -> None:
    od = canopen.import_od(str(EDS), 1)
    rig = Rig()
    table = object_table(NodeConfig())
    assert sorted(od.indices) == sorted(o.index for o in table)
    for obj in table:
        for e in obj.entries:
            var = od.get_variable(e.index, e.sub)
            assert var is not None, (hex(e.index), e.sub)
            assert var.data_type == int(e.dtype) and var.access_type == e.access.value
            assert var.pdo_mappable == e.pdo_mapping
            live = rig.node.od.get(e.index, e.sub)
            if e.dtype is DataType.REAL32:  # CiA 306: the IEEE-754 bit pattern in hex, which canopen leaves undecoded
                assert var.default_raw == real32_bits(float(live))
                (default,) = struct.unpack(">f", int(var.default_raw, 16).to_bytes(4, "big"))
                assert default == live and var.default is None
                continue
            assert var.default == live, (hex(e.index), e.sub, var.default, live)
            if e.dtype is not DataType.VISIBLE_STRING:
                assert rig.node.od.read(e.index, e.sub) == var.encode_raw(var.default)
        assert (od[obj.index].name if obj.index in od else None) == obj.name
    cp = configparser.RawConfigParser()
    cp.optionxform = str  # type: ignore[assignment,method-assign]
    cp.read(EDS)
    assert int(cp["DeviceInfo"]["NrOfTXPDO"]) == 3 and int(cp["DeviceInfo"]["NrOfRXPDO"]) == 1


def test_config_is_validated() -> None:
    for bad in (
        dict(adc_bits=14),
        dict(node_id=0),
        dict(valve_limit_v=11.0),
        dict(sample_period_s=1e-5),
        dict(sync_counter_overflow=100),
        dict(device_name="a;b"),
    ):
        with pytest.raises(ConfigError):
            NodeConfig(**bad)  # type: ignore[arg-type]
    assert NodeConfig(sample_period_s=1 / 300).sample_period_us == 3333


# --- fuzz --------------------------------------------------------------------------------

OUR_IDS = [NMT, SYNC, RPDO1, SDO_RX, HB, TPDO1, EMCY, 0x301, 0x100, 0x7E5, 0x202]

frames = st.builds(
    lambda cob_id, data, ext, rtr, err, fd: can.Message(
        arbitration_id=cob_id,
        data=data,
        is_extended_id=ext,
        is_remote_frame=rtr and not fd,
        is_error_frame=err,
        is_fd=fd,
        check=False,
    ),
    cob_id=st.one_of(st.sampled_from(OUR_IDS), st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
    data=st.one_of(st.binary(max_size=8), st.binary(min_size=9, max_size=64)),
    ext=st.sampled_from([False] * 5 + [True]),
    rtr=st.booleans(),
    err=st.sampled_from([False] * 9 + [True]),
    fd=st.sampled_from([False] * 9 + [True]),
)

NODE_COB_IDS = {0x081, 0x181, 0x281, 0x381, 0x581, 0x701}


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=st.booleans(),
    script=st.lists(st.tuples(frames, st.floats(0, 0.05)), max_size=40),
)
def test_fuzz_arbitrary_frames_never_raise(start: bool, script: list[tuple[can.Message, float]]) -> None:
    rig = Rig()
    if start:
        rig.nmt(NmtCommand.START)
        rig.sync()
    for msg, dt in script:
        rig.t += dt
        out = rig.node.handle(msg, rig.t) + rig.node.poll(rig.t)
        for f in out:
            assert f.arbitration_id in NODE_COB_IDS and len(f.data) <= 8 and not f.is_extended_id
    assert rig.node.counters.internal_errors == 0
    assert rig.node.state in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL, NmtState.STOPPED)
    assert rig.node.counters.as_dict()  # all ints


INDICES = sorted({o.index for o in object_table(NodeConfig())} | {0x0000, 0x5555, 0xFFFF})
sdo_requests = st.one_of(
    st.binary(min_size=8, max_size=8),
    st.builds(
        lambda cmd, index, sub, data: struct.pack("<BHB", cmd, index, sub) + data,
        cmd=st.one_of(st.sampled_from([0x40, 0x60, 0x70, 0x23, 0x27, 0x2B, 0x2F, 0x22, 0x21, 0x00, 0x11, 0x80]), st.integers(0, 255)),
        index=st.sampled_from(INDICES),
        sub=st.integers(0, 10),
        data=st.binary(min_size=4, max_size=4),
    ),
)


@settings(max_examples=300, deadline=None)
@given(start=st.booleans(), requests=st.lists(sdo_requests, max_size=20))
def test_fuzz_sdo_server_answers_every_request_with_eight_bytes(start: bool, requests: list[bytes]) -> None:
    node = CanopenNode(FakeApp())
    if start:
        node.handle(frame(NMT, encode_nmt(NmtCommand.START, 1)), 0.0)
    server: SdoServer = node.sdo
    for req in requests:
        resp = server.handle(req)
        assert resp is None or len(resp) == 8
        if resp is None:
            assert req[0] >> 5 == 4
    assert node.counters.internal_errors == 0


# --- a second master on the bus ---------------------------------------------------------------


def test_rpdo1_twice_in_a_sync_period_raises_rpdo_conflict() -> None:
    rig = Rig()
    rig.nmt(NmtCommand.START)
    rig.sync()
    for _ in range(3):  # event timer 0 (default): event-driven RPDOs, any number per period
        rig.send(RPDO1, encode_analog_outputs([160, 0]), dt=0.001)
    rig.sync()
    assert rig.node.counters.rpdo_conflicts == 0
    rig.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    assert rig.write(0x1400, 5, (25).to_bytes(2, "little"))[0] == 0x60  # RPDO1 cyclic, as the controller sets it
    rig.nmt(NmtCommand.START)
    out: list[can.Message] = []
    for _ in range(3):  # one RPDO per SYNC period: no conflict
        out += rig.sync()
        out += rig.send(RPDO1, encode_analog_outputs([160, 0]), dt=0.001)
    assert not [e for e in emcys(out) if e[0] == EmcyCode.RPDO_CONFLICT]
    # a lost SYNC (counter gap of 1) allows two RPDOs in that period
    rig.send(RPDO1, encode_analog_outputs([160, 0]), dt=0.001)
    out = rig.sync(counter=rig.sync_counter + 2)
    assert rig.node.counters.rpdo_conflicts == 0 and not emcys(out)
    # a foreign producer at 1 kHz: five RPDOs per period
    for _ in range(5):
        rig.send(RPDO1, encode_analog_outputs([-3200, 0]), dt=0.001)
    out = rig.sync(dt=0.0)
    ((code, register, vendor),) = [e for e in emcys(out) if e[0] == EmcyCode.RPDO_CONFLICT]
    assert register & 0x81 == 0x81 and vendor[0] == 5
    assert rig.node.counters.rpdo_conflicts == 1
    out = []
    for _ in range(CONFLICT_CLEAR_PERIODS):
        rig.send(RPDO1, encode_analog_outputs([160, 0]), dt=0.001)
        out += rig.sync(dt=0.004)
    assert (0, 0, struct.pack("<H", EmcyCode.RPDO_CONFLICT) + b"\x00" * 3) in emcys(out)
    assert rig.node.counters.rpdo_conflicts == 1


def test_a_foreign_sync_stream_does_not_feed_the_watchdog_of_a_frozen_controller() -> None:
    """The controller sends SYNC + RPDO1 each period, then freezes while someone
    else keeps sending SYNC: the missing RPDO1 trips the watchdog (valves to zero,
    EMCY SYNC_TIMEOUT with vendor byte 1 = 1); the controller's next RPDO1 releases it."""
    rig = Rig()
    assert rig.read(0x1400, 5) == 0  # off by default: a master that sets its outputs once keeps them
    assert rig.write(0x1400, 5, (25).to_bytes(2, "little"))[0] == 0x60  # what the controller sets
    rig.nmt(NmtCommand.START)
    assert abort_code(rig.write(0x1400, 5, b"\x00\x00")) == SdoAbortCode.CANNOT_STORE_DEVICE_STATE
    for _ in range(10):
        rig.sync()
        rig.send(RPDO1, encode_analog_outputs([3200, 0]), dt=0.001)
    frozen_at = rig.t
    out: list[can.Message] = []
    for _ in range(10):  # the foreign stream, SYNC without counter, a stock master's
        out += rig.send(SYNC, b"", dt=0.005)
        out += rig.node.poll(rig.t)  # as the runner does after each frame
    assert rig.node.watchdog_tripped and rig.app.watchdog == [True]
    ((code, _, vendor),) = [e for e in emcys(out) if e[0] == EmcyCode.RPDO_TIMEOUT]  # CiA 301 0x8250: this one is an RPDO timeout
    assert vendor[1] == 1 and rig.node.counters.rpdo_timeouts == 1
    assert EmcyCode.SYNC_TIMEOUT not in [e[0] for e in emcys(out)]
    trip = next(f for f in of(out, EMCY) if decode_emcy(f.data).code == EmcyCode.RPDO_TIMEOUT)
    assert 0.025 <= trip.timestamp - frozen_at <= 0.025 + 0.005 + 1e-9  # noticed at the first SYNC past the time
    assert rig.node.outputs_v.tolist() == [0.0, 0.0]
    assert rig.node.counters.sync_conflicts == 1  # and the mixed SYNC forms are reported
    # the controller thaws: its first RPDO1 releases (held), the next applies
    rig.sync()
    assert rig.node.watchdog_tripped
    rig.send(RPDO1, encode_analog_outputs([3200, 0]), dt=0.001)
    assert not rig.node.watchdog_tripped and rig.node.outputs_v.tolist() == [0.0, 0.0]
    rig.sync()
    rig.send(RPDO1, encode_analog_outputs([3200, 0]), dt=0.001)
    assert rig.node.outputs_v[0] == pytest.approx(200 * DAC12.lsb_v)
