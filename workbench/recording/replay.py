"""Replay of a recording: the DSP's identification re-run over the recorded
batches, and the CAN side played back onto a bus.

Re-identification (the thesis's own workflow: record once, identify again
with other settings, compare). :func:`reidentify` feeds the recorded
configuration changes and batches, in the order the tap saw them, through
the DSP's own core, :class:`dsp_service.core.DspCore` (the one the zenoh
service and the co-simulation drive: block admission, identifier, the
interrupt's identification fields). At the recorded settings the
poles, confidence, history and valid fraction equal the on-line run's bit
for bit (batches travel as float64 and are recorded as shortest-round-trip
JSON, so nothing is lost); :func:`compare` checks that and measures each
track against the recorded ground truth (error, lag).

CAN playback (:func:`play_can`): python-can player semantics
(:class:`can.MessageSync`: the recorded gaps kept, or a fixed gap, or as fast
as possible), bounded by a frame count and a wall-time limit.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from dsp_service.core import DspCore
from protocol.batch_codec import SampleBatch
from protocol.messages import ConfigChange
from protocol.settings import ACCESS_FIELDS, DspSettings, upgrade_recorded
from workbench.recording.reader import Recording

IDENTIFICATION_FIELDS = ("poles", "confidence", "samples_in_history", "valid_fraction")
"""The interrupt fields the identification decides (compute time and latency are the host's)."""


@dataclass(frozen=True)
class Identified:
    """The identification part of one interrupt."""

    batch_seq: int
    sim_time_s: float
    poles: tuple[dict[str, Any], ...]
    confidence: float
    samples_in_history: int
    valid_fraction: float

    @property
    def f1_hz(self) -> float:
        return float(self.poles[0]["frequency_hz"]) if self.poles else math.nan

    def key(self) -> tuple[Any, ...]:
        return (self.batch_seq, self.poles, self.confidence, self.samples_in_history, self.valid_fraction)

    @classmethod
    def from_interrupt(cls, irq: Mapping[str, Any]) -> Identified:
        return cls(
            batch_seq=int(irq["batch_seq"]),
            sim_time_s=float(irq["sim_time_s"]),
            poles=tuple({k: p[k] for k in ("frequency_hz", "damping_ratio", "magnitude", "source")} for p in irq["poles"]),
            confidence=float(irq["confidence"]),
            samples_in_history=int(irq["samples_in_history"]),
            valid_fraction=float(irq["valid_fraction"]),
        )


def dsp_settings_of(rec: Recording, overrides: Mapping[str, Any] | None = None) -> DspSettings:
    """The DSP's settings as recorded (defaults where the recording has none),
    with ``overrides`` (field names of :class:`~protocol.settings.DspSettings`)."""
    recorded = {k: v for k, v in upgrade_recorded(rec.settings("dsp")).items() if k in DspSettings.model_fields and k not in ACCESS_FIELDS}
    values = {**recorded, **dict(overrides or {})}
    return DspSettings.model_validate({k: v for k, v in values.items() if v is not None})


def _batch(d: Mapping[str, Any]) -> SampleBatch:
    return SampleBatch(
        seq=int(d["seq"]),
        first_tick=int(d["first_tick"]),
        sample_rate_hz=float(d["sample_rate_hz"]),
        sim_time_s=float(d["sim_time_s"]),
        wall_time_s=float(d["wall_time_s"]),
        inputs=np.asarray(d["inputs"], dtype=np.float64),
        outputs=np.asarray(d["outputs"], dtype=np.float64),
        dropped_before=int(d["dropped_before"]),
    )


def dsp_events(rec: Recording) -> Iterator[tuple[str, Any]]:
    """``("config", ConfigChange)`` and ``("batch", SampleBatch)`` in the tap's order."""
    for m in rec.iter("dsp/config", "dsp/batch"):
        if m.topic.endswith("/dsp/config"):
            yield "config", ConfigChange.model_validate(m.data)
        else:
            yield "batch", _batch(m.data)


def reidentify(events: Iterable[tuple[str, Any]], settings: DspSettings) -> list[Identified]:
    """Run the DSP's identification over recorded events (see the module doc).

    Drives :class:`dsp_service.core.DspCore` as the DSP service does: a
    ``reset`` restarts the block and the history, the FFT width, batch size,
    alpha and latency changes apply (a change the board refuses changes
    nothing), a batch the block rejects is skipped, a gap in ticks restarts
    the history. The block is released after each batch (the on-line board
    releases it before the next batch is sent).
    """
    # Compute time is the host's, not the recording's (not compared): a constant
    # clock keeps a loaded host's budget-miss warnings out of the replay.
    core = DspCore(settings, perf_counter=lambda: 0.0)
    out: list[Identified] = []
    for kind, obj in events:
        if kind == "config":
            try:
                core.apply_config(obj)
            except ValueError:
                pass  # refused on-line too
            continue
        batch: SampleBatch = obj
        admission = core.admit(batch)
        if not admission.accepted:
            continue
        irq = core.process(batch, admission)
        out.append(
            Identified(
                batch_seq=irq.batch_seq,
                sim_time_s=irq.sim_time_s,
                poles=tuple(
                    {"frequency_hz": p.frequency_hz, "damping_ratio": p.damping_ratio, "magnitude": p.magnitude, "source": p.source} for p in irq.poles
                ),
                confidence=irq.confidence,
                samples_in_history=irq.samples_in_history,
                valid_fraction=irq.valid_fraction,
            )
        )
        core.release()
    return out


def _normalise(ident: Identified) -> Identified:
    """Through JSON's float64 round trip as the recording holds it (a no-op on float64 values)."""
    return Identified(
        batch_seq=ident.batch_seq,
        sim_time_s=float(ident.sim_time_s),
        poles=tuple(
            {**p, "frequency_hz": float(p["frequency_hz"]), "damping_ratio": float(p["damping_ratio"]), "magnitude": float(p["magnitude"])} for p in ident.poles
        ),
        confidence=float(ident.confidence),
        samples_in_history=int(ident.samples_in_history),
        valid_fraction=float(ident.valid_fraction),
    )


# --- comparison -------------------------------------------------------------------------------


@dataclass
class TrackScore:
    """One first-mode track against the recorded truth."""

    name: str
    interrupts: int
    scored: int
    """Interrupts of a full history (the ones scored)."""
    median_abs_error_pct: float
    rms_error_pct: float
    within_2pct: float
    """Fraction of estimates within 2 % of the true first mode."""
    lag_s: float
    """The shift of the true track that best explains the estimates (median error minimal), 0..max_lag."""
    times_s: list[float] = field(default_factory=list, repr=False)
    f1_hz: list[float] = field(default_factory=list, repr=False)

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if k not in ("times_s", "f1_hz")}


