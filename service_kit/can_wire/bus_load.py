"""Bus load: the share of wire time busy per window, frames/s, bits/s, and
per-identifier queuing delays, from the simulated bus
(:func:`service_kit.can_wire.arbitration.simulate`) or from timestamped
frames (a python-can log: BLF, ASC, ... read with ``can.LogReader``).

A logged frame's time on the wire is its exact bit count
(:mod:`service_kit.can_wire.bits`) times the bit time. python-can stamps a
frame when it is received, i.e. at its end: by default the frame occupies
``[timestamp - wire time, timestamp]`` (``timestamp_at="start"`` for a log
stamped at SOF). Frames of a log from a bus with no wire (udp_multicast,
the virtual bus) may lie closer together than their wire time: the busy
share counts the union of the intervals (never above 100 %), the offered
load adds them up (it can exceed 100 %: that traffic would not fit on a real
bus at this bit rate), and :attr:`LoadReport.overlapping` counts the frames
that began before the previous one ended. Error frames and CAN FD frames in
a log have no classical frame layout: counted, not timed.

``python -m service_kit.can_wire.bus_load LOG --bitrate 500000 [--window-ms 100]``
prints the figures of a log file.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from service_kit.can_wire.arbitration import BusRun
from service_kit.can_wire.bits import frame_of_message
from service_kit.can_wire.timing import NS_PER_S, bit_time_ns


@dataclass(frozen=True)
class BusyInterval:
    start_ns: int
    end_ns: int
    arbitration_id: int
    bits: int
    ok: bool = True
    """False for an attempt cut by an error frame (its bits include the error frame)."""


@dataclass(frozen=True)
class WindowLoad:
    start_ns: int
    busy: float
    """Share of the window the bus was busy (0..1)."""
    frames: int
    """Frames that started in the window."""
    bits: int
    """Bits of those frames."""


@dataclass(frozen=True)
class DelayStats:
    """Queuing delays of one identifier (ns): queued to SOF of the successful attempt."""

    n: int
    mean_ns: float
    p50_ns: float
    p99_ns: float
    max_ns: int


@dataclass
class LoadReport:
    bitrate: int
    start_ns: int
    end_ns: int
    frames: int
    bits: int
    busy: float
    """Share of [start, end) covered by at least one frame (0..1)."""
    offered: float
    """Sum of the frames' wire times over the span (may exceed 1 for a log from a wireless bus)."""
    windows: list[WindowLoad]
    errors: int = 0
    """Attempts cut by an error frame (simulated bus) or error frames (log)."""
    overlapping: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    """Log frames not timed, by reason."""

    @property
    def frames_per_s(self) -> float:
        span = self.end_ns - self.start_ns
        return self.frames * NS_PER_S / span if span > 0 else 0.0

    @property
    def bits_per_s(self) -> float:
        span = self.end_ns - self.start_ns
        return self.bits * NS_PER_S / span if span > 0 else 0.0

    @property
    def peak_window_busy(self) -> float:
        return max((w.busy for w in self.windows), default=0.0)


def intervals_from_run(run: BusRun) -> list[BusyInterval]:
    """Every attempt of a simulated run, error frames included."""
    return [BusyInterval(a.start_ns, a.end_ns, a.arbitration_id, a.bits, a.ok) for a in run.attempts]


def intervals_from_messages(
    messages: Iterable[can.Message], bitrate: int, *, timestamp_at: str = "end", refused: dict[str, int] | None = None
) -> list[BusyInterval]:
    """Busy intervals of timestamped frames (module docstring); ``refused``
    collects the counts of frames left out, by reason."""
    if timestamp_at not in ("end", "start"):
        raise ValueError(f"timestamp_at must be 'end' or 'start', got {timestamp_at!r}")
    bit = bit_time_ns(bitrate)
    out: list[BusyInterval] = []
    counts = refused if refused is not None else {}
    for msg in messages:
        if msg.is_error_frame:
            counts["error frame"] = counts.get("error frame", 0) + 1
            continue
        if msg.is_fd:
            counts["CAN FD"] = counts.get("CAN FD", 0) + 1
            continue
        try:
            frame = frame_of_message(msg)
        except ValueError:
            counts["malformed"] = counts.get("malformed", 0) + 1
            continue
        stamp = round(msg.timestamp * NS_PER_S)
        wire = frame.n_bits * bit
        start = stamp - wire if timestamp_at == "end" else stamp
        out.append(BusyInterval(start, start + wire, frame.arbitration_id, frame.n_bits))
    out.sort(key=lambda iv: (iv.start_ns, iv.end_ns))
    return out


