"""RALF's physics: kinematics, hydraulic joints, flexible links, and the
integrated plant with its sensors (docs/plant-model.md).

The façade the plant service uses::

    arm = RalfArm(PlantConfig(seed=0))
    arm.set_valve_voltages(np.array([0.1, -0.05]))   # V, held
    arm.advance(0.005)                               # any dt >= 0
    reading = arm.sample()                           # codes, saturated, volts
    truth = arm.truth()                              # GroundTruth dataclass
"""

from plant_emulator.model.arm import GroundTruth, PlantConfig, RalfArm
from plant_emulator.model.hydraulics import HardStop
from plant_emulator.model.modes import DEFAULT_STRUCTURE, Structure, frequency_response, modal_parameters, static_deflection_in
from plant_emulator.sensors import SensorReading

__all__ = [
    "DEFAULT_STRUCTURE",
    "GroundTruth",
    "HardStop",
    "PlantConfig",
    "RalfArm",
    "SensorReading",
    "Structure",
    "frequency_response",
    "modal_parameters",
    "static_deflection_in",
]
