"""The restbus (service_kit/can_wire/restbus/) against references it did
not write: the AUTOSAR CRC library's test vectors through crccheck, cantools
decoding what was sent, the bus-load module measuring the simulated bus,
Davis et al.'s analysis (checked against the paper's example in
test_arbitration.py), and the arbitration model's own delivery times."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from crccheck.crc import Crc8Autosar, Crc8SaeJ1850

from protocol import can_map
from service_kit.can_wire.bus_load import bus_load, intervals_from_run
from service_kit.can_wire.restbus.cli import analysis, main
from service_kit.can_wire.restbus.sender import RestbusSender
from service_kit.can_wire.restbus.traffic import (
    NS_PER_MS,
    RestbusError,
    check,
    checksum,
    from_database,
    load,
    nodes_of,
    offered_load,
    rig_cycle,
    rig_identifiers,
    schedule,
    simulate_restbus,
    spread_drift,
)
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "restbus" / "vehicle.dbc"
RESULT = ROOT / "docs" / "results" / "restbus-example.md"
BITRATE = 1_000_000

# AUTOSAR SWS CRC Library, Crc_CalculateCRC8 and Crc_CalculateCRC8H2F check values.
AUTOSAR_VECTORS = [
    ("00000000", 0x59, 0x12),
    ("F20183", 0x37, 0xC2),
    ("0FAA0055", 0x79, 0xC6),
    ("00FF5511", 0xB8, 0x77),
    ("332255AABBCCDDEEFF", 0xCB, 0x11),
    ("926B55", 0x8C, 0x33),
    ("FFFFFFFF", 0x74, 0x6C),
]

HEAD = """VERSION ""
NS_ :
BS_:
BU_: Ecu
"""
DEFS = """BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ SG_ "RestbusRole" STRING ;
BA_DEF_ SG_ "GenSigStartValue" INT 0 100000;
BA_DEF_DEF_ "GenSigStartValue" 0;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "RestbusRole" "";
"""


def _db(body: str, attrs: str) -> cantools.database.Database:
    return cantools.database.load_string(HEAD + body + "\n" + DEFS + attrs, database_format="dbc")


@pytest.fixture(scope="module")
def example() -> object:
    return load(EXAMPLE)


def test_crccheck_gives_the_autosar_check_values() -> None:
    assert Crc8SaeJ1850.calc(b"123456789") == 0x4B
    assert Crc8Autosar.calc(b"123456789") == 0xDF
    for hexdata, j1850, h2f in AUTOSAR_VECTORS:
        data = bytes.fromhex(hexdata)
        assert Crc8SaeJ1850.calc(data) == j1850
        assert Crc8Autosar.calc(data) == h2f


def test_checksum_runs_over_data_id_low_high_then_the_other_bytes() -> None:
    # data ID 0x01F2 (F2, 01) and payload [83, crc]: the CRC's input is F2 01 83, an AUTOSAR vector
    assert checksum("crc8_sae_j1850", 0x01F2, bytes([0x83, 0xEE]), 1) == 0x37
    assert checksum("crc8_h2f", 0x01F2, bytes([0xEE, 0x83]), 0) == 0xC2


def test_example_messages_and_load(example: object) -> None:
    rb = example
    assert rb.not_sent == ("Crash_Event", "OBD_Request")
    # what docs/can-wire.md says of it
    assert (len(rb.messages), len({m.node for m in rb.messages})) == (19, 9)
    assert (sum(m.counter is not None for m in rb.messages), sum(m.checksum is not None for m in rb.messages)) == (6, 4)
    ids = [m.frame_id for m in rb.messages]
    assert min(ids) < can_map.SYNC_COB_ID and max(ids) > can_map.HEARTBEAT_BASE + can_map.DEFAULT_NODE_ID
    load_alone = offered_load(rb, BITRATE)
    assert 0.65 <= load_alone <= 0.75
    assert check(rb, BITRATE, rig=rig_cycle()) == []


def test_offered_load_equals_the_load_measured_on_the_simulated_bus(example: object) -> None:
    """The load from exact frame lengths matches bus_load over a simulated second (no rig)."""
    until = 1000 * NS_PER_MS
    sim = simulate_restbus(example, BITRATE, until)
    report = bus_load(intervals_from_run(sim.run), BITRATE, 100 * NS_PER_MS, start_ns=0, end_ns=until)
    assert not sim.run.unsent and sim.run.id_collisions == 0
    assert report.offered == pytest.approx(offered_load(example, BITRATE), abs=0.003)
    assert report.busy == pytest.approx(offered_load(example, BITRATE), abs=0.003)


def test_rig_identifiers_are_the_can_map_ones() -> None:
    n = can_map.DEFAULT_NODE_ID
    expected = {
        can_map.NMT_COB_ID,
        can_map.SYNC_COB_ID,
        can_map.EMCY_BASE + n,
        can_map.TPDO1_BASE + n,
        can_map.TPDO2_BASE + n,
        can_map.TPDO3_BASE + n,
        can_map.RPDO1_BASE + n,
        can_map.SDO_TX_BASE + n,
        can_map.SDO_RX_BASE + n,
        can_map.HEARTBEAT_BASE + n,
    }
    assert set(rig_identifiers()) == expected
    assert [r.frame.arbitration_id for r in rig_cycle()] == [can_map.SYNC_COB_ID, can_map.TPDO1_BASE + n, can_map.RPDO1_BASE + n]


def test_checks_refuse_bit_rate_load_and_rig_identifiers(example: object) -> None:
    assert check(example, 300_000) == ["unsupported bit rate 300000 bit/s (one of 125000, 250000, 500000, 1000000)"]
    over = check(example, 500_000, rig=rig_cycle())
    assert len(over) == 1 and "above 100 %" in over[0]
    db = _db(
        'BO_ 385 Clash: 8 Ecu\n SG_ A : 0|8@1+ (1,0) [0|255] "" Vector__XXX\nBO_ 386 Fine: 8 Ecu\n SG_ B : 0|8@1+ (1,0) [0|255] "" Vector__XXX\n',
        'BA_ "GenMsgCycleTime" BO_ 385 10;\nBA_ "GenMsgCycleTime" BO_ 386 10;\n',
    )
    problems = check(from_database(db), BITRATE)
    assert problems == ["message Clash uses identifier 0x181, the rig's TPDO1_AnalogInputs16"]


@pytest.mark.parametrize(
    ("signals", "attrs", "message"),
    [
        ('SG_ C : 0|8@1+ (2,0) [0|255] "" Vector__XXX', 'BA_ "RestbusRole" SG_ 16 C "counter";', "factor 1, offset 0"),
        ('SG_ K : 4|8@1+ (1,0) [0|255] "" Vector__XXX', 'BA_ "RestbusRole" SG_ 16 K "crc8_sae_j1850";', "exactly one byte"),
        ('SG_ K : 0|4@1+ (1,0) [0|15] "" Vector__XXX', 'BA_ "RestbusRole" SG_ 16 K "crc8_h2f";', "unsigned 8-bit"),
        ('SG_ K : 0|8@1+ (1,0) [0|255] "" Vector__XXX', 'BA_ "RestbusRole" SG_ 16 K "md5";', "is none of"),
        ('SG_ A : 0|4@1+ (1,0) [0|15] "" Vector__XXX', 'BA_ "GenSigStartValue" SG_ 16 A 300;', "start value 300 is no raw value of 4 unsigned bits"),
        ('SG_ C : 0|4@1+ (1,0) [0|14] "" Vector__XXX', 'BA_ "RestbusRole" SG_ 16 C "counter";\nBA_ "GenSigStartValue" SG_ 16 C 15;', "outside 0..14"),
    ],
)
def test_bad_conventions_are_one_line(signals: str, attrs: str, message: str) -> None:
    db = _db(f"BO_ 16 M: 8 Ecu\n {signals}\n", 'BA_ "GenMsgCycleTime" BO_ 16 10;\n' + attrs + "\n")
    with pytest.raises(RestbusError, match=message) as info:
        from_database(db)
    assert "\n" not in str(info.value)


def test_simulated_response_times_stay_within_the_analysis(example: object) -> None:
    """Restbus + the rig's SYNC/TPDO1/RPDO1 on the arbitration model: no frame takes longer than
    Davis et al.'s bound for the message set, and the highest-priority frames come close to it."""
    rig = rig_cycle()
    bound = analysis(example, BITRATE, rig)
    sim = simulate_restbus(example, BITRATE, 500 * NS_PER_MS, rig=rig, drift_ppm=spread_drift(nodes_of(example, rig), 200))
    assert not sim.run.unsent
    worst: dict[str, int] = {}
    for tx in sim.run.transmissions:
        name = sim.names[tx.index]
        assert tx.response_ns <= bound[name], name
        worst[name] = max(worst.get(name, 0), tx.response_ns)
    assert set(worst) == set(bound)
    for name in ("ESP_WheelSpeeds", "EPS_Steering"):  # the two highest priorities
        assert worst[name] >= 0.85 * bound[name], (name, worst[name], bound[name])


