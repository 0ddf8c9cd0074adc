"""``ralf-hil experiment fmu-plant --quick``: the identification and the
adaptive OATF on the example FMU plant, reported against the FMU's truth."""

from __future__ import annotations

import json
from pathlib import Path

import pytest


@pytest.mark.timeout(300)
def test_fmu_plant_experiment_quick(tmp_path: Path) -> None:
    from workbench.experiments import run_experiment

    out = tmp_path / "fmu-plant"
    outcome = run_experiment("fmu-plant", out, quick=True, show_progress=False)
    assert outcome.ok, outcome
    results = json.loads((out / "results.json").read_text())
    assert all(c["passed"] for c in results["checks"])
    ident = results["results"]["identification"]["fmu_adaptive"]
    assert ident["f1_median_abs_error_hz"] < 2 * 200.0 / 2048
    costs = results["results"]["costs"]
    for link in (0, 1):  # the adaptive OATF, tuned by what the DSP found, lowers the FMU's vibration
        assert costs["fmu_adaptive"]["velocity_pct"][link] < 100.0
    assert (out / "fmu_plant_tracking.png").is_file() and "What the DSP found" in (out / "report.md").read_text()
