"""The valve commands' dither (controller/excitation.py): its spectrum against
scipy's Welch estimate, its RMS, its determinism, the two valves' independence,
bad settings refused, and that it reaches the D/A only when switched on (the
tick with the dither against scipy references is in ``test_law_reference.py``)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from controller.config import build_trajectory, law_config
from controller.excitation import DitherConfig, dither_table
from controller.loop import ROW_NAMES, ControlLaw
from protocol.settings import ControllerSettings

TS = 0.005


def test_the_dither_has_its_rms_and_its_power_in_its_band() -> None:
    cfg = DitherConfig(amplitude_v=0.2, band_hz=(3.0, 6.0), seed=4)
    table = dither_table(cfg, TS)
    assert table.shape == (4096, 2)
    np.testing.assert_allclose(np.sqrt(np.mean(table**2, axis=0)), [0.2, 0.2], rtol=1e-12)
    x = np.tile(table, (4, 1))
    f, p = ss.welch(x, fs=1 / TS, nperseg=4096, noverlap=0, window="boxcar", axis=0)  # one period per segment: exact bins
    inside = (f >= 3.0) & (f <= 6.0)
    assert np.all(p[inside] > 0)
    assert p[~inside].sum() < 1e-20 * p[inside].sum()
    # a flat amplitude spectrum: every bin of the band carries the same power
    np.testing.assert_allclose(p[inside] / p[inside].mean(), 1.0, rtol=1e-9)


def test_the_dither_is_deterministic_and_the_valves_are_uncorrelated() -> None:
    cfg = DitherConfig(amplitude_v=0.1, seed=1)
    a, b = dither_table(cfg, TS), dither_table(cfg, TS)
    assert a.tobytes() == b.tobytes()
    assert dither_table(DitherConfig(amplitude_v=0.1, seed=2), TS).tobytes() != a.tobytes()
    rho = np.corrcoef(a[:, 0], a[:, 1])[0, 1]
    assert abs(rho) < 0.1  # independent random phases; collinear valves would give |ρ| = 1
    assert not dither_table(DitherConfig(), TS).any()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"amplitude_v": -0.1}, "amplitude"),
        ({"amplitude_v": float("nan")}, "amplitude"),
        ({"band_hz": (5.0, 2.0)}, "band"),
        ({"period_ticks": 4}, "period"),
    ],
)
def test_bad_dither_settings_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        DitherConfig(**kwargs)  # type: ignore[arg-type]


def test_a_band_above_nyquist_is_refused() -> None:
    with pytest.raises(ValueError, match="no bin"):
        dither_table(DitherConfig(amplitude_v=0.1, band_hz=(120.0, 150.0)), TS)


def test_the_dither_reaches_the_d_a_only_when_on() -> None:
    """Same words, same law: off gives the D/A the PI's output; on adds the table's value (the PI's own output unchanged)."""
    runs = {}
    for amp in (0.0, 0.4):
        cs = ControllerSettings(duration_s=10.0, can_interface="virtual", oatf_mode="off", dither_amplitude_v=amp)
        law = ControlLaw(law_config(cs), build_trajectory(cs))
        rows = [law.step_row(tick, [9000, 9000, 0, 0]) for tick in range(300)]
        runs[amp] = np.array([[r[ROW_NAMES.index(k)] for k in ("u1_v", "u2_v", "pi1_v", "pi2_v")] for r in rows])
    off, on = runs[0.0], runs[0.4]
    np.testing.assert_array_equal(off[:, 2:], on[:, 2:])
    table = dither_table(DitherConfig(amplitude_v=0.4), TS)[:300]
    lsb = 20.0 / 4096
    np.testing.assert_allclose(on[:, :2] - off[:, :2], table, atol=lsb)
    assert np.sqrt(np.mean((on[:, :2] - off[:, :2]) ** 2)) > 0.3


def test_the_settings_refuse_a_reversed_dither_band() -> None:
    from protocol.settings import ConfigError, load_settings

    with pytest.raises(ConfigError, match="dither band"):
        load_settings(ControllerSettings, {"dither_band_hz": "7,2"})
    assert load_settings(ControllerSettings, {"dither_band_hz": "3,6"}).dither_band_hz == (3.0, 6.0)