def score_track(name: str, track: list[Identified], truth: Mapping[str, np.ndarray], max_lag_s: float = 10.0, lag_step_s: float = 0.05) -> TrackScore:
    """Error of a track's first mode against the true first mode, and its lag."""
    t = np.array([i.sim_time_s for i in track], dtype=float)
    f = np.array([i.f1_hz for i in track], dtype=float)
    ok = np.isfinite(f)
    nan = math.nan
    if not truth or not ok.any():
        return TrackScore(name, len(track), 0, nan, nan, 0.0, nan, t.tolist(), f.tolist())
    tt = np.asarray(truth["sim_time_s"], dtype=float)
    ft = np.asarray(truth["modal_frequencies_hz"], dtype=float)[:, 0]
    # Score the estimates of a full history only (the warm-up's are not estimates yet).
    full = np.array([i.samples_in_history for i in track]) >= max(i.samples_in_history for i in track)
    ok &= full
    t, f = t[ok], f[ok]
    rel = (f - np.interp(t, tt, ft)) / np.interp(t, tt, ft)
    lags = np.arange(0.0, max_lag_s + 1e-9, lag_step_s)
    medians = [float(np.median(np.abs(f - np.interp(t - lag, tt, ft)))) for lag in lags]
    best = float(lags[int(np.argmin(medians))])
    return TrackScore(
        name=name,
        interrupts=len(track),
        scored=int(t.size),
        median_abs_error_pct=float(np.median(np.abs(rel)) * 100),
        rms_error_pct=float(np.sqrt(np.mean(rel**2)) * 100),
        within_2pct=float(np.mean(np.abs(rel) <= 0.02)),
        lag_s=best,
        times_s=t.tolist(),
        f1_hz=f.tolist(),
    )


