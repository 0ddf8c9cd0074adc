"""The stand-alone tools folded into ``ralf-hil`` subcommands: the old
``python -m`` invocations name the new command in one line and exit 2; the
new subcommands parse and run."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from workbench.cli import build_parser, main

MOVED = {
    "plant_emulator.model.report": "ralf-hil plant report",
    "plant_emulator.model.speed_probe": "ralf-hil plant speed-probe",
    "plant_emulator.model.calibration": "ralf-hil plant calibration",
    "plant_emulator.fmu.build": "ralf-hil plant fmu-build",
    "dsp_service.bench": "ralf-hil bench --only dsp",
    "workbench.bench": "ralf-hil bench",
    "workbench.experiments": "ralf-hil experiment",
    "workbench.bench.hotpath": "ralf-hil measure hotpath",
    "workbench.bench.cosim_parts": "ralf-hil measure cosim-parts",
    "workbench.recording.bench": "ralf-hil measure recording",
    "workbench.live.bench": "ralf-hil measure live",
    "workbench.campaign.measure": "ralf-hil measure campaign",
}


@pytest.mark.parametrize("module", sorted(MOVED))
def test_the_old_invocation_names_its_subcommand_and_exits_2(module: str) -> None:
    proc = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.splitlines() == [f"python -m {module} is now `{MOVED[module]}`"]


@pytest.mark.parametrize(
    "argv",
    [
        ["plant", "report", "--out", "figs"],
        ["plant", "speed-probe", "--only", "model", "noiseless", "--seed", "3"],
        ["plant", "calibration", "--fit"],
        ["plant", "fmu-build", "src", "out.fmu"],
        ["measure", "hotpath", "--controller-side", "5"],
        ["measure", "cosim-parts", "--plant", "4"],
        ["measure", "recording", "--pairs", "1", "--writer-only"],
        ["measure", "live", "--rounds", "1"],
        ["measure", "live", "--rounds", "1", "--json", "live.json"],
        ["measure", "input-flood", "--rounds", "1", "--messages", "100", "--other", "ralf-hil", "--json", "flood.json"],
        ["measure", "campaign", "--blocks", "1", "--runs", "2"],
    ],
)
def test_every_folded_tool_parses(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    assert callable(args.func)


def test_plant_calibration_prints_the_metrics_as_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plant", "calibration"]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["mean_f1_hz"] == pytest.approx(4.4, abs=0.05)  # the fit's target (thesis §3)
    assert metrics["mean_f1_payload_hz"] == pytest.approx(3.6, abs=0.05)


def test_an_unknown_speed_probe_variant_is_refused_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plant", "speed-probe", "--only", "warp-drive"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown variant(s) warp-drive" in err[0]
