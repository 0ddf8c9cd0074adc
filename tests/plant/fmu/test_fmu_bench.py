"""``ralf-hil bench --only fmu --quick`` reports every figure with its floor
(no timing threshold: only that the numbers are measured and complete)."""

from __future__ import annotations

import math

import pytest


@pytest.mark.timeout(300)
def test_the_fmu_bench_item_measures_both_models_and_the_cosim() -> None:
    from workbench.bench.items import BenchContext, run_item

    result = run_item("fmu", BenchContext(quick=True, iterations=200, warmup=20))
    assert result["status"] == "ok", result["errors"]
    m = result["measurements"]
    fmu = m["plant step, FMU (SYNC -> TPDO1)"]
    assert fmu["n"] == 500 and fmu["floor"] == "plant step, built-in arm (SYNC -> TPDO1)"
    assert all(math.isfinite(v) and v > 0 for v in fmu["ratio"].values() if v is not None)
    assert m["  FMU doStep with input set and output get"]["n"] >= 500
    speed = m["cosim sim_s/wall_s, example FMU"]
    assert speed["floor_value"] == 50.0 and speed["value"] > 0 and speed["ratio"] > 0
    assert m["cosim sim_s/wall_s, built-in arm"]["value"] > 0
    against = m["cosim with the FMU vs fmpy.simulate_fmu"]
    assert against["value"] > 0 and against["floor_value"] > 0 and against["ratio"] == pytest.approx(against["value"] / against["floor_value"])
    assert against["sim_s"] == pytest.approx(10.0)


def test_fmpy_takes_the_cosimulation_inputs(two_mode_fmu: object) -> None:
    """The FMPy floor runs the FMU over the run's own time with a non-empty input table."""
    from plant_emulator.fmu.build import EXAMPLE_MAPPING
    from workbench.bench.model_floor import fmpy_floor

    out = fmpy_floor(two_mode_fmu, EXAMPLE_MAPPING, {"duration_s": 1.0}, rounds=1)  # type: ignore[arg-type]
    assert out["ticks"] == 200 and out["sim_s"] == pytest.approx(1.0) and out["input_rows"] >= 1
    assert out["cosim_s"] > 0 and out["fmpy_s"] > 0 and out["ratio"] == pytest.approx(out["cosim_s"] / out["fmpy_s"])
