"""From A/D words to engineering values: the MVME's sensor objects.

TPDO words are CiA 401 left-justified INT16 (volts = word * 10 V / 32768,
whatever the converter's resolution); :mod:`protocol.signals` gives the volts
per inch; the cylinder extensions become joint angles through the pin
triangles by the law of cosines (thesis §3.1.1), and theta becomes the
controlled phi [A.7, A.8].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
_pow = math.pow
_arccos = np.arccos


def _angle(extension: float, tri: tuple[float, float, float, float]) -> float:
    """:meth:`PinTriangle.angle` on one float, the same IEEE operations in the
    same order: the square as numpy's float64 power computes it (the C
    library's ``pow``, which ``math.pow`` calls too; not always ``x * x``)
    and the arc cosine as the numpy ufunc (which may differ from
    ``math.acos`` where numpy dispatches a SIMD kernel); the clip as min/max
    (identical for finite values)."""
    pq2, two_pq, retracted, offset = tri
    cos_gamma = (pq2 - _pow(extension + retracted, 2.0)) / two_pq
    return float(_arccos(min(1.0, max(-1.0, cos_gamma)))) - offset


def measure_values(w: Sequence[int]) -> tuple[float, ...]:
    """The engineering values of four TPDO1 words (plain ints) as floats:
    ``(volts 1-4, extension 1-2, deflection 1-2, theta 1-2, phi 1-2)``
    (in, rad; [A.7, A.8]). The loop's per-tick form of :func:`measure`,
    which is built from it."""
    lsb = WORD16_VOLTS_PER_LSB
    (vpu0, c0), (vpu1, c1), (vpu2, c2), (vpu3, c3) = _CHANNELS
    w0, w1, w2, w3 = w
    v0, v1, v2, v3 = w0 * lsb, w1 * lsb, w2 * lsb, w3 * lsb
    e0, e1 = v0 / vpu0 + c0, v1 / vpu1 + c1
    t1 = _angle(e0, _TRIANGLES[0])
    t2 = _angle(e1, _TRIANGLES[1])
    return (v0, v1, v2, v3, e0, e1, v2 / vpu2 + c2, v3 / vpu3 + c3, t1, t2, t1 - DELTA_RAD, t2 + DELTA_RAD)


def measure(words: npt.ArrayLike) -> Measurement:
    """Engineering values from the four TPDO1 words (plain floats inside:
    bit for bit what the array form computes, see ``_angle``)."""
    raw = np.asarray(words, dtype=np.int64)
    w = raw.tolist()
    if len(w) != len(_CHANNELS) or raw.ndim != 1:
        raise ValueError(f"four TPDO1 words expected, got shape {raw.shape}")
    return measurement_of(raw, measure_values(w))


def measurement_of(raw: npt.NDArray[np.int64], values: Sequence[float]) -> Measurement:
    """The array form of :func:`measure_values`' tuple for the words ``raw``."""
    v0, v1, v2, v3, e0, e1, d0, d1, t1, t2, p1, p2 = values
    return Measurement(
        words=raw,
        volts=np.array((v0, v1, v2, v3), dtype=np.float64),
        extension_in=np.array((e0, e1), dtype=np.float64),
        theta_rad=np.array((t1, t2), dtype=np.float64),
        phi_rad=np.array((p1, p2), dtype=np.float64),
        deflection_in=np.array((d0, d1), dtype=np.float64),
    )
