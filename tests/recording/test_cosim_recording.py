"""A co-simulation recorded into MCAP (``run_cosim(record=...)``, what
``ralf-hil experiment --record`` uses by default): read back with the mcap
library and cantools, replayed bit for bit, and the run itself unchanged by
recording."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cantools
import numpy as np
import pytest

from tests.recording.support import CHANNELS_OF_A_RUN, read_validated
from workbench.cosim import run_cosim
from workbench.recording.reader import Recording
from workbench.recording.replay import compare, report_markdown

ROOT = Path(__file__).resolve().parents[2]
CONTROLLER = {"duration_s": 6.0, "tf_download_samples": 200, "batch_size": 20}
DSP = {"fft_width": 256, "emulated_latency_s": 0.05}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("cosim-rec")
    common = {"rig_id": "cosimrec"}
    plain = run_cosim(controller=CONTROLLER, dsp=DSP, common=common)
    path = tmp / "run.mcap"
    taped = run_cosim(controller=CONTROLLER, dsp=DSP, common=common, record=str(path), can_log=str(tmp / "run.asc"))
    return {"plain": plain, "taped": taped, "path": path, "tmp": tmp}


def test_recording_changes_nothing_in_the_run(recorded: dict[str, Any]) -> None:
    a, b = recorded["plain"].controller.record.to_columns(), recorded["taped"].controller.record.to_columns()
    assert a.keys() == b.keys()
    for name in a:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_the_file_holds_every_channel_validated_against_its_schema(recorded: dict[str, Any]) -> None:
    seen = read_validated(recorded["path"])
    counts, meta = seen.counts, seen.metadata
    for suffix in CHANNELS_OF_A_RUN:
        assert counts.get(f"/ralf/cosimrec/{suffix}", 0) > 0, suffix
    assert set(seen.encodings.values()) == {"application/json", "application/octet-stream;ralf-batch-v1", "application/octet-stream;ralf-tf-v1"}
    ticks = int(CONTROLLER["duration_s"] * 200)
    assert counts["/can"] >= 3 * ticks  # SYNC, TPDO1, RPDO1 each tick
    assert meta["ralf.run"]["clock"] == "cosim"
    assert json.loads(meta["ralf.settings.dsp"]["fft_width"]) == 256


def test_cantools_decodes_the_recorded_frames(recorded: dict[str, Any]) -> None:
    db = cantools.database.load_file(str(ROOT / "protocol" / "ralf.dbc"))
    assert isinstance(db, cantools.database.can.Database)
    known = {m.frame_id for m in db.messages}
    rec = Recording.load(recorded["path"], only=["can"])
    frames = rec.can_frames()
    decoded = 0
    for frame in frames:
        if frame["arbitration_id"] in known:
            db.decode_message(frame["arbitration_id"], bytes(frame["data"]))
            decoded += 1
    assert decoded > 0.9 * len(frames)
    assert (recorded["tmp"] / "run.asc").stat().st_size > 10_000


def test_replay_of_a_cosim_recording_is_bit_identical(recorded: dict[str, Any]) -> None:
    rec = Recording.load(recorded["path"])
    same, replayed = compare(rec)
    assert same.identical and not same.too_few
    assert len(replayed) == len(rec.interrupts()) == same.compared > 5
    assert f"all {same.compared} replayed interrupts equal the recorded ones bit for bit" in report_markdown(same)


def test_a_replay_and_a_doctor_of_a_recording_holding_no_message_do_not_pass(recorded: dict[str, Any], tmp_path: Path) -> None:
    """A valid MCAP with no message, and the first 100 bytes of a real
    recording: replay compares nothing and doctor checks nothing, and both
    say so and exit 1 (no "identical", no "ok")."""
    from mcap.writer import Writer

    from workbench.cli import main

    empty = tmp_path / "empty.mcap"
    with open(empty, "wb") as fh:
        writer = Writer(fh)
        writer.start(profile="", library="test")
        writer.finish()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded["path"].read_bytes()[:100])
    for path in (empty, cut):
        comparison, _ = compare(Recording.load(path, only=("dsp/config", "dsp/batch", "dsp/interrupt", "plant/truth")))
        assert comparison.too_few and not comparison.identical and comparison.compared == 0
        text = report_markdown(comparison)
        assert "**compared nothing**" in text and "identical" not in text
        assert main(["replay", str(path)]) == 1
        assert main(["replay", str(path), "--can", "--interface", "virtual", "--channel", "nothing-compared"]) == 1
        assert main(["doctor", str(path)]) == 1
    assert main(["doctor", str(recorded["path"])]) == 0


def test_doctor_says_how_many_messages_it_checked(recorded: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    from mcap.reader import make_reader

    from workbench.cli import main
    from workbench.recording.doctor import examine

    with open(recorded["path"], "rb") as fh:
        stats = make_reader(fh).get_summary().statistics  # type: ignore[union-attr]
    found = examine(recorded["path"])
    assert found.problems == [] and (found.messages, found.chunks) == (stats.message_count, stats.chunk_count)  # type: ignore[union-attr]
    assert found.messages > 100 and found.channels > 3 and found.chunks >= 1
    assert main(["doctor", str(recorded["path"])]) == 0
    assert f"ok ({found.messages} messages on {found.channels} channels in {found.chunks} chunks checked)" in capsys.readouterr().out


def test_doctor_finds_the_file_sound_and_a_damaged_one_not(recorded: dict[str, Any], tmp_path: Path) -> None:
    from mcap import records
    from mcap.stream_reader import StreamReader

    from workbench.recording.doctor import check

    assert check(recorded["path"]) == []
    data = recorded["path"].read_bytes()
    with open(recorded["path"], "rb") as fh:
        chunk = next(r for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, records.Chunk))
    at = data.find(chunk.data[64:128]) + 8  # a byte inside the first chunk's compressed data
    flipped = bytearray(data)
    flipped[at] ^= 0x01
    (tmp_path / "flipped.mcap").write_bytes(bytes(flipped))
    assert any("crc" in p.lower() or "unreadable" in p for p in check(tmp_path / "flipped.mcap"))
    (tmp_path / "truncated.mcap").write_bytes(data[: len(data) - 4000])
    assert check(tmp_path / "truncated.mcap")


def test_a_recording_cut_short_reads_up_to_the_cut_in_doctor_plot_and_replay(recorded: dict[str, Any], tmp_path: Path) -> None:
    """A run killed by a signal leaves its MCAP without summary and ends inside a
    record: doctor says where it ends, plot and replay read the intact messages
    (the mcap library's stream reader counts them independently)."""
    from mcap.stream_reader import StreamReader

    from workbench.recording.doctor import check
    from workbench.recording.plot import plot_all

    whole = Path(recorded["path"]).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: int(len(whole) * 0.6)])
    intact = 0
    try:
        with open(cut, "rb") as fh:
            for record in StreamReader(fh, record_size_limit=len(whole)).records:
                intact += type(record).__name__ == "Message"
    except Exception:  # noqa: BLE001 -- the reference stops at the cut, whatever it raises
        pass
    assert intact > 100
    problems = check(cut)
    assert len(problems) == 1 and problems[0].startswith("cut short") and f"{intact} messages" in problems[0], problems
    rec = Recording.load(cut)
    assert rec.cut and len(rec.messages) == intact and rec.metadata  # the metadata comes first in the file
    assert [m.log_time_ns for m in rec.messages] == sorted(m.log_time_ns for m in rec.messages)
    figures = plot_all(cut, tmp_path / "plots")
    assert figures and all(p.exists() for p in figures)
    comparison, identified = compare(Recording.load(cut, only=("dsp/config", "dsp/batch", "dsp/interrupt", "plant/truth")))
    assert identified  # the batches before the cut were identified again
