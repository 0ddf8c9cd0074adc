"""The control tick (controller/fast_tick.py through :class:`ControlLaw`)
against references built from scipy: the OATF (thesis [3-34]) as the dense
FIR ``scipy.signal.lfilter`` runs, the PI (§4) as ``lfilter``'s first-order
recursion, the 12-bit D/A as ``numpy.round`` of the LSB count. Tolerances:
1e-12 relative where the reference adds the same terms in another order;
the D/A codes and flags exactly."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy import signal

from controller import fast_tick
from controller.config import build_trajectory, law_config
from controller.engineering import measure_values
from controller.excitation import dither_table
from controller.loop import ROW_NAMES, ControlLaw
from protocol import can_map
from protocol.settings import ControllerSettings

COL = {name: i for i, name in enumerate(ROW_NAMES)}
RTOL = 1e-12


def _law(**settings: Any) -> ControlLaw:
    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", **settings)
    return ControlLaw(law_config(cs), build_trajectory(cs))


def _base_words(law: ControlLaw) -> np.ndarray:
    """The 12-bit words (``code << 4``) whose angles are nearest the first set-point (phi1 reads word 0, phi2 word 1)."""
    grid = [code << 4 for code in range(-2048, 2048)]
    phi = np.array([measure_values((w, w, 0, 0))[10:12] for w in grid])
    near = np.abs(phi - law.setpoint(0)).argmin(axis=0)
    return np.array([grid[near[0]], grid[near[1]], 0, 0])


def _words(n: int, spread: int, seed: int, base: np.ndarray | None = None) -> list[list[int]]:
    """Words about ``base`` (default: a fixed point) with ``spread`` LSB of noise."""
    rng = np.random.default_rng(seed)
    base = np.array([9000, 9000, 0, 0]) if base is None else base
    return [[int(x) for x in np.clip(base + rng.integers(-spread, spread + 1, size=4), -32768, 32767)] for _ in range(n)]


def _run(law: ControlLaw, words: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Rows and per-tick (c0, c1, s0, s1) of ``len(words)`` ticks from tick 0."""
    rows, codes = [], []
    for tick, w in enumerate(words):
        law.tick_compiled(tick, *w)
        rows.append(law.row.copy())
        codes.append(law.codes.copy())
    return np.array(rows), np.array(codes)


def _dense_fir(law: ControlLaw) -> np.ndarray:
    assert law.oatf is not None
    delays, weights = law.oatf.kernel
    b = np.zeros(int(delays.max()) + 1)
    np.add.at(b, delays, weights)
    return b


def _fir_with_history(b: np.ndarray, x: np.ndarray, initial: np.ndarray) -> np.ndarray:
    """``lfilter(b, 1, x)`` per channel, the past filled with ``initial`` (the delay line's reset value)."""
    past = np.broadcast_to(initial, (len(b) - 1, x.shape[1]))
    return signal.lfilter(b, [1.0], np.vstack([past, x]), axis=0)[len(b) - 1 :]


def _pi_reference(law: ControlLaw, errors: np.ndarray) -> np.ndarray:
    """``u = Kp e + Ki I``, ``I_k = (1 - lambda) I_{k-1} + Ts e_k`` (errors inside the gate, no saturation)."""
    cfg = law.pi.config
    integral = signal.lfilter([cfg.integral_scale], [1.0, -(1.0 - cfg.forgetting_factor)], errors, axis=0)
    return cfg.kp_v_per_rad * errors + cfg.ki_v_per_rad * integral


