"""Reading a run's transfer-function downloads, and refusing a run without any."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from workbench.experiments.lib.tf_downloads import TfDownloads


def _record(tf: dict[str, Any] | None) -> Any:
    return SimpleNamespace(tf=tf)


def test_downloads_with_an_estimate() -> None:
    mag = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 2.0], [3.0, 0.0, 4.0]])
    dl = TfDownloads.of(_record({"sim_time_s": np.array([5.0, 10.0, 15.0]), "freqs_hz": np.array([0.0, 1.0, 2.0]), "Htot_mag": mag, "H11_mag": 2 * mag}))
    assert dl.have == [1, 2]
    assert dl.magnitude(2, "H11").tolist() == [6.0, 0.0, 8.0]
    assert dl.valid(1).tolist() == [False, True, True]


def test_refused_in_one_line() -> None:
    with pytest.raises(RuntimeError, match="downloaded no transfer functions"):
        TfDownloads.of(_record(None))
    with pytest.raises(RuntimeError, match="no download carries an estimate"):
        TfDownloads.of(_record({"sim_time_s": np.array([1.0]), "freqs_hz": np.array([0.0]), "Htot_mag": np.zeros((1, 1))}))
