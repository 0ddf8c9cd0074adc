"""``ralf-hil up --can-bitrate/--restbus`` (workbench/rig_wire.py): refusals
before anything starts, and a rig on the wire arbiter (in .ci/loopback-netns)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from workbench.cli import main
from workbench.rig_wire import summary_rows, wire_request

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "restbus" / "vehicle.dbc"


def _refused(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    code = main(["up", "--duration", "1", *argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_bad_bit_rate_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert "unsupported CAN bit rate 300000" in _refused(capsys, ["--can-bitrate", "300000"])


def test_restbus_without_a_wire_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert "--restbus needs a wire" in _refused(capsys, ["--restbus", str(EXAMPLE)])


def test_restbus_load_above_100_percent_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert "above 100 %" in _refused(capsys, ["--can-bitrate", "500000", "--restbus", str(EXAMPLE)])


def test_restbus_that_does_not_parse_is_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a DBC\n", encoding="utf-8")
    assert "not a DBC" in _refused(capsys, ["--can-bitrate", "1000000", "--restbus", str(bad)])


def test_restbus_on_the_rigs_identifier_is_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    clash = tmp_path / "clash.dbc"
    clash.write_text(text.replace(" 1824 ", " 385 ").replace(" 1824;", " 385;"), encoding="utf-8")
    assert "0x181, the rig's TPDO1" in _refused(capsys, ["--can-bitrate", "1000000", "--restbus", str(clash)])


def test_the_setting_asks_for_the_wire(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("RALF_CAN_BITRATE", "250001")
    assert "unsupported CAN bit rate 250001" in _refused(capsys, [])
    monkeypatch.delenv("RALF_CAN_BITRATE")
    assert wire_request(None, None, {"controller": {"RALF_CAN_BITRATE": "250000"}}, "realtime") is not None
    assert wire_request(None, None, {}, "realtime") is None  # off by default
    overrides: dict[str, dict[str, str]] = {"plant": {}, "controller": {}}
    assert wire_request(1_000_000, None, overrides, "cosim") is None  # the co-simulation's own simulated wire
    assert all(env["RALF_CAN_BITRATE"] == "1000000" for env in overrides.values())


LIGHT_DBC = """VERSION ""

NS_ :

BS_:

BU_: ESP BMS

BO_ 32 WheelSpeeds: 8 ESP
 SG_ Speed : 0|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX

BO_ 768 BmsCurrent: 4 BMS
 SG_ Current : 0|16@1- (0.1,0) [-3276.8|3276.7] "A" Vector__XXX

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 32 10;
BA_ "GenMsgCycleTime" BO_ 768 20;
"""
"""Two cyclic messages, one above and one below the rig's identifiers in priority (a light load)."""


def test_a_rig_runs_on_the_wire_with_the_restbus(tmp_path: Path) -> None:
    """Three services, the recorder's tap and the restbus on one arbiter at 1 Mbit/s (lockstep: no verdict on the host's timing)."""
    summary_path, record, dbc = tmp_path / "up.json", tmp_path / "run.mcap", tmp_path / "light.dbc"
    dbc.write_text(LIGHT_DBC, encoding="utf-8")
    cmd = [sys.executable, "-m", "workbench", "up", "--duration", "2", "--clock", "lockstep", "--rig-id", f"wire{os.getpid()}", "--can-bitrate", "1000000"]
    cmd += ["--restbus", str(dbc), "--json", str(summary_path), "--record", str(record)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "CAN wire at 1000000 bit/s (ralfhub " in proc.stdout
    summary = json.loads(summary_path.read_text())
    wire = summary["can_wire"]
    assert wire["bitrate"] == 1_000_000 and wire["frames"] > 0
    assert {"0x080", "0x181", "0x201", "0x020", "0x300"} <= set(wire["queuing_delay_us"])  # the rig's and the restbus's frames
    assert wire["sync_to_tpdo1_floor_margin_min_us"] >= 0
    assert wire["clients"]["connected"] == 4 and wire["clients"]["junk"] == 0  # controller, plant, tap, restbus
    assert "frames sent" in wire["restbus_sender"]
    assert summary["recording"]["can_frames"] > 0
    assert any(item == "CAN wire SYNC→TPDO1" for item, _ in summary_rows(wire))


def test_the_arbiters_figures_are_recorded_while_the_rig_runs(tmp_path: Path) -> None:
    """``up --can-bitrate --record --live``: the arbiter's period figures on ``/can/bus_load`` in the MCAP and
    the live view (lockstep)."""
    import jsonschema
    from mcap.reader import make_reader

    from workbench.recording.reader import Recording
    from workbench.recording.schemas import CAN_BUS_LOAD_SCHEMA

    record, summary_path = tmp_path / "x.mcap", tmp_path / "up.json"
    cmd = [sys.executable, "-m", "workbench", "up", "--duration", "2", "--clock", "lockstep", "--rig-id", f"live{os.getpid()}", "--can-bitrate", "1000000"]
    cmd += ["--record", str(record), "--live", "127.0.0.1:0", "--json", str(summary_path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    live = json.loads(summary_path.read_text())["live"]
    assert live["records"] > 0 and live["late_channels"] == 0  # /can/bus_load among the channels made before serving
    figures = Recording.load(record, only=("can/bus_load",)).data("can/bus_load")
    assert figures, "no /can/bus_load record"
    for f in figures:
        jsonschema.validate(f, CAN_BUS_LOAD_SCHEMA)
        assert f["bitrate"] == 1_000_000 and f["source"] == "arbiter"
        assert 0 <= f["busy_mean_pct"] <= f["busy_max_pct"] <= 100
    assert [f["seq"] for f in figures] == sorted({f["seq"] for f in figures})  # each period once, in order
    busy = [f for f in figures if f["frames"] > 0]
    assert busy and all(f["frames_per_s"] > 0 and f["bits_per_s"] > 0 for f in busy)
    paired = [f for f in figures if "sync_to_tpdo1_us" in f]
    assert paired and all(f["sync_to_tpdo1_floor_margin_min_us"] >= 0 for f in paired)
    with record.open("rb") as fh:  # the mcap library's own reader: the channel and its schema
        mcap = make_reader(fh).get_summary()
    assert mcap is not None
    channels = [c for c in mcap.channels.values() if c.topic == "/can/bus_load"]
    assert len(channels) == 1 and mcap.schemas[channels[0].schema_id].name == "ralf.CanBusLoad"
    assert mcap.statistics is not None and mcap.statistics.channel_message_counts[channels[0].id] == len(figures)
    doctor = subprocess.run([sys.executable, "-m", "workbench", "doctor", str(record)], capture_output=True, text=True, check=False, timeout=120)
    assert doctor.returncode == 0 and ": ok (" in doctor.stdout, doctor.stdout[-2000:] + doctor.stderr[-2000:]
