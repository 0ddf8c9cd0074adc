"""Rolling history buffer of the C40 identifier (thesis §3.2.3, notes §2).

The DSP keeps the last ``N`` samples (``N`` = FFT width) of every input and
output channel. Each batch of ``l`` samples from the CPU is appended; the
oldest samples fall out. Changing ``N`` zeroes the whole history, as on the
C40.

Implementation: a "mirrored" ring buffer of width ``2N``. Every sample is
written at column ``p`` and ``p + N``, so the ``N`` most recent samples are
always the contiguous slice ``[head, head + N)`` — the FFT stage reads them
without a copy or ``np.roll``. Channel order: rows 0, 1 = inputs u1, u2;
rows 2, 3 = outputs y1, y2.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

N_INPUTS = 2
N_OUTPUTS = 2
N_CHANNELS = N_INPUTS + N_OUTPUTS


class HistoryBuffer:
    """Last ``n`` samples of 2 inputs and 2 outputs, oldest first."""

    def __init__(self, n: int) -> None:
        self._n = 0
        self._buf: NDArray[np.float64] = np.zeros((N_CHANNELS, 0))
        self._head = 0
        self._seen = 0
        self.resize(n)

    # ------------------------------------------------------------------ state
    @property
    def n(self) -> int:
        """History length ``N`` (the FFT width)."""
        return self._n

    @property
    def samples_seen(self) -> int:
        """Samples appended since the last :meth:`resize`/:meth:`clear`."""
        return self._seen

    @property
    def samples_in_history(self) -> int:
        """Number of real (non-zero-fill) samples currently held, ≤ ``N``."""
        return min(self._seen, self._n)

    @property
    def is_full(self) -> bool:
        """True once ``N`` samples have been appended since the last reset."""
        return self._seen >= self._n

    def resize(self, n: int) -> None:
        """Set the history length to ``n`` and zero the history (C40 behaviour)."""
        if int(n) != n or n < 2:
            raise ValueError(f"history length must be an integer >= 2, got {n!r}")
        self._n = int(n)
        self._buf = np.zeros((N_CHANNELS, 2 * self._n))
        self._head = 0
        self._seen = 0

    def clear(self) -> None:
        """Zero the history without changing its length."""
        self._buf.fill(0.0)
        self._head = 0
        self._seen = 0

    # ------------------------------------------------------------------- data
    def append(self, inputs: NDArray[np.float64], outputs: NDArray[np.float64]) -> None:
        """Append one batch: ``inputs`` and ``outputs`` of shape ``(2, l)``, any ``l ≥ 0``.

        A batch longer than ``N`` keeps only its last ``N`` samples (but all
        of them count in :attr:`samples_seen`). Raises ``ValueError`` on a
        shape mismatch or non-finite values; the history is then unchanged.
        """
        u = np.asarray(inputs, dtype=np.float64)
        y = np.asarray(outputs, dtype=np.float64)
        if u.ndim != 2 or y.ndim != 2 or u.shape[0] != N_INPUTS or y.shape[0] != N_OUTPUTS:
            raise ValueError(f"expected inputs (2, l) and outputs (2, l), got {u.shape} and {y.shape}")
        if u.shape[1] != y.shape[1]:
            raise ValueError(f"inputs have {u.shape[1]} samples but outputs {y.shape[1]}")
        if not (np.isfinite(u).all() and np.isfinite(y).all()):
            raise ValueError("batch contains NaN or inf")
        total = u.shape[1]
        if total == 0:
            return
        n = self._n
        keep = min(total, n)
        start = total - keep
        head = self._head
        first = min(keep, n - head)  # columns before the ring wraps
        buf = self._buf
        for rows, src in ((slice(0, N_INPUTS), u), (slice(N_INPUTS, N_CHANNELS), y)):
            chunk = src[:, start : start + first]
            buf[rows, head : head + first] = chunk
            buf[rows, head + n : head + n + first] = chunk
            if keep > first:
                rest = src[:, start + first : total]
                buf[rows, 0 : keep - first] = rest
                buf[rows, n : n + keep - first] = rest
        self._head = (head + keep) % n
        self._seen += total

    def view(self) -> NDArray[np.float64]:
        """The history, shape ``(4, N)``, oldest sample first (a read-only view)."""
        v = self._buf[:, self._head : self._head + self._n]
        v.flags.writeable = False
        return v
