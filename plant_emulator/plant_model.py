"""What the plant node asks of its model, every SYNC and on every RPDO1:
the seam between the CANopen node's application
(:class:`plant_emulator.service.PlantApplication`) and the physics behind it.

Two models satisfy it: :class:`plant_emulator.model.RalfArm` (the built-in
RALF arm, the default) and :class:`plant_emulator.fmu.FmuPlant` (an FMI
co-simulation FMU, ``plant.model=fmu:PATH``).
:func:`plant_emulator.plant_factory.build_plant_model` picks one from the
plant's settings.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy.typing as npt

from protocol.can_map import ConverterScale

__all__ = ["PlantModel", "ReportsStepFaults", "SamplesVolts", "TruthSummary"]

TruthSummary = tuple[tuple[float, ...], tuple[float, ...], tuple[float, float], tuple[float, float], tuple[float, float], bool]
"""Modal frequencies (Hz), damping ratios, deflections (in), joint angles (rad), tip (in), payload attached."""


@runtime_checkable
class PlantModel(Protocol):
    """A plant behind the node's two D/A and four A/D channels."""

    @property
    def time_s(self) -> float:
        """Simulated time (s)."""
        ...

    @property
    def hard_stop_count(self) -> int:
        """Arrivals at a hard stop since the start (0 for a model without stops)."""
        ...

    def advance(self, dt: float) -> None:
        """Integrate ``dt >= 0`` seconds with the valve voltages held."""
        ...

    def set_valve_voltages(self, volts: npt.ArrayLike) -> None:
        """The two valve voltages (V, after the D/A), held until the next call."""
        ...

    def set_valve_values(self, volts0: float, volts1: float) -> None:
        """:meth:`set_valve_voltages` given two floats."""
        ...

    def sample_codes(self) -> tuple[list[int], list[bool]]:
        """The four A/D codes of TPDO1 now and their saturation flags."""
        ...

    def truth_summary(self) -> TruthSummary:
        """What the test port publishes as ground truth."""
        ...

    def attach_payload(self, attached: bool) -> None: ...

    def set_adc_bits(self, bits: int) -> None: ...

    def reseed(self, seed: int) -> None: ...

    def close(self) -> None:
        """Free what the model holds (called once, when the plant stops)."""
        ...


@runtime_checkable
class ReportsStepFaults(Protocol):
    """A model whose step can fail (the FMU plant): it calls ``on_fault(cause,
    active, detail)`` when a fault appears or clears."""

    on_fault: Callable[[int, bool, str], None] | None


@runtime_checkable
class SamplesVolts(Protocol):
    """A model whose A/D voltages can be read before the converter (both
    built-in models): what faults on the A/D inputs need
    (:mod:`plant_emulator.channel_faults`)."""

    @property
    def adc_scale(self) -> ConverterScale: ...

    def sample_volts(self) -> list[float]:
        """The four A/D inputs' voltages now, before the converter; drawing
        the same sensor noise as :meth:`PlantModel.sample_codes` would."""
        ...
