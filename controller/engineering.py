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
from protocol.geometry import CYLINDERS, theta_to_phi
from protocol.signals import volts_to_inputs

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


def measure(words: npt.ArrayLike) -> Measurement:
    """Engineering values from the four TPDO1 words."""
    raw = np.asarray(words, dtype=np.int64)
    volts = np.asarray(raw * WORD16_VOLTS_PER_LSB, dtype=np.float64)
    values = volts_to_inputs(volts)
    extension = values[:2]
    theta = np.array([cyl.angle(e) for cyl, e in zip(CYLINDERS, extension, strict=True)], dtype=np.float64)
    phi = np.asarray(theta_to_phi(theta[0], theta[1]), dtype=np.float64)
    return Measurement(words=raw, volts=volts, extension_in=extension, theta_rad=theta, phi_rad=phi, deflection_in=values[2:])
