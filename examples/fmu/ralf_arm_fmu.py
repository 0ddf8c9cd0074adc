"""The built-in RALF arm exported as an FMI 3.0 co-simulation FMU with
pythonfmu3, to run it through the FMU path (``plant.model=fmu:``):

    pythonfmu3 build -f examples/fmu/ralf_arm_fmu.py --dest .
    ralf-hil up --clock cosim --set plant.model=fmu:RalfArm.fmu \\
                --set plant.fmu_mapping=examples/fmu/ralf_arm.yaml

Its outputs are the four A/D input voltages before the converter (the arm's
sensors, noise included: ``RalfArm.sample().analog_volts``), so the mapping
passes them through (scale 1, offset 0) and the node's A/D quantizes them as
the built-in path does. The FMU runs the ralf-hil package in the Python
that loads it (a pythonfmu FMU embeds no interpreter).
"""

from __future__ import annotations

from typing import Any

from pythonfmu3 import Float64, Fmi3Causality, Fmi3Slave, Fmi3Variability, Int32


class RalfArm(Fmi3Slave):
    author = "ralf-hil"
    description = "RALF, the flexible two-link hydraulic arm, with its sensors (plant_emulator.model.RalfArm)"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.time = 0.0
        self.seed = 0
        self.u1 = 0.0
        self.u2 = 0.0
        self.ai1 = self.ai2 = self.ai3 = self.ai4 = 0.0
        self.f1 = self.f2 = self.zeta1 = self.zeta2 = 0.0
        self.defl1 = self.defl2 = 0.0
        self.arm: Any = None
        self.register_variable(Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous))
        self.register_variable(Int32("seed", causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed))
        for name in ("u1", "u2"):
            self.register_variable(Float64(name, causality=Fmi3Causality.input))
        for name in ("ai1", "ai2", "ai3", "ai4", "f1", "f2", "zeta1", "zeta2", "defl1", "defl2"):
            self.register_variable(Float64(name, causality=Fmi3Causality.output))

    def exit_initialization_mode(self) -> None:
        from plant_emulator.model import PlantConfig
        from plant_emulator.model import RalfArm as Arm

        self.arm = Arm(PlantConfig(seed=int(self.seed)))
        self._outputs([0.0, 0.0, 0.0, 0.0])  # no A/D conversion before the first step: its noise draws stay the first SYNC's

    def do_step(self, current_time: float, step_size: float) -> bool:
        arm = self.arm
        arm.set_valve_values(self.u1, self.u2)
        arm.advance(step_size)
        self._outputs(arm.sample().analog_volts.tolist())
        self.time = current_time + step_size
        return True

    def _outputs(self, volts: list[float]) -> None:
        self.ai1, self.ai2, self.ai3, self.ai4 = volts
        freqs, damping, deflections, _, _, _ = self.arm.truth_summary()
        self.f1, self.f2 = freqs[0], freqs[1]
        self.zeta1, self.zeta2 = damping[0], damping[1]
        self.defl1, self.defl2 = deflections
