"""From A/D words to engineering values: the MVME's sensor objects.

TPDO words are CiA 401 left-justified INT16 (volts = word * 10 V / 32768,
whatever the converter's resolution); :mod:`protocol.signals` gives the volts
per inch; the cylinder extensions become joint angles through the pin
triangles by the law of cosines (thesis §3.1.1), and theta becomes the
controlled phi [A.7, A.8].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocol.can_map import WORD16_VOLTS_PER_LSB
from protocol.geometry import CYLINDERS, DELTA_RAD
from protocol.signals import ANALOG_INPUTS

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Measurement:
    """One tick's engineering values."""

    words: npt.NDArray[np.int64]
    """The raw left-justified A/D words as they came in TPDO1."""
    volts: FloatArray
    extension_in: FloatArray
    theta_rad: FloatArray
    phi_rad: FloatArray
    deflection_in: FloatArray


_CHANNELS: tuple[tuple[float, float], ...] = tuple((ch.volts_per_unit, ch.centre) for ch in ANALOG_INPUTS)
"""(volts per unit, centre) of the four inputs, as :meth:`AnalogChannel.from_volts` uses them."""
_TRIANGLES: tuple[tuple[float, float, float, float], ...] = tuple(
    (cyl.p_in**2 + cyl.q_in**2, 2.0 * cyl.p_in * cyl.q_in, cyl.retracted_length_in, cyl.offset_rad) for cyl in CYLINDERS
)
""":meth:`PinTriangle.angle`'s constant sub-expressions, evaluated as it evaluates them."""


def _angle(extension: float, tri: tuple[float, float, float, float]) -> float:
    """:meth:`PinTriangle.angle` on one float, the same IEEE operations in the
    same order: the square as a numpy float64 power and the arc cosine as the
    numpy ufunc (which may differ from ``math.acos`` where numpy dispatches a
    SIMD kernel); the clip as min/max (identical for finite values)."""
    pq2, two_pq, retracted, offset = tri
    length = np.float64(extension + retracted)
    cos_gamma = float((pq2 - length**2) / two_pq)
    return float(np.arccos(min(1.0, max(-1.0, cos_gamma)))) - offset


def measure(words: npt.ArrayLike) -> Measurement:
    """Engineering values from the four TPDO1 words (plain floats inside:
    bit for bit what the array form computes, see ``_angle``)."""
    raw = np.asarray(words, dtype=np.int64)
    w = raw.tolist()
    if len(w) != len(_CHANNELS) or raw.ndim != 1:
        raise ValueError(f"four TPDO1 words expected, got shape {raw.shape}")
    volts = [x * WORD16_VOLTS_PER_LSB for x in w]
    values = [v / vpu + centre for v, (vpu, centre) in zip(volts, _CHANNELS, strict=True)]
    t1 = _angle(values[0], _TRIANGLES[0])
    t2 = _angle(values[1], _TRIANGLES[1])
    return Measurement(
        words=raw,
        volts=np.array(volts, dtype=np.float64),
        extension_in=np.array(values[:2], dtype=np.float64),
        theta_rad=np.array((t1, t2), dtype=np.float64),
        phi_rad=np.array((t1 - DELTA_RAD, t2 + DELTA_RAD), dtype=np.float64),
        deflection_in=np.array(values[2:], dtype=np.float64),
    )
