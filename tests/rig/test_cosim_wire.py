"""The co-simulation on the simulated CAN wire (workbench/cosim_wire.py): off by
default, deterministic, wire times against the frame model's bits, bus load
against the restbus's offered load, late TPDO1s held, bad settings refused."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from plant_emulator.service import PlantApplication
from protocol import can_map
from protocol.errors import ConfigError
from protocol.settings import CAN_BITRATES, PlantSettings
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.restbus import traffic
from service_kit.can_wire.timing import STANDARD_BITRATES
from service_kit.can_wire.worst_case import longest_frame, shortest_frame
from service_kit.transport import TransportError, open_can_bus
from workbench.cosim import DirectCanWire, run_cosim
from workbench.cosim_wire import TimedCanWire

ROOT = Path(__file__).resolve().parents[2]
RESTBUS_50 = ROOT / "examples" / "restbus" / "vehicle-50pct-1000k.dbc"
CONTROLLER = {"duration_s": 2.0, "tf_download_samples": 0}


def _run(common: dict[str, Any] | None = None, **kw: Any) -> Any:
    return run_cosim(controller=dict(CONTROLLER), common=common, **kw)


def _columns(run: Any) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in run.controller.record.to_columns().items()}


def test_the_wire_is_off_by_default_and_the_direct_wire_stays() -> None:
    run = _run()
    assert run.can_bus is None
    assert type(run.controller.plant.bus) is DirectCanWire
    wired = _run({"can_bitrate": 1_000_000})
    assert type(wired.controller.plant.bus) is TimedCanWire
    assert wired.can_bus is not None and wired.result.error is None and wired.result.ticks == 400


def test_wired_runs_with_a_restbus_are_bit_identical() -> None:
    common = {"can_bitrate": 1_000_000, "can_restbus": str(RESTBUS_50)}
    a, b = _run(common), _run(common)
    ca, cb = _columns(a), _columns(b)
    assert ca.keys() == cb.keys()
    for name in ca:
        assert np.array_equal(ca[name], cb[name], equal_nan=True), name
    assert a.can_bus == b.can_bus


def test_sync_to_tpdo1_never_below_its_wire_time_at_1_mbit() -> None:
    """SYNC queued to TPDO1's last bit: at least the SYNC's bits (the TPDO1 starts once the bus is
    idle) plus the shortest TPDO1's bits to its EOF, at 1 us a bit; without a restbus at most the longest."""
    sync = frame_bits(can_map.SYNC_COB_ID, can_map.encode_sync(1))
    sync_bits = {frame_bits(can_map.SYNC_COB_ID, can_map.encode_sync(c)).n_bits for c in range(1, 241)}
    tpdo1 = can_map.cob_ids(1)["tpdo1"]
    floor_us = min(sync_bits) + shortest_frame(tpdo1, 8).n_bits - 3
    ceiling_us = max(sync_bits) + longest_frame(tpdo1, 8).n_bits - 3
    assert sync.n_bits in sync_bits
    quiet = _run({"can_bitrate": 1_000_000}).can_bus
    assert floor_us <= quiet["sync_to_tpdo1_us"]["min"] <= quiet["sync_to_tpdo1_us"]["p50"] <= ceiling_us
    loaded = _run({"can_bitrate": 1_000_000, "can_restbus": str(RESTBUS_50)}).can_bus
    assert loaded["sync_to_tpdo1_us"]["min"] >= floor_us
    assert loaded["sync_to_tpdo1_us"]["p50"] > quiet["sync_to_tpdo1_us"]["p50"]  # the restbus delays the cycle


def test_busy_share_matches_the_offered_load_of_the_restbus_and_the_rig() -> None:
    """The wire's measured busy share against the long-run load computed from the DBC (cantools'
    payloads, exact frame lengths, cycle times) and the rig's own cycle: within a percentage point
    (heartbeats and the TPDO1 payloads' stuff bits are the difference)."""
    bus = _run({"can_bitrate": 1_000_000, "can_restbus": str(RESTBUS_50)}).can_bus
    offered = traffic.offered_load(traffic.load(RESTBUS_50), 1_000_000, rig=traffic.rig_cycle())
    assert bus["busy_mean_pct"] == pytest.approx(100 * offered, abs=1.0)
    assert bus["busy_max_pct"] >= bus["busy_mean_pct"]
    assert bus["queuing_delay_us"]["0x080"]["n"] == 400


