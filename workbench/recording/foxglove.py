"""A Foxglove layout for a recording: four plot panels (tip deflections,
joint angles, identified vs true first mode, TET and SYNC lateness).

``docs/foxglove-layout.json`` is this layout for rig ``default``;
``ralf-hil plot RUN.mcap --foxglove-layout FILE`` writes it for the rig id
of a recording. Import it in Foxglove (Layouts -> Import from file) and
open the MCAP file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def _plot(title: str, paths: list[tuple[str, str]]) -> dict[str, Any]:
    return {
        "title": title,
        "paths": [{"value": value, "label": label, "enabled": True, "timestampMethod": "receiveTime"} for value, label in paths],
        "showXAxisLabels": True,
        "showYAxisLabels": True,
        "showLegend": True,
        "legendDisplay": "floating",
        "showPlotValuesInLegend": False,
        "isSynced": True,
        "xAxisVal": "timestamp",
        "sidebarDimension": 240,
    }


def layout(rig_id: str = "default") -> dict[str, Any]:
    """The layout for a rig id (topics are ``/ralf/<rig-id>/...``)."""
    root = f"/ralf/{rig_id}"
    panels = {
        "Plot!deflections": _plot(
            "Tip deflections (in)",
            [
                (f"{root}/plant/truth.deflections_in[0]", "link 1 (true)"),
                (f"{root}/plant/truth.deflections_in[1]", "link 2 (true)"),
            ],
        ),
        "Plot!joints": _plot(
            "Joint angles (rad)",
            [(f"{root}/plant/truth.theta_rad[0]", "theta 1"), (f"{root}/plant/truth.theta_rad[1]", "theta 2")],
        ),
        "Plot!modes": _plot(
            "First mode (Hz): identified vs true",
            [
                (f"{root}/dsp/interrupt.poles[0].frequency_hz", "identified f1"),
                (f"{root}/plant/truth.modal_frequencies_hz[0]", "true f1"),
            ],
        ),
        "Plot!timing": _plot(
            "Controller TET and SYNC lateness (s)",
            [
                (f"{root}/health/controller.latencies.tet.p50", "TET p50"),
                (f"{root}/health/controller.latencies.tet.p99", "TET p99"),
                (f"{root}/health/controller.latencies.sync_jitter.p99", "SYNC lateness p99"),
                (f"{root}/health/controller.counters.overruns", "overruns"),
            ],
        ),
    }
    return {
        "configById": panels,
        "globalVariables": {},
        "userNodes": {},
        "linkedGlobalVariables": [],
        "playbackConfig": {"speed": 1, "messageOrder": "receiveTime"},
        "layout": {
            "direction": "column",
            "first": {"direction": "row", "first": "Plot!deflections", "second": "Plot!joints", "splitPercentage": 50},
            "second": {"direction": "row", "first": "Plot!modes", "second": "Plot!timing", "splitPercentage": 50},
            "splitPercentage": 50,
        },
    }


def write_layout(path: str | Path, rig_id: str = "default") -> Path:
    p = Path(path)
    p.write_text(json.dumps(layout(rig_id), indent=2) + "\n")
    return p


def message_paths(rig_id: str = "default") -> list[str]:
    """Every message path the layout plots (for checking them against a recording)."""
    return [path["value"] for panel in layout(rig_id)["configById"].values() for path in panel["paths"]]
