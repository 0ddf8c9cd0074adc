"""The node's entry points that promise the same frames: the co-simulation's
direct wire (``exchange``, ``poll_frames``, ``own_cob_frame``) and the bus
path (``handle`` + ``poll``), on random traffic; the node's process data as an
SDO client reads it back; the application's codes as lists, arrays or floats
against the converter's quantization."""

from __future__ import annotations

import struct
from typing import Any

import can
import numpy as np
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig
from plant_emulator.canopen_node.frames import Frame
from protocol.can_map import ConverterScale, NmtCommand, decode_analog_inputs_16, encode_nmt
from tests.plant.support import FakeApp

TPDO1 = 0x181


class _ListApp(FakeApp):
    """The same plant stand-in handing its codes as lists (as the plant service does)."""

    def on_sync(self, counter: int) -> tuple[list[int], list[bool]]:  # type: ignore[override]
        codes, sat = super().on_sync(counter)
        return codes.tolist(), sat.tolist()


class _FloatListApp(FakeApp):
    def on_sync(self, counter: int) -> tuple[list[float], list[bool]]:  # type: ignore[override]
        codes, sat = super().on_sync(counter)
        return [float(c) + 0.25 for c in codes.tolist()], sat.tolist()


def _tpdos(app: FakeApp, bits: int = 12) -> list[tuple[int, bytes]]:
    app.bits = bits
    node = CanopenNode(app)
    node.handle(can.Message(arbitration_id=0, data=encode_nmt(NmtCommand.START, 1), is_extended_id=False), 0.0)
    out = []
    for k in range(1, 6):
        app.saturated = np.array([k % 2 == 0, False, k == 3, False])
        frames = node.handle(can.Message(arbitration_id=0x80, data=bytes([k]), is_extended_id=False), 0.005 * k)
        out += [(f.arbitration_id, bytes(f.data)) for f in frames]
    return out


def test_the_node_takes_list_codes_as_it_takes_arrays() -> None:
    volts = (1.0, -2.5, 9.99, -10.0)
    reference = _tpdos(FakeApp(volts))
    assert _tpdos(_ListApp(volts)) == reference
    assert {cob for cob, _ in reference} == {TPDO1, 0x81}  # TPDO1s and the saturation EMCYs
    # floats in a list are not codes: the general path rounds them (+0.25 rounds away)
    assert _tpdos(_FloatListApp(volts)) == reference
    words = decode_analog_inputs_16(next(data for cob, data in reference if cob == TPDO1))
    np.testing.assert_array_equal(words >> 4, ConverterScale(12).quantize(np.array(volts)).counts)


def _random_traffic(seed: int, n: int) -> list[tuple[float, int, bytes]]:
    """Frames a master (and a few rogue stations) might send, with their times:
    NMT commands, SYNC with and without counter (gaps, repeats), RPDO1 words
    inside and beyond the valve limit, wrong lengths, SDO reads and writes of
    the configuration (0x1017, 0x2002, 0x2003, 0x1400 sub 5, 0x2001, 0x6411),
    TIME, foreign and unknown COB-IDs; time steps that let the heartbeat and
    the watchdog fire."""
    rng = np.random.default_rng(seed)
    t = 0.0
    counter = 0
    out: list[tuple[float, int, bytes]] = [(0.0, 0x000, bytes([0x01, 1]))]
    sdo_writes = [
        (0x1017, 0, 2, [20, 50, 0]),
        (0x2002, 0, 4, None),
        (0x2003, 0, 2, [3, 5, 0]),
        (0x1400, 5, 2, [0, 15, 40]),
        (0x2001, 0, 1, [12, 16, 20]),
        (0x6411, 1, 2, [0x1230, -0x7000 & 0xFFFF]),
        (0x1003, 0, 1, [0]),
    ]
    for _ in range(n):
        t += float(rng.choice([0.0, 0.001, 0.005, 0.005, 0.005, 0.012, 0.04, 0.2]))
        r = rng.random()
        if r < 0.45:
            counter = counter % 240 + 1 if rng.random() > 0.05 else int(rng.integers(1, 241))
            out.append((t, 0x080, bytes([counter]) if rng.random() > 0.03 else b""))
        elif r < 0.85:
            words = rng.integers(-32768, 32768, 2)
            if rng.random() < 0.5:
                words = (rng.integers(-2048, 2048, 2) << 4) // int(rng.choice([1, 1, 4]))
            data = struct.pack("<2h", *(int(w) for w in words))
            out.append((t, 0x201, data if rng.random() > 0.03 else data[:3]))
        elif r < 0.9:
            index, sub, size, choices = sdo_writes[int(rng.integers(len(sdo_writes)))]
            if index == 0x2002:
                payload = struct.pack("<f", float(rng.choice([10.0, 4.5, 2.0, 0.0])))
            else:
                value = int(rng.choice(choices))  # type: ignore[arg-type]
                payload = value.to_bytes(size, "little", signed=False)
            cmd = 0x23 | ((4 - size) << 2)
            out.append((t, 0x601, struct.pack("<BHB", cmd, index, sub) + payload.ljust(4, b"\x00")))
        elif r < 0.93:
            out.append((t, 0x601, struct.pack("<BHB4x", 0x40, int(rng.choice([0x6401, 0x6402, 0x6411, 0x1001, 0x2010])), int(rng.integers(0, 5)))))
        elif r < 0.96:
            cmd = int(rng.choice([0x01, 0x01, 0x01, 0x01, 0x02, 0x80, 0x81, 0x82, 0x7F]))
            out.append((t, 0x000, bytes([cmd, int(rng.choice([0, 1, 1, 9]))])))
        else:
            out.append((t, int(rng.choice([0x100, 0x182, 0x181, 0x7E5, 0x2A1, 0x301])), bytes(rng.integers(0, 256, int(rng.integers(0, 9))).tolist())))
    return out