def _dac_reference(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dac = can_map.DAC12
    counts = np.round(np.clip(x, -2 * dac.full_scale_v, 2 * dac.full_scale_v) / dac.lsb_v)
    return np.clip(counts, dac.code_min, dac.code_max), (counts < dac.code_min) | (counts > dac.code_max)


@pytest.mark.parametrize("mode", ["off", "fixed"])
def test_outer_oatf_pi_and_dac_equal_the_scipy_references(mode: str) -> None:
    law = _law(oatf_mode=mode)
    words = _words(600, spread=40, seed=1, base=_base_words(law))
    rows, codes = _run(law, words)
    ref = np.array([law.setpoint(k) for k in range(len(words))])
    np.testing.assert_array_equal(rows[:, [COL["phi_ref1"], COL["phi_ref2"]]], ref)
    shaped = ref if mode == "off" else _fir_with_history(_dense_fir(law), ref, ref[0])
    np.testing.assert_allclose(rows[:, [COL["phi_shaped1"], COL["phi_shaped2"]]], shaped, rtol=RTOL, atol=1e-15)
    phi = rows[:, [COL["phi1"], COL["phi2"]]]
    np.testing.assert_array_equal(phi, [measure_values(w)[10:12] for w in words])
    errors = rows[:, [COL["phi_shaped1"], COL["phi_shaped2"]]] - phi
    assert np.abs(errors).max() < law.pi.config.integrate_threshold_rad  # inside the gate throughout
    pi = rows[:, [COL["pi1_v"], COL["pi2_v"]]]
    assert np.abs(pi).max() < law.pi.config.output_limit_v  # never saturated
    np.testing.assert_allclose(pi, _pi_reference(law, errors), rtol=RTOL, atol=1e-13)
    want_codes, want_flags = _dac_reference(pi)
    np.testing.assert_array_equal(codes[:, :2], want_codes)
    np.testing.assert_array_equal(codes[:, 2:], want_flags)
    np.testing.assert_array_equal(rows[:, [COL["u1_v"], COL["u2_v"]]], codes[:, :2] * can_map.DAC12.lsb_v)


def test_inner_oatf_filters_the_pi_commands_and_dither_adds_before_the_dac() -> None:
    law = _law(oatf_mode="fixed", oatf={"location": "inner"}, dither={"amplitude_v": 0.5, "seed": 9})
    words = _words(500, spread=20000, seed=2)  # wild words: large errors, the integrator gated
    pi_out = []
    rows = []
    codes = []
    for tick, w in enumerate(words):
        law.tick_compiled(tick, *w)
        pi_out.append(law.pi.output_v)
        rows.append(law.row.copy())
        codes.append(law.codes.copy())
    fs = can_map.DAC12.full_scale_v
    shaped = np.clip(_fir_with_history(_dense_fir(law), np.array(pi_out), np.zeros(2)), -fs, fs)
    got = np.array(rows)[:, [COL["pi1_v"], COL["pi2_v"]]]
    np.testing.assert_allclose(got, shaped, rtol=RTOL, atol=1e-13)
    dither = dither_table(law.config.dither, law.config.sample_period_s)
    sent = got + dither[np.arange(len(words)) % len(dither)]
    want_codes, want_flags = _dac_reference(sent)
    mismatch = np.array(codes)[:, :2] != want_codes
    # A sum within 1e-12 of a half LSB may round either way against the reference: only there may they differ.
    assert not mismatch.any() or np.all(np.abs(np.abs(sent / can_map.DAC12.lsb_v % 1.0) - 0.5)[mismatch] < 1e-9)
    np.testing.assert_array_equal(np.array(codes)[:, 2:][~mismatch], want_flags[~mismatch])
    r = np.array(rows)
    gated = np.abs(r[:, [COL["phi_shaped1"], COL["phi_shaped2"]]] - r[:, [COL["phi1"], COL["phi2"]]]) > law.pi.config.integrate_threshold_rad
    assert gated.any() and not gated.all()  # the integrator's gate both closed and open


def test_a_redesign_changes_the_fir_from_the_next_tick_on() -> None:
    law = _law(oatf_mode="adaptive")
    words = _words(400, spread=40, seed=3)
    rows_a, _ = _run(law, words[:200])
    assert law.oatf is not None
    before = _dense_fir(law)
    law.oatf.update_modes([3.1])
    after = _dense_fir(law)
    rows = []
    for tick, w in enumerate(words[200:], start=200):
        law.tick_compiled(tick, *w)
        rows.append(law.row.copy())
    ref = np.array([law.setpoint(k) for k in range(400)])
    full = np.vstack([np.broadcast_to(ref[0], (len(law.oatf._buf), 2)), ref])  # the delay line started at ref[0]
    start = len(law.oatf._buf)
    want = np.array([after @ full[start + k - np.arange(len(after))] for k in range(200, 400)])
    np.testing.assert_allclose(np.array(rows)[:, [COL["phi_shaped1"], COL["phi_shaped2"]]], want, rtol=RTOL, atol=1e-15)
    assert not np.array_equal(before, after)
    np.testing.assert_allclose(rows_a[-1, [COL["phi_shaped1"], COL["phi_shaped2"]]], before @ full[start + 199 - np.arange(len(before))], rtol=RTOL)


def test_the_tick_fills_angles_once_and_refuses_non_finite_errors() -> None:
    law = _law(oatf_mode="off")
    w = [12345, -4321, 7, -7]
    law.tick_compiled(0, *w)
    assert fast_tick.ANGLE_TABLE[0, w[0] + 32768] == measure_values(w)[8]
    assert fast_tick.ANGLE_TABLE[1, w[1] + 32768] == measure_values(w)[9]
    law._data[fast_tick.SETPOINTS + 2] = np.nan  # tick 1's set-point is not a number: the PI refuses it
    before = law.pi.state.copy()
    with pytest.raises(ValueError, match="non-finite angle error"):
        law.tick_compiled(1, *w)
    assert np.array_equal(law.pi.state, before)