BLOCKERS = """VERSION ""

NS_ :

BS_:

BU_: Blocker

BO_ 16 Block_A: 8 Blocker
 SG_ A : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 17 Block_B: 8 Blocker
 SG_ B : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 18 Block_C: 8 Blocker
 SG_ C : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 16 10;
BA_ "GenMsgCycleTime" BO_ 17 10;
BA_ "GenMsgCycleTime" BO_ 18 10;
"""


def test_a_tpdo1_after_its_deadline_holds_the_last_sample(tmp_path: Path) -> None:
    """At 125 kbit/s three 8-byte frames that beat SYNC every other period delay its TPDO1 past
    0.8 of the 5 ms period: those ticks hold the last sample (the same deflections again)."""
    dbc = tmp_path / "blockers.dbc"
    dbc.write_text(BLOCKERS)
    run = _run({"can_bitrate": 125_000, "can_restbus": str(dbc)})
    bus = run.can_bus
    assert run.result.error is None
    # the blockers start with the first SYNC, every 10 ms: the TPDO1s of ticks 0, 2, 4, ... are late
    assert bus["late_tpdo1"] == 200
    assert bus["sync_to_tpdo1_us"]["max"] > 4000 > bus["sync_to_tpdo1_us"]["min"]
    cols = _columns(run)
    d = np.column_stack([cols["defl1_in"], cols["defl2_in"]])
    held = np.flatnonzero(np.all(d[1:] == d[:-1], axis=1)) + 1
    assert held.tolist() == list(range(2, 400, 2))  # tick 0 holds the start's sample: no row before it


def test_the_plant_model_advances_to_each_arrival_never_back() -> None:
    app = PlantApplication(PlantSettings(clock="lockstep"))
    app.wire_arrival_ns = 6_000_000
    app.on_sync(1)
    assert app.arm.time_s == pytest.approx(0.006, abs=1e-12)
    app.wire_arrival_ns = 7_000_000
    app.on_output_values(1.0, -1.0)
    assert app.arm.time_s == pytest.approx(0.007, abs=1e-12)
    app.wire_arrival_ns = 6_500_000  # a frame arriving on an earlier sub-step adds nothing
    app.on_output_values(0.0, 0.0)
    assert app.arm.time_s == pytest.approx(0.007, abs=1e-12)
    app.wire_arrival_ns = None
    app.on_sync(2)  # no wire: one sample period per SYNC, as before
    assert app.arm.time_s == pytest.approx(0.012, abs=1e-12)


def test_the_bit_rates_are_the_wire_models() -> None:
    assert CAN_BITRATES == STANDARD_BITRATES


@pytest.mark.parametrize(
    ("common", "expected"),
    [
        ({"can_bitrate": 400_000}, "0 (no wire) or one of 125000, 250000, 500000, 1000000"),
        ({"can_restbus": str(RESTBUS_50)}, "needs RALF_CAN_BITRATE"),
        ({"can_bitrate": 500_000, "can_restbus": str(ROOT / "examples" / "restbus" / "vehicle.dbc")}, "above 100 %"),
    ],
)
def test_bad_wire_settings_are_refused_in_one_line(common: dict[str, Any], expected: str) -> None:
    with pytest.raises(ConfigError) as err:
        _run(common)
    lines = [line for line in str(err.value).splitlines() if expected in line]
    assert len(lines) == 1 and ("RALF_CAN_" in lines[0] or "can_restbus" in lines[0])  # the setting named on its line


def test_a_restbus_on_the_rigs_identifiers_or_unparsable_is_refused(tmp_path: Path) -> None:
    clash = tmp_path / "clash.dbc"
    clash.write_text(BLOCKERS.replace("BO_ 17 ", "BO_ 385 ").replace("BO_ 17 10", "BO_ 385 10"))  # 0x181: TPDO1 of node 1
    with pytest.raises(ConfigError, match=r"clash\.dbc: message Block_B uses identifier 0x181"):
        _run({"can_bitrate": 1_000_000, "can_restbus": str(clash)})
    broken = tmp_path / "broken.dbc"
    broken.write_text("BO_ this is no DBC\n")
    with pytest.raises(ConfigError, match=r"broken\.dbc"):
        _run({"can_bitrate": 1_000_000, "can_restbus": str(broken)})