def _as_tuples(frames: list[Any]) -> list[tuple[int, bytes, float]]:
    return [(f.arbitration_id, bytes(f.data), f.timestamp) for f in frames]


def _od_values(node: CanopenNode) -> dict[tuple[int, int], Any]:
    return {(e.index, e.sub): node.od.get(e.index, e.sub) for e in node.od}


@pytest.mark.parametrize("seed", range(6))
def test_exchange_is_handle_then_poll(seed: int) -> None:
    traffic = _random_traffic(seed, 700)
    apps = (FakeApp(), FakeApp(), FakeApp())
    cfg = NodeConfig(heartbeat_ms=20, watchdog_periods=3 if seed % 2 else 5)
    general, direct, quick = (CanopenNode(app, cfg) for app in apps)
    out_general = _as_tuples(general.poll(0.0))
    out_direct = _as_tuples(direct.poll_frames(0.0))
    out_quick = _as_tuples(quick.poll(0.0))
    for t, cob_id, data in traffic:
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        out_general += _as_tuples(general.handle(msg, t) + general.poll(t))
        out_direct += _as_tuples(direct.exchange(cob_id, bytearray(data), t))
        out_quick += _as_tuples(quick.handle(msg, t) + quick.poll(t))
        assert direct.next_deadline() == quick.next_deadline() == general.next_deadline()  # the quiet time, or worked out afresh
        for dt in (0.003, 0.011) if seed % 3 == 0 else ():  # the timers between frames too
            out_general += _as_tuples(general.poll(t + dt))
            out_direct += _as_tuples(direct.poll_frames(t + dt))
            out_quick += _as_tuples(quick.poll(t + dt))
    assert out_direct == out_general
    assert out_quick == out_general
    for node, app in ((direct, apps[1]), (quick, apps[2])):
        assert node.counters.as_dict() == general.counters.as_dict()
        assert _od_values(node) == _od_values(general)
        assert [o.tolist() for o in app.outputs] == [o.tolist() for o in apps[0].outputs]
        assert node.state == general.state and node.watchdog_tripped == general.watchdog_tripped
        np.testing.assert_array_equal(node.outputs_v, general.outputs_v)
    # the traffic reached the places it is meant to test
    c = general.counters
    assert c.samples > 30 and c.outputs_applied > 30 and c.clipped_outputs > 0 and c.tx["heartbeat"] > 5 and c.malformed_total > 0
    assert c.sdo.downloads > 5 and c.tx["emcy"] > 3
    if seed % 2:
        assert c.watchdog_trips > 0


def test_frames_read_like_python_can_messages() -> None:
    node = CanopenNode(FakeApp())
    node.exchange(0x000, bytes([0x01, 1]), 0.0)
    (tpdo,) = node.exchange(0x080, bytes([1]), 0.005)
    msg = tpdo.to_message()
    assert isinstance(msg, can.Message) and msg.arbitration_id == tpdo.arbitration_id == TPDO1
    assert bytes(msg.data) == tpdo.data and msg.dlc == tpdo.dlc == 8 and msg.timestamp == tpdo.timestamp == 0.005
    for flag in ("is_extended_id", "is_remote_frame", "is_error_frame", "is_fd"):
        assert getattr(tpdo, flag) is False is getattr(msg, flag)
    assert tpdo == Frame(TPDO1, tpdo.data, 0.005) and tpdo != Frame(TPDO1, tpdo.data, 0.01)
    assert "0x181" in repr(tpdo)


def _sdo_read(node: CanopenNode, index: int, sub: int, t: float) -> int:
    (reply,) = (f for f in node.exchange(0x601, struct.pack("<BHB4x", 0x40, index, sub), t) if f.arbitration_id == 0x581)
    assert reply.data[0] & 0xE3 == 0x43, reply
    n = 4 - ((reply.data[0] >> 2) & 3)
    return int.from_bytes(reply.data[4 : 4 + n], "little", signed=True)


