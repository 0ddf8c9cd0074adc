"""The identification step's bench (``ralf-hil bench --only dsp``) returns the structure it documents."""

from __future__ import annotations

from workbench.bench.dsp_step import bench_identifier


def test_bench_returns_the_documented_structure() -> None:
    out = bench_identifier(n=256, repeats=5)
    for key in ("step_p50_us", "step_p99_us", "floor_p50_us", "floor_p99_us", "ratio_p50", "ratio_p99", "c40_fraction"):
        assert isinstance(out[key], float) and out[key] > 0, key
    assert out["n"] == 256 and out["repeats"] == 5
    assert isinstance(out["poles_found"], int)