def bus_load(
    intervals: Sequence[BusyInterval],
    bitrate: int,
    window_ns: int,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    refused: dict[str, int] | None = None,
) -> LoadReport:
    """Load over ``[start_ns, end_ns)`` (default: first start to last end) in windows of ``window_ns``."""
    if window_ns <= 0:
        raise ValueError(f"window must be positive, got {window_ns} ns")
    ivs = sorted(intervals, key=lambda iv: (iv.start_ns, iv.end_ns))
    lo = start_ns if start_ns is not None else (ivs[0].start_ns if ivs else 0)
    hi = end_ns if end_ns is not None else (max(iv.end_ns for iv in ivs) if ivs else lo)
    # union of the busy intervals, clipped to the span
    union: list[list[int]] = []
    overlapping = 0
    for iv in ivs:
        s, e = max(iv.start_ns, lo), min(iv.end_ns, hi)
        if union and iv.start_ns < union[-1][1]:
            overlapping += 1
        if e <= s:
            continue
        if union and s <= union[-1][1]:
            union[-1][1] = max(union[-1][1], e)
        else:
            union.append([s, e])
    span = hi - lo
    busy_total = sum(e - s for s, e in union)
    bit = bit_time_ns(bitrate)
    inside = [iv for iv in ivs if lo <= iv.start_ns < hi]
    windows: list[WindowLoad] = []
    for w0 in range(lo, hi, window_ns):
        w1 = min(w0 + window_ns, hi)
        busy = sum(max(0, min(e, w1) - max(s, w0)) for s, e in union)
        started = [iv for iv in inside if w0 <= iv.start_ns < w1]
        windows.append(WindowLoad(w0, busy / (w1 - w0), len(started), sum(iv.bits for iv in started)))
    return LoadReport(
        bitrate=bitrate,
        start_ns=lo,
        end_ns=hi,
        frames=sum(1 for iv in inside if iv.ok),
        bits=sum(iv.bits for iv in inside),
        busy=busy_total / span if span > 0 else 0.0,
        offered=sum(iv.bits for iv in inside) * bit / span if span > 0 else 0.0,
        windows=windows,
        errors=sum(1 for iv in inside if not iv.ok) + (refused or {}).get("error frame", 0),
        overlapping=overlapping,
        refused=dict(refused or {}),
    )


def queuing_delays(run: BusRun) -> dict[int, DelayStats]:
    """Per identifier: queuing delay statistics of the successful transmissions."""
    by_id: dict[int, list[int]] = {}
    for tx in run.transmissions:
        by_id.setdefault(tx.arbitration_id, []).append(tx.queuing_delay_ns)
    return delay_stats(by_id)


def delay_stats(by_id: dict[int, list[int]]) -> dict[int, DelayStats]:
    """Per identifier: the statistics of its queuing delays (ns); identifiers without one are left out."""
    out: dict[int, DelayStats] = {}
    for ident, delays in sorted(by_id.items()):
        if not delays:
            continue
        arr = np.asarray(delays, dtype=np.float64)
        out[ident] = DelayStats(
            n=len(delays),
            mean_ns=float(arr.mean()),
            p50_ns=float(np.percentile(arr, 50)),
            p99_ns=float(np.percentile(arr, 99)),
            max_ns=max(delays),
        )
    return out


def load_of_log(path: Path, bitrate: int, window_ns: int, *, timestamp_at: str = "end") -> LoadReport:
    """:func:`bus_load` of a python-can log file (any format ``can.LogReader`` reads)."""
    refused: dict[str, int] = {}
    with can.LogReader(path) as reader:
        ivs = intervals_from_messages(reader, bitrate, timestamp_at=timestamp_at, refused=refused)
    return bus_load(ivs, bitrate, window_ns, refused=refused)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m service_kit.can_wire.bus_load", description="Bus load of a python-can log file.")
    parser.add_argument("log", type=Path)
    parser.add_argument("--bitrate", type=int, default=500_000)
    parser.add_argument("--window-ms", type=float, default=100.0)
    parser.add_argument("--timestamp-at", choices=("end", "start"), default="end")
    args = parser.parse_args(argv)
    try:
        window_ns = round(args.window_ms * 1e6)
        report = load_of_log(args.log, args.bitrate, window_ns, timestamp_at=args.timestamp_at)
    except (OSError, ValueError) as exc:
        print(f"bus_load: {args.log}: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a log format's reader failing on a damaged file
        print(f"bus_load: {args.log}: cannot read: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    if report.frames == 0:
        print(f"bus_load: {args.log}: no frame to measure", file=sys.stderr)
        return 1
    span_s = (report.end_ns - report.start_ns) / NS_PER_S
    print(f"{args.log}: {report.frames} frames in {span_s:.3f} s at {report.bitrate} bit/s")
    print(f"busy {100 * report.busy:.2f} % (peak window {100 * report.peak_window_busy:.2f} %), offered {100 * report.offered:.2f} %")
    print(f"{report.frames_per_s:.1f} frames/s, {report.bits_per_s:.0f} bit/s")
    if report.overlapping:
        print(f"{report.overlapping} frames began before the previous one ended: more than this bit rate carries")
    for reason, n in sorted(report.refused.items()):
        print(f"not timed: {n} {reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
