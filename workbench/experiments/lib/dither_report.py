"""The report section of a dither study (:mod:`.dither_cost` with :func:`.arx_replay.arx_replays` per run):
the dither's cost against the ARX's delays per amplitude."""

from __future__ import annotations

from typing import Any

from controller.excitation import DitherConfig
from workbench.experiments.lib.dither_cost import expected_sent_rms_v
from workbench.experiments.lib.identification_delay import STEADY_AFTER_S
from workbench.experiments.report import Report

__all__ = ["dither_section", "dither_sent_checks"]


def _arx_cells(a: dict[str, Any]) -> list[Any]:
    """The ARX's delays and accuracy of one run: per event, the three medians, steady share, error at the end."""
    return [
        ", ".join(f"{e['settle_2pct_s']:.1f}" for e in a["as_run"]["events"]),
        a["as_run"]["median_settle_2pct_s"],
        a["reset_at_the_event"]["median_settle_2pct_s"],
        a["change_detection"]["median_settle_2pct_s"],
        100 * a["steady_within_2pct"],
        100 * a["as_run"]["median_rel_error_end"],
    ]


def dither_section(rep: Report, dither: dict[str, Any], sample_rate_hz: float, dither_cfg: DitherConfig) -> None:
    """Heading, method and the table: per amplitude (``dither["runs"]``, against ``dither["base"]``) the dither as
    sent, the costs and their ratios, the ARX's delays as run, reset at the event, with its detector."""
    rep.heading("Persistent excitation: a dither on the valve commands")
    rep.text(
        "The payload kick rings the second mode, and on the return stroke nothing excites the first for seconds, so the data after a "
        "change may hold no information about the new first mode. The controller's opt-in dither (`RALF_DITHER=amplitude_v=...`, "
        f"`controller/excitation.py`: a periodic multisine, flat over every bin of its {dither_cfg.period_ticks / sample_rate_hz:g}-s period in "
        f"{dither_cfg.band_hz[0]:g}–{dither_cfg.band_hz[1]:g} Hz, independent random phases per "
        "valve) is added to both valve commands after the PI, before the D/A, so the DSP's inputs carry it. Same seed, trajectory and "
        "events as the ARX run above; with the OATF off the identifier does not act on the plant, so the dither is the only difference. "
        "**Cost**: RMS deflection velocity and acceleration over the whole run (the §4.2.1 metrics), against the undithered run. "
        "**Benefit**: the ARX's median delay to stay within 2 % for 2 s, as run, with a reset at the true event and with its change detector "
        "(replayed from each record)."
    )
    base = dither["base"]
    rows = [["none", "–", *base["velocity_rms"], "1 / 1", "1 / 1", *_arx_cells(base["arx"])]]
    for d in dither["runs"]:
        rows.append(
            [
                f"{1e3 * d['amplitude_v']:g} mV",
                " / ".join(f"{1e3 * x:.1f}" for x in d["sent_rms_v"]),
                *d["velocity_rms"],
                " / ".join(f"{x:.2f}" for x in d["velocity_ratio"]),
                " / ".join(f"{x:.2f}" for x in d["acceleration_ratio"]),
                *_arx_cells(d["arx"]),
            ]
        )
    rep.table(
        [
            "dither (RMS per valve)",
            "sent: RMS of u − PI output (mV, valve 1 / 2)",
            "RMS defl. velocity link 1 (in/s)",
            "link 2 (in/s)",
            "velocity / undithered (link 1 / 2)",
            "acceleration / undithered",
            "ARX delay to 2 %, per event (s)",
            "median, as run (s)",
            "median, reset at the event (s)",
            "median, change detector (s)",
            f"steady: time within 2 % from {STEADY_AFTER_S:g} s after each event (%)",
            "error at the end (%)",
        ],
        rows,
        caption="The dither's cost and the ARX's delays per amplitude (undithered: the ARX run above)",
        digits=3,
    )


def dither_sent_checks(rep: Report, dither: dict[str, Any], rel: float = 0.2) -> None:
    """Per amplitude, the check that the D/A carried the dither: what it sent above the PI's output (the dither
    and the D/A's rounding) within ``rel`` of :func:`.dither_cost.expected_sent_rms_v` on both valves."""
    for d in dither["runs"]:
        expect = expected_sent_rms_v(d["amplitude_v"])
        rep.check(
            f"dither {1e3 * d['amplitude_v']:g} mV: the D/A carries it (RMS of u − PI output within {100 * rel:g} % of √(A² + LSB²/12))",
            all(abs(x / expect - 1.0) <= rel for x in d["sent_rms_v"]),
            " / ".join(f"{1e3 * x:.2f}" for x in d["sent_rms_v"]) + f" mV for {1e3 * expect:.2f} mV",
        )