def test_process_data_reads_back_by_sdo_and_resets_with_the_node() -> None:
    """0x6401/0x6402/0x6411, kept by the node and served to SDO: the last
    sample's words and the last RPDO's, the table's defaults after
    RESET_NODE, unchanged by RESET_COMMUNICATION (which resets 0x1000-0x1FFF only)."""
    app = FakeApp((1.0, -2.5, 9.99, -10.0))
    app.bits = 20
    node = CanopenNode(app, NodeConfig(adc_bits=20))
    defaults = {(i, s): _sdo_read(node, i, s, 0.0) for i, s in ((0x6401, 1), (0x6402, 3), (0x6411, 2))}
    node.exchange(0x000, bytes([0x01, 1]), 0.0)
    frames = node.exchange(0x080, bytes([1]), 0.005)
    tpdo1 = decode_analog_inputs_16(next(f.data for f in frames if f.arbitration_id == TPDO1))
    codes = ConverterScale(20).quantize(np.array(app.volts)).counts
    node.exchange(0x201, struct.pack("<2h", 0x1230, -0x7000), 0.006)
    outputs = [0x1230, -0x7000]
    for t in (0.007, 0.008):
        assert [_sdo_read(node, 0x6401, s, t) for s in range(1, 5)] == tpdo1.tolist() == (codes >> 4).tolist()
        assert [_sdo_read(node, 0x6402, s, t) for s in range(1, 5)] == (codes << 12).tolist()
        assert [_sdo_read(node, 0x6411, s, t) for s in (1, 2)] == outputs
        node.exchange(0x000, bytes([0x82, 1]), t)  # RESET_COMMUNICATION: the inputs stay,
        outputs = [0, 0]  # the outputs go to 0 V as the node leaves OPERATIONAL
    node.exchange(0x000, bytes([0x81, 1]), 0.01)  # RESET_NODE: every object to its default
    assert {(i, s): _sdo_read(node, i, s, 0.011) for i, s in defaults} == defaults


def test_a_poll_sees_a_dictionary_changed_behind_its_back() -> None:
    """The heartbeat period written straight into the object dictionary (no
    frame through the node) restarts the heartbeat at the next poll: one
    period (20 ms) from that poll, then every 20 ms, each beat at the first
    poll at or after its time."""
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=100))
    frames = node.poll_frames(0.0) + node.poll_frames(0.01)
    node.od.write(0x1017, 0, (20).to_bytes(2, "little"))
    for k in range(2, 60):
        frames += node.poll_frames(0.005 * k)
    beats = [f.timestamp for f in frames if f.arbitration_id == 0x701 and f.data != bytes([0])]
    due = [0.03 + 0.02 * n for n in range(14)]  # 20 ms from the poll that saw the write, on a 5 ms poll grid
    assert len(beats) == len(due) and all(-1e-9 < b - d < 0.005 + 1e-9 for b, d in zip(beats, due, strict=True)), beats


@pytest.mark.parametrize("echoes", [True, False], ids=["echoing-bus", "quiet-bus"])
def test_the_runners_own_cob_id_shortcut_is_what_handle_does(echoes: bool) -> None:
    """The runner's shortcut for frames on our own COB-IDs (node.own_cob_frame) leaves the node
    as handle + poll leave it, and sends the same frames: echoes of what it sent counted as
    such (a bus that hands them back), anything else as impersonation with EMCY 0x8150."""
    handled, counted = CanopenNode(FakeApp()), CanopenNode(FakeApp())
    for node in (handled, counted):
        node.expect_echoes(echoes)
        node.exchange(0x000, bytes([0x01, 1]), 0.0)
        sent = node.exchange(0x080, bytes([1]), 0.005)
    assert handled.own_cob_ids == frozenset({0x81, 0x181, 0x281, 0x381, 0x581, 0x701})
    ours = [(f.arbitration_id, f.data) for f in sent]
    others = [(cob_id, bytes(8)) for cob_id in sorted(handled.own_cob_ids)]
    for k, (cob_id, data) in enumerate(ours + others):
        t = 0.006 + 0.0001 * k
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        by_handle = [(m.arbitration_id, bytes(m.data)) for m in handled.handle(msg, t) + handled.poll(t)]
        by_runner = [(f.arbitration_id, f.data) for f in counted.own_cob_frame(cob_id, data, t)] + [(m.arbitration_id, bytes(m.data)) for m in counted.poll(t)]
        assert by_runner == by_handle
        assert counted.counters.as_dict() == handled.counters.as_dict()
        assert counted.next_deadline() == handled.next_deadline()
    assert counted.counters.rx["own_cob_id"] == (len(ours) if echoes else 0)
    assert counted.counters.impersonated_total == len(others) + (0 if echoes else len(ours))
