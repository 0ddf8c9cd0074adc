"""The identifier's FFT forms against scipy.fft.rfft, and the choice among them."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import scipy.fft

from dsp_service import rfft_into
from dsp_service.identifier import Identifier, IdentifierConfig


def _buffers(n: int, rows: int = 4) -> tuple[np.ndarray, np.ndarray]:
    x = np.random.default_rng(n).standard_normal((rows, n))
    return x, np.empty((rows, n // 2 + 1), dtype=np.complex128)


@pytest.mark.parametrize("n", [4, 5, 64, 1000, 2048, 3000, 8192])
@pytest.mark.parametrize("form", rfft_into.FORMS)
def test_every_form_the_probe_accepts_gives_scipys_bits(n: int, form: str) -> None:
    x, out = _buffers(n)
    bound = rfft_into.bind(x, out, forms=(form,))
    bound()
    want = scipy.fft.rfft(x, axis=-1)
    if bound.form == form:  # accepted on the probe: the same bits on other data too
        np.testing.assert_array_equal(out.view(np.float64), want.view(np.float64))
    else:  # refused on the probe: the reference took its place
        assert bound.form == "scipy"
        np.testing.assert_array_equal(out.view(np.float64), want.view(np.float64))


def test_bound_to_the_buffers_themselves() -> None:
    x, out = _buffers(256)
    bound = rfft_into.bind(x, out)
    x[:] = np.random.default_rng(1).standard_normal(x.shape)  # new data in the same buffer
    bound()
    np.testing.assert_array_equal(out, scipy.fft.rfft(x, axis=-1))


def test_a_binding_with_other_bits_is_passed_over(monkeypatch: pytest.MonkeyPatch) -> None:
    def off_by_one_ulp(x: np.ndarray, axes: Any, forward: bool, inorm: int, out: np.ndarray, nthreads: int) -> np.ndarray:
        np.copyto(out, scipy.fft.rfft(x, axis=-1))
        out.real[0, 0] = np.nextafter(out.real[0, 0], np.inf)
        return out

    monkeypatch.setattr(rfft_into, "_r2c", off_by_one_ulp)
    x, out = _buffers(512)
    assert rfft_into.bind(x, out).form != "binding"
    assert rfft_into.bind(x, out, forms=("binding",)).form == "scipy"


def test_a_binding_with_another_signature_or_none_is_passed_over(monkeypatch: pytest.MonkeyPatch) -> None:
    def other_signature(x: np.ndarray) -> np.ndarray:
        raise TypeError("r2c() takes other arguments")

    x, out = _buffers(512)
    monkeypatch.setattr(rfft_into, "_r2c", other_signature)
    assert rfft_into.bind(x, out, forms=("binding",)).form == "scipy"
    monkeypatch.setattr(rfft_into, "_r2c", None)
    assert rfft_into.bind(x, out, forms=("binding", "numpy")).form in ("numpy", "scipy")


@pytest.mark.parametrize(
    ("x", "out"),
    [
        (np.zeros((4, 8), dtype=np.float32), np.empty((4, 5), dtype=np.complex128)),
        (np.zeros((4, 8)), np.empty((4, 4), dtype=np.complex128)),
        (np.zeros((8, 4)).T, np.empty((4, 5), dtype=np.complex128)),
    ],
)
def test_buffers_of_another_type_or_shape_are_refused(x: np.ndarray, out: np.ndarray) -> None:
    with pytest.raises(ValueError, match="rfft_into.bind"):
        rfft_into.bind(x, out)


def test_the_identifier_names_its_form_and_its_ffts_are_scipys() -> None:
    ident = Identifier(IdentifierConfig(sample_rate_hz=200.0, fft_width=256))
    ks = ident._k
    assert ks.fft_form in rfft_into.FORMS
    est = ident._est
    est._tmp[:] = np.random.default_rng(2).standard_normal(est._tmp.shape)
    ks.fft(*ks.fft_args)
    np.testing.assert_array_equal(est.ffts, scipy.fft.rfft(est._tmp, axis=-1))
