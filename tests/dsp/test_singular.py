"""Singular and degenerate data never produce NaN/inf; bins are masked and confidence is low (test 5)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from dsp_service.identifier import IdentificationResult, Identifier, IdentifierConfig

N = 512
SMALL = dict(fft_width=N)


def _finite_everywhere(idf: Identifier, result: IdentificationResult) -> None:
    for f in dataclasses.fields(result):
        v = getattr(result, f.name)
        if isinstance(v, float):
            assert math.isfinite(v), f.name
    assert 0.0 <= result.confidence <= 1.0
    assert 0.0 <= result.valid_fraction <= 1.0
    for pole in result.poles:
        for f in dataclasses.fields(pole):
            v = getattr(pole, f.name)
            if isinstance(v, float):
                assert math.isfinite(v), f.name
    for smoothed in (True, False):
        tf = idf.transfer_functions(smoothed=smoothed)
        for name in ("h11", "h12", "h21", "h22", "htot"):
            assert np.all(np.isfinite(getattr(tf, name))), name
    for name, s in idf.spectra().items():
        assert np.all(np.isfinite(s)), name


def _steps(idf: Identifier, u: np.ndarray, y: np.ndarray, batch: int) -> IdentificationResult:
    result = idf.step()
    for s in range(0, u.shape[1], batch):
        idf.push(u[:, s : s + batch], y[:, s : s + batch])
        with np.errstate(divide="raise", invalid="raise", over="raise"):
            result = idf.step()
        _finite_everywhere(idf, result)
    return result


@pytest.mark.parametrize("solver", ["mimo", "uncorrelated"])
@pytest.mark.parametrize("averaging", ["exponential", "rls"])
def test_empty_history(solver: str, averaging: str) -> None:
    idf = Identifier(IdentifierConfig(solver=solver, averaging=averaging, **SMALL))
    with np.errstate(divide="raise", invalid="raise", over="raise"):
        result = idf.step()
    assert result.poles == () and result.confidence == 0.0 and result.samples_in_history == 0
    _finite_everywhere(idf, result)
    assert not idf.transfer_functions().valid.any()


@pytest.mark.parametrize("averaging", ["exponential", "rls"])
def test_single_snapshot_is_singular_and_fully_masked(averaging: str) -> None:
    """One snapshot: P11 P22 − |P12|² = 0 at every bin, so the MIMO solve is undefined."""
    rng = np.random.default_rng(3)
    u, y = rng.standard_normal((2, N)), rng.standard_normal((2, N))
    idf = Identifier(IdentifierConfig(averaging=averaging, collinear="mask", **SMALL))
    idf.push(u, y)
    with np.errstate(divide="raise", invalid="raise", over="raise"):
        result = idf.step()
    _finite_everywhere(idf, result)
    assert result.valid_fraction == 0.0
    assert result.confidence == 0.0
    assert result.effective_averages == pytest.approx(1.0)
    tf = idf.transfer_functions(smoothed=False)
    assert not tf.valid.any()
    assert np.all(tf.h11 == 0) and np.all(tf.htot == 0)


@pytest.mark.parametrize("solver", ["mimo", "uncorrelated"])
def test_all_zero_inputs(solver: str) -> None:
    rng = np.random.default_rng(4)
    u, y = np.zeros((2, 4 * N)), rng.standard_normal((2, 4 * N))
    idf = Identifier(IdentifierConfig(solver=solver, **SMALL))
    result = _steps(idf, u, y, N // 2)
    assert result.valid_fraction == 0.0 and result.confidence == 0.0 and result.poles == ()


@pytest.mark.parametrize("solver", ["mimo", "uncorrelated"])
def test_constant_inputs_are_silent_after_detrending(solver: str) -> None:
    rng = np.random.default_rng(5)
    u = np.full((2, 4 * N), 2.5)
    y = rng.standard_normal((2, 4 * N))
    result = _steps(Identifier(IdentifierConfig(solver=solver, **SMALL)), u, y, N // 2)
    assert result.valid_fraction == 0.0 and result.confidence == 0.0


@pytest.mark.parametrize("averaging", ["exponential", "linear", "rls"])
def test_one_silent_input(averaging: str) -> None:
    rng = np.random.default_rng(6)
    u = np.vstack([rng.standard_normal(6 * N), np.zeros(6 * N)])
    y = rng.standard_normal((2, 6 * N))
    idf = Identifier(IdentifierConfig(averaging=averaging, collinear="mask", **SMALL))
    result = _steps(idf, u, y, N // 4)
    assert result.valid_fraction == 0.0 and result.confidence == 0.0
    assert not idf.transfer_functions().valid.any()


def test_identical_inputs_are_collinear_and_masked() -> None:
    rng = np.random.default_rng(8)
    w = rng.standard_normal(6 * N)
    u = np.vstack([w, 2.0 * w])
    y = rng.standard_normal((2, 6 * N))
    result = _steps(Identifier(IdentifierConfig(collinear="mask", **SMALL)), u, y, N // 2)
    assert result.valid_fraction == 0.0 and result.confidence == 0.0


def test_non_finite_batches_are_rejected_without_corrupting_history() -> None:
    idf = Identifier(IdentifierConfig(**SMALL))
    bad = np.zeros((2, 10))
    bad[0, 3] = np.nan
    with pytest.raises(ValueError):
        idf.push(bad, np.zeros((2, 10)))
    with pytest.raises(ValueError):
        idf.push(np.zeros((2, 10)), np.zeros((2, 9)))
    with pytest.raises(ValueError):
        idf.push(np.zeros((3, 10)), np.zeros((2, 10)))
    assert idf.samples_in_history == 0
    assert np.all(idf.history.view() == 0)
