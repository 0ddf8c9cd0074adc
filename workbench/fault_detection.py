"""How fast the controller's input monitors catch each channel fault: the
detection-latency table of docs/fault-insertion.md.

For every fault kind (each A/D kind on the link-1 deflection input AI3 and on
the cylinder-1 extension input AI1, each D/A kind on valve 1), one
co-simulation of the thesis trajectory with every input monitor on (policy
``count``, so a firing changes nothing) and the fault inserted at
:data:`INSERT_S` (the arm following the trajectory). The latency of a
monitor is the simulated time from the insertion to the sample whose check
fired: tick ``k`` processes the sample the plant took at ``(k + 1) Ts``
(lockstep: the arm steps one period, then samples), so 0 ms is the first
faulted sample. A clean lap with the same monitors gives the figures their
default limits are set against.

``python -m workbench.fault_detection --write docs/results/fault-detection.md``
regenerates the page (about a minute; co-simulation is bit-identical, so the
page changes only with the code).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from controller.monitors import INPUT_MONITORS
from protocol.can_map import WORD16_VOLTS_PER_LSB
from protocol.setting_groups import InputMonitors
from protocol.static_sag import static_sag_in
from workbench.hil import HilRig, RunRecord

__all__ = ["CASES", "Case", "detection_table", "main"]

INSERT_S: Final[float] = 16.0
"""When each fault is inserted (simulated s): the set-point moves from 14 s to the lap's end."""
RUN_S: Final[float] = 19.0
"""Each run's length: 3 s of fault."""
ALL_ON: Final[str] = "range=true,stuck=true,rate=true,disagree=true"
COUNT: Final[str] = ",".join(f"{name}=count" for name in INPUT_MONITORS)


@dataclass(frozen=True)
class Case:
    """One fault of the table: its channel, kind and parameters."""

    channel: str
    kind: str
    params: tuple[tuple[str, Any], ...] = ()

    def fault(self) -> dict[str, Any]:
        return {"channel": self.channel, "kind": self.kind, "start_s": INSERT_S, **dict(self.params)}

    def label(self) -> str:
        shown = ", ".join(f"{k}={v}" for k, v in self.params)
        return f"`{self.channel}` {self.kind}" + (f" ({shown})" if shown else "")


def _ad_cases(channel: str, other: str) -> list[Case]:
    return [
        Case(channel, "open"),
        Case(channel, "short_ground"),
        Case(channel, "short_supply"),
        Case(channel, "stuck"),
        Case(channel, "offset", (("offset_v", 2.0),)),
        Case(channel, "gain", (("factor", 1.5),)),
        Case(channel, "noise", (("sigma_v", 0.5), ("seed", 1))),
        Case(channel, "drift", (("rate_v_s", 1.0),)),
        Case(channel, "intermittent", (("period_s", 0.1), ("duty", 0.5))),
        Case(channel, "lost_bits", (("bits", 6),)),
        Case(channel, "delay", (("samples", 10),)),
        Case(channel, "short_channels", (("other", other),)),
    ]


CASES: Final[tuple[Case, ...]] = (
    *_ad_cases("AI3", "AI4"),
    *_ad_cases("AI1", "AI2"),
    Case("AO1", "open"),
    Case("AO1", "stuck"),
    Case("AO1", "offset", (("offset_v", 2.0),)),
    Case("AO1", "gain", (("factor", 0.5),)),
    Case("AO1", "saturate", (("limit_v", 1.0),)),
    Case("AO1", "delay", (("samples", 10),)),
)
"""The table's rows."""


def _run(controller: dict[str, Any], plant: dict[str, Any] | None = None) -> tuple[Any, RunRecord]:
    """A co-simulated run with every monitor on and counting: its controller (monitors, record) and its record."""
    own = {"tf_download_samples": 0, "input_monitors": ALL_ON, "policies": COUNT, **controller}
    with HilRig(controller=own, plant_settings=dict(plant or {}), mcap=False) as rig:
        record = rig.run()
        return rig.controller_service, record


def latencies(case: Case) -> dict[str, float | None]:
    """Per monitor, ms from the insertion to the first firing (None: not detected)."""
    ctrl, _ = _run({"duration_s": RUN_S}, {"scenario": {"channel_faults": [case.fault()]}})
    inputs = ctrl.inputs
    ts = ctrl.settings.sample_period_s
    before = [e for e in inputs.events if (e[0] + 1) * ts < INSERT_S - 1e-9]
    if before:
        raise RuntimeError(f"{case.label()}: a monitor fired before the fault: {before[0]}")
    out: dict[str, float | None] = {}
    for name in INPUT_MONITORS:
        tick = inputs.first_tick(name)
        out[name] = None if tick is None else ((tick + 1) * ts - INSERT_S) * 1e3
    return out