class _FakeClock:
    """An injected clock: waiting moves it at once."""

    def __init__(self) -> None:
        self.t = 1_000_000_000

    def now(self) -> int:
        return self.t

    def wait_until(self, t_ns: int) -> bool:
        self.t = max(self.t, t_ns)
        return True


def test_virtual_bus_frames_decode_to_the_schedule(example: object) -> None:
    """Frames on a python-can bus, decoded by cantools: start values, counters rolling,
    checksums valid by crccheck, periods on the injected clock equal the cycle times."""
    db = cantools.database.load_file(str(EXAMPLE))
    clock = _FakeClock()
    until = 60 * NS_PER_MS
    with (
        can.Bus(interface="virtual", channel="restbus-test", receive_own_messages=False) as tx_bus,
        can.Bus(interface="virtual", channel="restbus-test") as rx_bus,
    ):
        sender = RestbusSender(tx_bus, example, clock_ns=clock.now, wait_until=clock.wait_until, until_ns=until)
        n = sender.run()
        received = []
        while (msg := rx_bus.recv(timeout=0)) is not None:
            received.append(msg)
    assert n == len(received) == sum(-(-(until - m.offset_ns) // m.cycle_ns) for m in example.messages)
    by_name: dict[str, list[tuple[int, dict[str, float]]]] = {}
    for s, msg in zip(sender.sent, received, strict=True):
        assert msg.arbitration_id == s.msg.arbitration_id and bytes(msg.data) == bytes(s.msg.data)
        message = db.get_message_by_frame_id(msg.arbitration_id)
        decoded = message.decode(bytes(msg.data), decode_choices=False, scaling=False)
        by_name.setdefault(message.name, []).append((s.time_ns, decoded))
        role = {sig.name: sig.dbc.attributes["RestbusRole"].value for sig in message.signals if "RestbusRole" in sig.dbc.attributes}
        for sig in message.signals:
            if sig.name not in role:
                assert decoded[sig.name] == (sig.raw_initial or 0), (message.name, sig.name)
            elif role[sig.name].startswith("crc8"):
                data = bytes(msg.data)
                data_id = message.dbc.attributes["RestbusDataId"].value
                crc = {"crc8_sae_j1850": Crc8SaeJ1850, "crc8_h2f": Crc8Autosar}[role[sig.name]]
                assert data[0] == crc.calc(bytes([data_id & 0xFF, data_id >> 8]) + data[1:]), message.name
    for m in example.messages:
        seq = by_name[m.name]
        times = [t for t, _ in seq]
        assert times[0] == m.offset_ns
        assert {b - a for a, b in zip(times, times[1:], strict=False)} <= {m.cycle_ns}
        if m.counter is not None:
            lo, hi = m.counter_range
            counts = [int(d[m.counter]) for _, d in seq]
            assert counts[0] == int(m.raw_values[m.counter])
            assert all(b == (a + 1 if a < hi else lo) for a, b in zip(counts, counts[1:], strict=False))
    assert max(len(s) for s in by_name.values()) >= 20  # the 4-bit counters wrapped


def test_ralfwire_deliveries_equal_the_simulated_back_end(example: object) -> None:
    """The same schedule on ralfwire (manual clock) and on simulate(): same frames, same end times."""
    clock = ManualWireClock()
    until = 20 * NS_PER_MS

    def wait_until(t: int) -> bool:
        clock.advance_to(t)
        return True

    with (
        WireBus(channel="restbus-wire", bitrate=BITRATE, clock=clock) as tx_bus,
        WireBus(channel="restbus-wire", bitrate=BITRATE, clock=clock) as rx_bus,
    ):
        sender = RestbusSender(tx_bus, example, clock_ns=clock.now_ns, wait_until=wait_until, until_ns=until)
        sender.run()
        while (t := clock.next_event_ns()) is not None:
            clock.advance_to(t)
        received = []
        while (msg := rx_bus.recv(timeout=0)) is not None:
            received.append(msg)
    sim = simulate_restbus(example, BITRATE, until)
    expected = [(tx.arbitration_id, tx.last_bit_ns) for tx in sim.run.transmissions]
    assert [(m.arbitration_id, round(m.timestamp * 1e9)) for m in received] == expected


def test_real_time_sender_is_bounded_and_stops(example: object) -> None:
    with can.Bus(interface="virtual", channel="restbus-rt") as bus:
        bounded = RestbusSender(bus, example, max_frames=25, until_ns=10_000 * NS_PER_MS)
        assert bounded.run() == 25
        endless = RestbusSender(bus, example)
        endless.start()
        assert endless.running
        endless.stop(timeout=10.0)
        assert not endless.running
        assert endless.send_errors == 0


def test_schedule_is_in_time_order_with_offsets(example: object) -> None:
    inst = list(schedule(example.messages, 20 * NS_PER_MS))
    assert [i.time_ns for i in inst] == sorted(i.time_ns for i in inst)
    chassis = [i.time_ns for i in inst if i.message.name == "Chassis_Height"]
    assert chassis == [3 * NS_PER_MS, 13 * NS_PER_MS]


def test_generated_table_is_up_to_date(monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/results/restbus-example.md is what the CLI writes (its figures are measured, not typed)."""
    monkeypatch.chdir(ROOT)
    assert RESULT.read_text(encoding="utf-8").count("| ESP_WheelSpeeds | 0x020 |") == 1
    assert main([str(EXAMPLE.relative_to(ROOT)), "--bitrate", str(BITRATE), "--check", str(RESULT)]) == 0


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--bitrate", "300000"], "unsupported bit rate 300000"),
        (["--bitrate", "500000"], "above 100 %"),
    ],
)
def test_cli_refuses_with_one_line(args: list[str], expected: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "service_kit.can_wire.restbus", str(EXAMPLE), *args], capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and expected in proc.stderr and "Traceback" not in proc.stderr


def test_cli_refuses_a_file_that_is_not_a_dbc(tmp_path: Path) -> None:
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a DBC\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "service_kit.can_wire.restbus", str(bad), "--bitrate", "1000000"], capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "not a DBC" in proc.stderr and "Traceback" not in proc.stderr


def test_cli_sends_on_a_virtual_bus_for_a_bounded_time() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "service_kit.can_wire.restbus", str(EXAMPLE), "--bitrate", "1000000", "--send", "--seconds", "0.05"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("restbus: ") and "frames sent" in proc.stdout


def test_cli_sends_on_the_rig_bus_from_its_settings() -> None:
    env = {**os.environ, "RALF_CAN_INTERFACE": "virtual", "RALF_CAN_CHANNEL": "restbus-rig"}
    cmd = [sys.executable, "-m", "service_kit.can_wire.restbus", str(EXAMPLE), "--bitrate", "1000000", "--send", "--rig-bus", "--seconds", "0.02"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "frames sent" in proc.stdout
    env["RALF_CAN_INTERFACE"] = "no_such_interface"
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "cannot open the rig's bus" in proc.stderr
