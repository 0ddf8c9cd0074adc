"""The ARX's regime bank: remembered models learned on line, switched to when the plant returns to a regime.

Reference: the plant is the synthetic 2×2 system of ``synth`` (``scipy.signal.cont2discrete`` ZOH models of
known modes, simulated with ``scipy.signal.lfilter``), alternating between two regimes (a payload on and
off: the first mode +9.5 %, the second 9 → 6 Hz); the truth is the modes the ZOH models were built from.
"""

from __future__ import annotations

import math

import numpy as np

from dsp_service.arx import RecursiveArx
from dsp_service.identifier import IdentifierConfig, arx_config

from .synth import FS, MODES, correlated_inputs, make_system

SEGMENT = 6000  # 30 s per regime
REGIME_B = ((MODES[0][0] * 1.095, MODES[0][1]), (6.0, 0.05))
BATCH = 20


def _alternating(segments: int, noise_seed: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs, outputs (2 % noise) and the true first mode per sample of the plant switching A, B, A, B, …"""
    n = segments * SEGMENT
    u = correlated_inputs(n, seed=3)
    ya, yb = make_system().simulate(u), make_system(modes=REGIME_B).simulate(u)
    y = np.empty_like(u)
    f1 = np.empty(n)
    for k in range(segments):
        s = slice(k * SEGMENT, (k + 1) * SEGMENT)
        y[:, s] = (ya if k % 2 == 0 else yb)[:, s]
        f1[s] = MODES[0][0] if k % 2 == 0 else REGIME_B[0][0]
    y += 0.02 * y.std(axis=1, keepdims=True) * np.random.default_rng(noise_seed).standard_normal(y.shape)
    return u, y, f1


def _run(m: RecursiveArx, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """First pole per batch and the sample indices (batch ends) at which the bank switched."""
    f = np.full(u.shape[1] // BATCH, math.nan)
    switches = []
    for k in range(f.size):
        before = m.bank_switches
        m.update(u[:, k * BATCH : (k + 1) * BATCH], y[:, k * BATCH : (k + 1) * BATCH])
        if m.bank_switches > before:
            switches.append((k + 1) * BATCH)
        p = m.poles()
        f[k] = p[0].frequency_hz if p else math.nan
    return f, switches


def _settle_s(f: np.ndarray, f1: np.ndarray, start: int) -> float:
    """Seconds after sample ``start`` until the ±0.25 s running median of the first pole stays within 2 % for 2 s."""
    truth = f1[(np.arange(f.size) + 1) * BATCH - 1]
    med = np.array([np.nanmedian(f[max(0, k - 12) : k + 13]) for k in range(f.size)])
    ok = np.abs(med / truth - 1.0) <= 0.02
    hold = int(2.0 * FS / BATCH)
    for k in range(start // BATCH, min(f.size - hold, (start + SEGMENT) // BATCH)):
        if ok[k : k + hold + 1].all():
            return (k + 1) * BATCH / FS - start / FS
    return math.inf


def test_a_regime_seen_before_is_recalled_within_a_second() -> None:
    """The rig configuration with a bank of 4, three noise realisations of A, B, A, B, A, B (30 s each): the first
    visit of each regime is learned (no switch), every return switches to the remembered model within 1 s (0.4-0.7 s
    here) and none happens elsewhere; the first pole is then within 2 % of the regime's true first mode in ≤ 1 s,
    where the plain model takes at least twice as long (2.5-6.8 s; median over the returns)."""
    cfg = arx_config(IdentifierConfig(method="arx", arx_regime_bank=4))
    returns = [k * SEGMENT for k in range(2, 6)]
    for seed in (4, 5, 6):
        u, y, f1 = _alternating(6, noise_seed=seed)
        banked = RecursiveArx(cfg)
        f, switches = _run(banked, u, y)
        assert len(banked.bank) == 2  # two regimes, each refreshed, never duplicated
        assert len(switches) == len(returns)  # no switch at the first visits, none in steady running
        for s, at in zip(switches, returns):
            assert 0 < s - at <= FS
        plain_f, _ = _run(RecursiveArx(cfg.model_copy(update={"regime_bank": 0})), u, y)
        banked_settle = [_settle_s(f, f1, at) for at in returns]
        plain_settle = [_settle_s(plain_f, f1, at) for at in returns]
        assert max(banked_settle) <= 1.0
        assert np.median(plain_settle) >= 2.0 * np.median(banked_settle)


def test_off_by_default_and_the_bank_stays_bounded_and_sound() -> None:
    """``regime_bank`` 0 (the rig default) keeps no snapshot; with a bank of 2 over 8 alternations the bank never
    exceeds its size and ``R`` stays finite and upper triangular, ``θ`` finite."""
    u, y, _ = _alternating(8)
    plain = RecursiveArx(arx_config(IdentifierConfig(method="arx")))
    _run(plain, u[:, : 2 * SEGMENT], y[:, : 2 * SEGMENT])
    assert plain.bank == [] and plain.bank_switches == 0
    m = RecursiveArx(arx_config(IdentifierConfig(method="arx", arx_regime_bank=2)))
    _run(m, u, y)
    assert len(m.bank) <= 2
    for r in [m.R, *(reg.R for reg in m.bank)]:
        assert np.all(np.isfinite(r)) and np.allclose(r, np.triu(r))
    assert np.all(np.isfinite(m.theta))


def test_the_service_setting_reaches_the_identifier() -> None:
    """``RALF_ARX_REGIME_BANK`` (a DspSettings field) is the identifier's ``arx_regime_bank``: the bank runs on the rig, not only in replays."""
    from dsp_service.core import identifier_config
    from protocol.settings import DspSettings

    assert identifier_config(DspSettings(identifier="arx", arx_regime_bank=4)).arx_regime_bank == 4
    assert identifier_config(DspSettings()).arx_regime_bank == 0