@dataclass
class Comparison:
    settings: dict[str, Any]
    overrides: dict[str, Any]
    recorded: TrackScore
    replayed: TrackScore
    identical: bool
    """Every replayed interrupt equals the recorded one (batch, poles, confidence, history, valid fraction),
    and there were at least :data:`MIN_COMPARED` of them: nothing compared is not identical."""
    matched: int
    mismatched: list[int]
    """Batch sequence numbers whose identification differs (or exists on one side only)."""
    compared: int = 0
    """Batches compared: those recorded or replayed (either side)."""

    @property
    def too_few(self) -> bool:
        """Fewer than :data:`MIN_COMPARED` batches to compare: the replay proves nothing."""
        return self.compared < MIN_COMPARED

    def as_dict(self) -> dict[str, Any]:
        return {
            "settings": self.settings,
            "overrides": self.overrides,
            "recorded": self.recorded.as_dict(),
            "replayed": self.replayed.as_dict(),
            "identical_to_recorded": self.identical,
            "compared": self.compared,
            "too_few_to_compare": self.too_few,
            "matched": self.matched,
            "mismatched_batches": self.mismatched[:50],
        }


MIN_COMPARED = 1
"""Batches a replay must compare for its verdict to mean anything: one interrupt equal bit for bit
already checks the whole identification chain; none checks nothing (``ralf-hil replay`` exits 1)."""


def compare(rec: Recording, overrides: Mapping[str, Any] | None = None) -> tuple[Comparison, list[Identified]]:
    """Re-identify ``rec`` with ``overrides`` and compare with the on-line run and the truth."""
    settings = dsp_settings_of(rec, overrides)
    replayed = [_normalise(i) for i in reidentify(dsp_events(rec), settings)]
    recorded = [Identified.from_interrupt(irq) for irq in rec.interrupts()]
    by_seq = {i.batch_seq: i for i in recorded}
    seen = {i.batch_seq for i in replayed}
    mismatched = sorted({i.batch_seq for i in replayed if by_seq.get(i.batch_seq) is None or by_seq[i.batch_seq].key() != i.key()} | (set(by_seq) - seen))
    truth = rec.truth()
    compared = len(set(by_seq) | seen)
    comparison = Comparison(
        settings=settings.model_dump(mode="json", include=set(identifier_fields())),
        overrides=dict(overrides or {}),
        recorded=score_track("recorded (on-line)", recorded, truth),
        replayed=score_track("replayed", replayed, truth),
        identical=not mismatched and len(replayed) == len(recorded) and compared >= MIN_COMPARED,
        matched=len(replayed) - len([s for s in mismatched if s in seen]),
        mismatched=mismatched,
        compared=compared,
    )
    return comparison, replayed


def identifier_fields() -> tuple[str, ...]:
    """The DSP settings that change the identification (``ralf-hil replay --set`` takes these)."""
    return (
        "fft_width",
        "alpha",
        "averaging",
        "identifier",
        "solver",
        "smoothing",
        "search_band_hz",
        "sample_rate_hz",
    )


