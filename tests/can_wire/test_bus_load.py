"""Bus load from the simulated bus and from python-can logs (BLF, ASC)
written by python-can's own writers; the busy share against a bit-by-bit
timeline of the bus drawn with numpy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from service_kit.can_wire.arbitration import BusRun, QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.bus_load import bus_load, intervals_from_messages, intervals_from_run, load_of_log, main, queuing_delays
from service_kit.can_wire.timing import bit_time_ns

BITRATE = 500_000
BIT = bit_time_ns(BITRATE)


def _rig_like_run(periods: int = 200, period_ns: int = 1_000_000) -> tuple[list[QueuedFrame], BusRun]:
    sync = frame_bits(0x080, b"")
    frames: list[QueuedFrame] = []
    for k in range(periods):
        t = k * period_ns
        frames.append(QueuedFrame("controller", t, sync))
        frames.append(QueuedFrame("plant", t, frame_bits(0x181, bytes([k & 0xFF, 0, 0x10, 0, 0xF0, 0xFF, k >> 8, 1]))))
        frames.append(QueuedFrame("controller", t, frame_bits(0x201, bytes([0, k & 0xFF, 0, 0]))))
    return frames, simulate(frames, BITRATE)


def test_busy_share_against_a_bit_timeline() -> None:
    frames, run = _rig_like_run()
    window = 10_000_000
    report = bus_load(intervals_from_run(run), BITRATE, window, start_ns=0, end_ns=200_000_000)
    timeline = np.zeros(200_000_000 // BIT, dtype=bool)
    for a in run.attempts:
        timeline[a.start_ns // BIT : a.end_ns // BIT] = True
    assert report.busy == pytest.approx(timeline.mean(), abs=1e-12)
    per_window = timeline.reshape(-1, window // BIT).mean(axis=1)
    assert [w.busy for w in report.windows] == pytest.approx(list(per_window), abs=1e-12)
    assert report.frames == 600 and report.frames_per_s == pytest.approx(3000.0)
    assert report.bits == sum(q.frame.n_bits for q in frames)
    assert report.overlapping == 0 and report.offered == pytest.approx(report.busy)


def test_queuing_delays_of_contending_frames() -> None:
    _, run = _rig_like_run(periods=50)
    stats = queuing_delays(run)
    sync_bits = frame_bits(0x080, b"").n_bits
    assert stats[0x080].max_ns == 0
    # TPDO1 always waits for SYNC; RPDO1 for SYNC and TPDO1 (whose length varies with its data)
    assert stats[0x181].p50_ns == stats[0x181].max_ns == sync_bits * BIT
    delays = [t.queuing_delay_ns for t in run.transmissions if t.arbitration_id == 0x201]
    assert stats[0x201].n == 50 and stats[0x201].max_ns == max(delays)
    assert stats[0x201].mean_ns == pytest.approx(float(np.mean(delays)))


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_log_gives_the_same_load_as_the_run(suffix: str, tmp_path: Path) -> None:
    """The run's frames written by python-can's logger, stamped at their end
    as a receiver stamps them, read back with can.LogReader (ASC keeps
    microseconds from the first frame, BLF nanoseconds): the same load over
    the same span (first SOF to last intermission)."""
    frames, run = _rig_like_run(periods=100)
    path = tmp_path / f"bus{suffix}"
    with can.Logger(str(path)) as log:
        for tx in run.transmissions:
            frame = frames[tx.index].frame
            log.on_message_received(can.Message(timestamp=tx.end_ns / 1e9, arbitration_id=tx.arbitration_id, data=frame.data, is_extended_id=False))
    window = 10_000_000
    from_run = bus_load(intervals_from_run(run), BITRATE, window)
    from_log = load_of_log(path, BITRATE, window)
    assert from_log.frames == from_run.frames == 300
    assert from_log.bits == from_run.bits
    # BLF's nanoseconds come back through a float: a stamp may be 1 ns off
    slack_ns = 0 if suffix == ".asc" else 1
    span = from_run.end_ns - from_run.start_ns
    assert abs((from_log.end_ns - from_log.start_ns) - span) <= 2 * slack_ns
    assert from_log.busy == pytest.approx(from_run.busy, abs=1e-12 + 2 * slack_ns * 300 / span)
    assert [w.busy for w in from_log.windows] == pytest.approx([w.busy for w in from_run.windows], abs=1e-12 + 2 * slack_ns * 300 / window)


def test_log_from_a_bus_without_wire_overlaps() -> None:
    """udp_multicast carries frames 10 us apart; at 125 kbit/s each 8-byte
    frame needs about 1 ms: the log could not come from a real bus."""
    msgs = [can.Message(timestamp=k * 10e-6, arbitration_id=0x181, data=bytes(8), is_extended_id=False) for k in range(100)]
    msgs.append(can.Message(timestamp=0.5, is_error_frame=True))
    refused: dict[str, int] = {}
    ivs = intervals_from_messages(msgs, 125_000, refused=refused)
    report = bus_load(ivs, 125_000, 1_000_000, refused=refused)
    assert report.overlapping == 99
    assert report.busy <= 1.0 and report.offered > 10
    assert report.refused == {"error frame": 1} and report.errors == 1


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bus.asc"
    with can.Logger(str(path)) as log:
        for k in range(10):
            log.on_message_received(can.Message(timestamp=k * 0.001, arbitration_id=0x080, data=b"", is_extended_id=False))
    assert main([str(path), "--bitrate", "1000000", "--window-ms", "5"]) == 0
    out = capsys.readouterr().out
    assert "10 frames" in out and "busy" in out
    assert main([str(tmp_path / "missing.blf")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.blf" in err
    junk = tmp_path / "junk.blf"
    junk.write_bytes(b"not a blf file at all" * 10)
    proc = subprocess.run([sys.executable, "-m", "service_kit.can_wire.bus_load", str(junk)], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