def test_real_time_and_processes_refuse_the_wire() -> None:
    from workbench.composition import run_in_process
    from workbench.hil import HilRig, RigSettingError

    with pytest.raises(ValueError, match="needs simulated time"):
        run_in_process(controller={"duration_s": 0.1}, common={"can_bitrate": 500_000, "clock": "realtime"})
    with pytest.raises(RigSettingError, match="simulated time in one process"):
        HilRig(clock="lockstep", processes=True, common={"can_bitrate": 500_000})
    with pytest.raises(RigSettingError, match="simulated time in one process"):
        HilRig(clock="realtime", common={"can_bitrate": 500_000})
    with pytest.raises(TransportError, match="a bus of one service alone carries frames in no wire time"):
        open_can_bus(PlantSettings(can_interface="virtual", can_bitrate=500_000))


def test_late_tpdo1s_are_the_same_in_the_one_process_lockstep_rig(tmp_path: Path) -> None:
    """The blockers at 125 kbit/s on the wire between two threads: the same late ticks, the same record."""
    from workbench.composition import run_in_process

    dbc = tmp_path / "blockers.dbc"
    dbc.write_text(BLOCKERS)
    common = {"can_bitrate": 125_000, "can_restbus": str(dbc)}
    cosim = _run(common)
    one = run_in_process(controller=dict(CONTROLLER), common=common)
    assert one.result.error is None and one.can_bus is not None
    assert one.can_bus == cosim.can_bus and one.can_bus["late_tpdo1"] == 200
    a, b = _columns(cosim), _columns(one)
    for name in a:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_the_bench_item_prices_the_wire_per_frame() -> None:
    from workbench.bench.entries import BenchContext
    from workbench.bench.items import run_item

    result = run_item("can-wire", BenchContext(quick=True))
    assert result["status"] == "ok", result["errors"]
    m = result["measurements"]
    assert m["no wire: cpu per tick"]["value"] > 0
    wired = m["wire 1 Mbit/s + 50 % restbus: cpu per tick"]
    assert wired["floor"] == "no wire" and wired["ratio"] is not None
    per_frame = m["wire 1 Mbit/s + 50 % restbus: wire cost per frame"]
    assert per_frame["frames"] > 5 * 4000  # 5 s at about 4900 frames/s


def test_a_wire_whose_delays_stay_inside_the_first_sub_step_changes_no_sample() -> None:
    """At 1 Mbit/s without restbus SYNC arrives 56 us and RPDO1 about 0.26 ms after the SYNC's queueing:
    both round to the SYNC's own grid point, so the record equals the direct wire's bit for bit; at
    125 kbit/s the RPDO1 (about 2 ms) reaches later sub-steps and the valves act later: the record differs."""
    direct = _columns(_run())
    fast = _run({"can_bitrate": 1_000_000})
    assert fast.can_bus["sync_to_rpdo1_us"]["max"] < 500
    for name, values in _columns(fast).items():
        assert np.array_equal(values, direct[name], equal_nan=True), name
    slow = _run({"can_bitrate": 125_000})
    assert slow.can_bus["sync_to_rpdo1_us"]["min"] > 1500
    assert not np.array_equal(_columns(slow)["defl1_in"], direct["defl1_in"])


def test_the_figures_reach_the_run_record_its_summary_and_the_recording(tmp_path: Path) -> None:
    from workbench.hil import HilRig
    from workbench.recording.reader import Recording

    wired = HilRig(clock="cosim", common={"can_bitrate": 500_000}, mcap=tmp_path / "wired.mcap", duration_s=1.0).run()
    assert wired.can_bus is not None and wired.can_bus["bitrate"] == 500_000
    assert "CAN 500 kbit/s busy" in wired.summary() and wired.run_facts()["can_bus"] == wired.can_bus
    recorded = Recording.load(tmp_path / "wired.mcap", only=("can/bus_load",)).data("can/bus_load")
    assert recorded == [wired.can_bus]
    plain = HilRig(clock="cosim", mcap=tmp_path / "plain.mcap", duration_s=1.0).run()
    assert plain.can_bus is None and "CAN" not in plain.summary() and "can_bus" not in plain.run_facts()
    assert Recording.load(tmp_path / "plain.mcap").data("can/bus_load") == []
    one = HilRig(clock="lockstep", common={"can_bitrate": 500_000}, duration_s=1.0).run()
    assert one.layout == "one process" and one.can_bus is not None
    assert one.can_bus == wired.can_bus  # the same frames on the wire between two threads
