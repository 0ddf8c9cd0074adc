"""A run's transfer-function downloads: when each came, on which bins, and which carry an estimate.

The controller keeps every download of the DSP's estimates (``RunRecord.tf``,
the run's ``.tf.npz``): ``sim_time_s`` per download, ``freqs_hz`` the DSP's
bins, and ``<name>_mag`` (H11, H12, H21, H22, Htot) one row per download,
zero on the bins the DSP reports invalid and everywhere before its history
filled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from workbench.hil import RunRecord


@dataclass(frozen=True)
class TfDownloads:
    """The downloads of one run; :meth:`of` reads them from a :class:`~workbench.rig_record.RunRecord`."""

    tf: dict[str, np.ndarray]
    freqs: np.ndarray
    """The DSP's bins (Hz)."""
    times: np.ndarray
    """Simulated time of each download (s)."""
    have: list[int]
    """Indices of the downloads that carry an estimate (H_tot non-zero somewhere)."""

    @classmethod
    def of(cls, record: RunRecord) -> TfDownloads:
        """The run's downloads; ``RuntimeError`` in one line when it has none, or none with an estimate."""
        if record.tf is None:
            raise RuntimeError("the controller downloaded no transfer functions")
        times = np.asarray(record.tf["sim_time_s"])
        have = [i for i in range(times.size) if np.any(record.tf["Htot_mag"][i] > 0)]
        if not have:
            raise RuntimeError("no download carries an estimate (the history never filled)")
        return cls(record.tf, np.asarray(record.tf["freqs_hz"]), times, have)

    def magnitude(self, i: int, name: str) -> np.ndarray:
        """``|name|`` (H11, H12, H21, H22 or Htot) of download ``i`` on :attr:`freqs`; 0 on invalid bins."""
        return np.asarray(self.tf[f"{name}_mag"][i], dtype=float)

    def valid(self, i: int, name: str = "Htot") -> np.ndarray:
        """The bins download ``i`` reports valid (non-zero magnitude)."""
        return self.magnitude(i, name) > 0
