"""The experiments' shared analysis (workbench/experiments/lib) against hand-computed and analytic references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from controller.oatf import OatfConfig, OatfFilter
from workbench.experiments.lib.acceleration_readings import baselines, pooled
from workbench.experiments.lib.campaign_cells import cell, cell_mean, main_effects, pct_of_baseline_cells, seed_spread
from workbench.experiments.lib.oatf_design_facts import abs_at_pole, design_facts


def _row(point: str, a: int, b: float, seed: int, cost: float | None) -> dict[str, object]:
    return {"status": "ok", "point": point, "ax": a, "bx": b, "seed": seed, "cost": cost}


def test_cells_are_percent_of_the_same_seeds_baseline_averaged_over_seeds() -> None:
    rows = [
        _row("a", 12, 1.0, 1, 2.0),
        _row("a", 12, 1.0, 2, 4.0),
        _row("b", 12, 1.0, 1, 1.0),  # 50 % of its seed's baseline
        _row("b", 12, 1.0, 2, 3.0),  # 75 %
        _row("b", 20, 1.0, 1, 1.0),  # no baseline at 20: left out
        {"status": "error", "point": "b", "ax": 12, "bx": 1.0, "seed": 3},
    ]
    cells = pct_of_baseline_cells(rows, ("ax", "bx"), "seed", "a", ("cost",))
    c = cell(cells, "b", 12, 1.0)
    assert c is not None and cell(cells, "b", 20, 1.0) is None
    assert c["cost_pct"] == pytest.approx(62.5) and c["cost"] == pytest.approx(2.0) and c["seeds"] == 2
    assert c["cost_pct_seed_spread"] == pytest.approx(25.0)
    assert seed_spread(cells, "cost_pct") == pytest.approx(0.0 + 25.0 / 2)  # median of (a: 0, b: 25)
    assert cell_mean(cells, ["a", "b"], [12], [1.0], "cost_pct") == pytest.approx((100.0 + 62.5) / 2)
    assert math.isnan(cell_mean(cells, ["c"], [12], [1.0], "cost_pct"))


def test_a_missing_cost_is_nan_not_zero() -> None:
    cells = pct_of_baseline_cells([_row("a", 12, 1.0, 1, 2.0), _row("b", 12, 1.0, 1, None)], ("ax", "bx"), "seed", "a", ("cost",))
    c = cell(cells, "b", 12, 1.0)
    assert c is not None and math.isnan(c["cost_pct"]) and math.isnan(c["cost"])


def test_main_effects_are_ranges_of_the_axis_means() -> None:
    rows = [_row("a", a, b, 1, 1.0) for a in (12, 20) for b in (1.0, 4.0)]
    # cost % = 10 + 30 (if a = 20) + 5 (if b = 4) + 2 (identifier y): effects 30, 5, 2
    rows += [_row(f"e {i}", a, b, 1, (10 + 30 * (a == 20) + 5 * (b == 4.0) + 2 * (i == "y")) / 100) for i in ("x", "y") for a in (12, 20) for b in (1.0, 4.0)]
    cells = pct_of_baseline_cells(rows, ("ax", "bx"), "seed", "a", ("cost",))
    effects = main_effects(cells, ["e x", "e y"], [12, 20], [1.0, 4.0], lambda lab: lab[2:], "cost_pct")
    assert effects == pytest.approx((30.0, 5.0, 2.0))


def test_an_oatf_design_cancels_its_own_pole_and_not_another() -> None:
    ts = 0.005
    filt = OatfFilter([5.0], 2, OatfConfig(sample_period_s=ts, design_zeta=0.09))
    stage = filt.stages[0]
    assert abs_at_pole(stage, 5.0, 0.09) < 1e-9
    assert abs_at_pole(stage, 8.0, 0.09) > 0.1
    facts = design_facts(filt, 5.0, 0.09)
    # |F| at 5 Hz against scipy's filter of the same taps: the steady-state amplitude of a 5 Hz sine
    taps = np.zeros(2 * stage.delay_samples + 1)
    taps[:: stage.delay_samples] = stage.coefficients
    t = np.arange(4000) * ts
    y = lfilter(taps, [1.0], np.sin(2 * np.pi * 5.0 * t))
    assert facts["abs_F_at_mode"] == pytest.approx(np.max(np.abs(y[2000:])), rel=1e-3)
    assert facts["delay_samples"] == stage.delay_samples and facts["abs_coefficient_sum"] == pytest.approx(sum(abs(a) for a in stage.coefficients))


def test_pooled_unfiltered_rows_and_the_noise_part_in_quadrature() -> None:
    unf = {
        "group1": {"velocity_rms_in_s": [3.0, 4.0], "acceleration_rms_in_s2": [30.0, 40.0]},
        "group2": {"velocity_rms_in_s": [5.0, 5.0], "acceleration_rms_in_s2": [50.0, 50.0]},
    }
    bl = baselines(unf, {"group1": (1.0, 10.0), "group2": (2.0, 20.0)})
    assert pooled([3.0, 4.0]) == pytest.approx(math.sqrt(12.5))
    rows = {r["label"]: r for r in bl["rows"]}
    assert rows["group1 velocity"]["pooled"] == pytest.approx(math.sqrt(12.5))
    assert rows["noise part, velocity"]["pooled"] == pytest.approx(math.sqrt(25.0 - 12.5))
    assert rows["noise part, velocity"]["thesis"] == pytest.approx(math.sqrt(3.0))
    assert bl["noise_ratio_rad_s"] == pytest.approx(10.0) and bl["thesis_noise_ratio_rad_s"] == pytest.approx(10.0)