def report_markdown(c: Comparison) -> str:
    rows = [("", "recorded (on-line)", "replayed")]
    for label, attr, fmt in (
        ("interrupts", "interrupts", "{:d}"),
        ("of them scored (full history)", "scored", "{:d}"),
        ("median absolute error of f1 (%)", "median_abs_error_pct", "{:.2f}"),
        ("RMS error of f1 (%)", "rms_error_pct", "{:.2f}"),
        ("within 2 % of the true f1", "within_2pct", "{:.0%}"),
        ("lag behind the true f1 (s)", "lag_s", "{:.2f}"),
    ):
        a, b = getattr(c.recorded, attr), getattr(c.replayed, attr)
        rows.append((label, _fmt(fmt, a), _fmt(fmt, b)))
    table = "\n".join("| " + " | ".join(r) + " |" for r in rows[:1]) + "\n| --- | ---: | ---: |\n" + "\n".join("| " + " | ".join(r) + " |" for r in rows[1:])
    overrides = ", ".join(f"{k}={v}" for k, v in c.overrides.items()) or "none (the recorded settings)"
    if c.too_few:
        verdict = (
            f"**compared nothing**: {c.recorded.interrupts} interrupt(s) recorded, {c.replayed.interrupts} replayed "
            f"(at least {MIN_COMPARED} needed): not a test of anything"
        )
    elif c.identical:
        verdict = f"**identical**: all {c.compared} replayed interrupts equal the recorded ones bit for bit"
    else:
        verdict = f"differs from the on-line run in {len(c.mismatched)} of {c.compared} batch(es) (expected when the settings differ)"
    return (
        "# ralf-hil replay: identification\n\n"
        f"Identifier settings: {', '.join(f'{k}={v}' for k, v in c.settings.items())}.\n\n"
        f"Overrides: {overrides}. Replay {verdict}.\n\n"
        f"{table}\n\n"
        "Error: the first identified mode of each interrupt with a full history against the plant's true first mode at the interrupt's simulated time. "
        "Lag: the shift of the true track that minimises the median absolute error.\n"
    )


def _fmt(fmt: str, value: Any) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        return "–"
    return fmt.format(value)


# --- CAN playback -------------------------------------------------------------------------------


def recorded_can_messages(rec: Recording, direction: str | None = None) -> list[can.Message]:
    """The recorded frames as python-can messages (timestamps: the tap's wall clock)."""
    out = []
    for d in rec.can_frames():
        if direction and d["direction"] != direction:
            continue
        out.append(can.Message(timestamp=d["wall_time_s"], arbitration_id=d["arbitration_id"], is_extended_id=d["is_extended_id"], data=bytes(d["data"])))
    return out


def play_can(
    messages: Iterable[can.Message],
    bus: can.BusABC,
    *,
    ignore_timestamps: bool = False,
    gap_s: float = 0.0001,
    skip_s: float = 60.0,
    limit: int | None = None,
    max_wall_s: float | None = None,
) -> int:
    """Send ``messages`` onto ``bus`` as ``python -m can.player`` does
    (:class:`can.MessageSync`: recorded gaps, gaps over ``skip_s`` shortened,
    or ``gap_s`` apart with ``ignore_timestamps``); stops after ``limit``
    frames or ``max_wall_s``. Returns the number of frames sent."""
    sent = 0
    started = time.monotonic()
    for msg in can.MessageSync(messages, timestamps=not ignore_timestamps, gap=gap_s, skip=skip_s):
        if limit is not None and sent >= limit:
            break
        if max_wall_s is not None and time.monotonic() - started > max_wall_s:
            break
        bus.send(msg)
        sent += 1
    return sent


def export_can_log(rec: Recording, path: str) -> int:
    """Write the recorded CAN frames in python-can's format for ``path``'s suffix (.blf, .asc, .log, .csv)."""
    writer = can.Logger(path)
    n = 0
    try:
        for d in rec.can_frames():
            writer.on_message_received(
                can.Message(
                    timestamp=d["wall_time_s"],
                    arbitration_id=d["arbitration_id"],
                    is_extended_id=d["is_extended_id"],
                    data=bytes(d["data"]),
                    is_rx=d["direction"] != "controller->plant",
                )
            )
            n += 1
    finally:
        writer.stop()
    return n