def clean_lap() -> dict[str, Any]:
    """A clean lap's largest figures against each monitor's default limit."""
    ctrl, record = _run({"repeats": 1})
    cols = ctrl.record.to_columns()
    ts = ctrl.settings.sample_period_s
    words = np.stack([cols[f"ai{j}_word"] for j in range(1, 5)]).astype(np.int64)
    ref = np.stack([cols["phi_ref1"], cols["phi_ref2"]])
    moved = np.any(np.diff(ref, axis=1) != 0, axis=0)
    longest = []
    for row in words:
        run_len = best = 0
        for same, move in zip(np.diff(row) == 0, moved, strict=True):
            run_len = 0 if not same else run_len + (1 if move else 0)
            best = max(best, run_len)
        longest.append(best)
    rate = np.abs(np.diff(words, axis=1)).max(axis=1) * WORD16_VOLTS_PER_LSB / ts
    sag = np.array([static_sag_in(a, b) for a, b in zip(cols["theta1"].tolist(), cols["theta2"].tolist(), strict=True)])
    gap = np.abs(np.stack([cols["defl1_in"], cols["defl2_in"]], axis=1) - sag).max(axis=0)
    return {
        "ticks": record.ticks,
        "events": list(ctrl.inputs.events),
        "longest_unchanged": longest,
        "max_rate_v_s": rate.tolist(),
        "max_gap_in": gap.tolist(),
        "extension_in": (float(min(cols["ext1_in"].min(), cols["ext2_in"].min())), float(max(cols["ext1_in"].max(), cols["ext2_in"].max()))),
        "words": (int(words.min()), int(words.max())),
    }


def _ms(value: float | None) -> str:
    return "not detected" if value is None else f"{value:.0f}"


def detection_table(cases: Sequence[Case] = CASES) -> str:
    """The page: the latency table, then the clean lap against the limits."""
    limits = InputMonitors()
    lines = [
        "# Fault detection latency",
        "",
        "Generated by `python -m workbench.fault_detection --write docs/results/fault-detection.md`",
        "(co-simulation of the thesis trajectory, every input monitor on with policy `count`,",
        f"default limits; each fault inserted at {INSERT_S:g} s simulated, the arm moving, and left {RUN_S - INSERT_S:g} s).",
        "Simulated ms from the insertion to the sample whose check fired (0: the first faulted sample);",
        "how it is measured: [fault-insertion.md](../fault-insertion.md#detection-latency).",
        "",
        "| fault | " + " | ".join(f"`{m}`" for m in INPUT_MONITORS) + " |",
        "| --- | " + " | ".join("---" for _ in INPUT_MONITORS) + " |",
    ]
    for case in cases:
        lat = latencies(case)
        lines.append(f"| {case.label()} | " + " | ".join(_ms(lat[m]) for m in INPUT_MONITORS) + " |")
    lap = clean_lap()
    rate_limits = (limits.extension_rate_v_s,) * 2 + (limits.deflection_rate_v_s,) * 2
    lines += [
        "",
        "## A clean lap against the limits",
        "",
        f"One lap ({lap['ticks']} ticks) without a fault, every input monitor on: {len(lap['events'])} firings.",
        "",
        "| input | longest unchanged word while the set-point moves (ticks) | `stuck_samples` | largest change (V/s) | rate limit (V/s) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for j, name in enumerate(("AI1", "AI2", "AI3", "AI4")):
        lines.append(f"| `{name}` | {lap['longest_unchanged'][j]} | {limits.stuck_samples} | {lap['max_rate_v_s'][j]:.1f} | {rate_limits[j]:g} |")
    lines += [
        "",
        f"Largest |measured - implied| deflection: link 1 {lap['max_gap_in'][0]:.3f} in, link 2 {lap['max_gap_in'][1]:.3f} in "
        f"(`disagree_in` {limits.disagree_in:g} in). Extensions read {lap['extension_in'][0]:.2f} .. {lap['extension_in'][1]:.2f} in "
        f"(`extension_range_in` {limits.extension_range_in[0]:g} .. {limits.extension_range_in[1]:g}); words {lap['words'][0]} .. {lap['words'][1]} "
        "(the clip: 32752 and -32768).",
        "",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m workbench.fault_detection", description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", metavar="PATH", type=Path, help="write the page here (default: print it)")
    args = parser.parse_args(argv)
    page = detection_table()
    if args.write is None:
        sys.stdout.write(page)
        return 0
    try:
        args.write.write_text(page, encoding="utf-8")
    except OSError as exc:
        print(f"fault_detection: cannot write {args.write}: {exc.strerror}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
