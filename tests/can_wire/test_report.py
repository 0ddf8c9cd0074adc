"""The rig's frames built with cantools from protocol/ralf.dbc: sigrok-cli
reads our bits back into the same bytes, which cantools decodes into the
same signals; the generated table is up to date."""

from __future__ import annotations

from pathlib import Path

import pytest

from service_kit.can_wire.report import load_dbc, main, rig_frames
from service_kit.can_wire.timing import wire_time_ns, worst_case_bits
from tests.can_wire.sigrok import decode, needs_sigrok

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "docs" / "results" / "can-wire-times.md"


def test_frames_carry_what_cantools_encoded() -> None:
    db = load_dbc()
    frames = {f.name: f for f in rig_frames()}
    assert set(frames) == {m.name for m in db.messages} | {"SYNC (no counter)"}
    for message in db.messages:
        f = frames[message.name]
        for frame in (f.at_rest, f.shortest, f.longest):
            assert frame.arbitration_id == message.frame_id and len(frame.data) == message.length
            db.decode_message(message.frame_id, frame.data)  # a valid payload of the message
            assert f.shortest.n_bits <= frame.n_bits <= f.longest.n_bits <= worst_case_bits(message.length)
    assert db.decode_message(0x080, frames["SYNC"].at_rest.data) == {"SYNC_Counter": 1}
    tpdo1 = db.decode_message(0x181, frames["TPDO1_AnalogInputs16"].at_rest.data)
    assert tpdo1 == {"AI1": 0.0, "AI2": 0.0, "AI3": 0.0, "AI4": 0.0}


def test_sync_and_tpdo1_at_one_megabit() -> None:
    """SYNC (counter) + TPDO1: 55 + 111 bits unstuffed, 166 us at 1 Mbit/s;
    with their actual stuff bits somewhere between the fewest and the longest."""
    frames = {f.name: f for f in rig_frames()}
    sync, tpdo1 = frames["SYNC"], frames["TPDO1_AnalogInputs16"]
    unstuffed = (sync.at_rest.n_bits - sync.at_rest.n_stuff) + (tpdo1.at_rest.n_bits - tpdo1.at_rest.n_stuff)
    assert unstuffed == 166
    at_rest = wire_time_ns(sync.at_rest.n_bits + tpdo1.at_rest.n_bits, 1_000_000)
    assert wire_time_ns(166, 1_000_000) < at_rest <= wire_time_ns(65 + 135, 1_000_000)


@needs_sigrok
def test_sigrok_reads_the_rig_frames(tmp_path: Path) -> None:
    db = load_dbc()
    frames = [frame for f in rig_frames() for frame in (f.at_rest, f.longest)]
    for frame, got in zip(frames, decode(frames, 1_000_000, tmp_path)):
        assert (got.identifier, got.dlc, got.data, got.crc) == (frame.arbitration_id, frame.dlc, frame.data, frame.crc)
        assert got.stuff_positions == frame.stuff_positions
        if frame.dlc:
            assert db.decode_message(got.identifier, got.data) == db.decode_message(frame.arbitration_id, frame.data)


def test_generated_table_is_up_to_date(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--check", str(TABLE)]) == 0, capsys.readouterr().err


def test_check_reports_a_stale_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stale = tmp_path / "t.md"
    stale.write_text("old\n")
    assert main(["--check", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().err
    assert main(["--write", str(tmp_path / "missing" / "t.md")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
