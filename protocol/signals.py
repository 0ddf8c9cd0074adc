"""What each analog channel carries and its volts per engineering unit.

The sensor ranges of thesis §3.1.1 are mapped onto the ±10 V span of the
12-bit converters, which reproduces the thesis's resolutions:

* cylinder extension: 20 in range -> 1 V/in, 0 in at -10 V; 12-bit LSB
  = 4.88e-3 in (thesis: 5e-3 in);
* link 1 deflection: 1.15 in range -> 17.39 V/in, centred; LSB 2.81e-4 in
  (thesis: 2.8e-4 in);
* link 2 deflection: 1.11 in range -> 18.02 V/in, centred; LSB 2.71e-4 in
  (thesis: 2.7e-4 in);
* valves: the D/A output is the valve voltage itself (1 V/V).

Both the plant (engineering value -> volts) and the controller (volts ->
engineering value) use these, so they are part of the contract.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.can_map import FULL_SCALE_V


@dataclass(frozen=True)
class AnalogChannel:
    """A linear map ``volts = (value - centre) * volts_per_unit``."""

    name: str
    unit: str
    volts_per_unit: float
    centre: float

    @property
    def range(self) -> tuple[float, float]:
        half = FULL_SCALE_V / self.volts_per_unit
        return self.centre - half, self.centre + half

    def to_volts(self, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return (np.asarray(value, dtype=np.float64) - self.centre) * self.volts_per_unit

    def from_volts(self, volts: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return np.asarray(volts, dtype=np.float64) / self.volts_per_unit + self.centre


CYLINDER1_EXTENSION: Final = AnalogChannel("cylinder1_extension", "in", 1.0, 10.0)
CYLINDER2_EXTENSION: Final = AnalogChannel("cylinder2_extension", "in", 1.0, 10.0)
LINK1_DEFLECTION: Final = AnalogChannel("link1_deflection", "in", 2 * FULL_SCALE_V / 1.15, 0.0)
LINK2_DEFLECTION: Final = AnalogChannel("link2_deflection", "in", 2 * FULL_SCALE_V / 1.11, 0.0)
VALVE1: Final = AnalogChannel("valve1", "V", 1.0, 0.0)
VALVE2: Final = AnalogChannel("valve2", "V", 1.0, 0.0)

ANALOG_INPUTS: Final[tuple[AnalogChannel, ...]] = (
    CYLINDER1_EXTENSION,
    CYLINDER2_EXTENSION,
    LINK1_DEFLECTION,
    LINK2_DEFLECTION,
)
"""TPDO1 order: analog inputs 1-4 (0x6401 sub 1-4)."""
ANALOG_OUTPUTS: Final[tuple[AnalogChannel, ...]] = (VALVE1, VALVE2)
"""RPDO1 order: analog outputs 1-2 (0x6411 sub 1-2)."""


def inputs_to_volts(values: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Four engineering values (in) -> four A/D input voltages."""
    v = np.asarray(values, dtype=np.float64)
    return np.array([ch.to_volts(x) for ch, x in zip(ANALOG_INPUTS, v, strict=True)])


def volts_to_inputs(volts: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Four A/D input voltages -> four engineering values (in)."""
    v = np.asarray(volts, dtype=np.float64)
    return np.array([ch.from_volts(x) for ch, x in zip(ANALOG_INPUTS, v, strict=True)])
