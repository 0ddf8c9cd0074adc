"""A pythonfmu3 plant that fails on purpose at step ``fault_step``:
``fault_kind`` 1 returns False from ``do_step``, 2 raises, 3 makes the
truth-only output NaN, 4 logs a warning and goes on. Outputs: two A/D
voltages following the inputs, a truth frequency."""

from __future__ import annotations

from typing import Any

from pythonfmu3 import Float64, Fmi3Causality, Fmi3Slave, Fmi3Status, Fmi3Variability, Int32


class FaultyPlant(Fmi3Slave):
    author = "ralf-hil tests"
    description = "a plant that fails on purpose"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.time = 0.0
        self.fault_step = -1
        self.fault_kind = 0
        self.steps = 0
        self.u1 = self.u2 = 0.0
        self.ai1 = self.ai2 = 0.0
        self.f1 = 4.4
        self.register_variable(Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous))
        for name in ("fault_step", "fault_kind"):
            self.register_variable(Int32(name, causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed))
        for name in ("u1", "u2"):
            self.register_variable(Float64(name, causality=Fmi3Causality.input))
        for name in ("ai1", "ai2", "f1"):
            self.register_variable(Float64(name, causality=Fmi3Causality.output))

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.steps += 1
        self.ai1, self.ai2 = 1.0 + 0.5 * self.u1, -1.0 + 0.5 * self.u2
        self.f1 = 4.4
        self.time = current_time + step_size
        if self.steps == self.fault_step:
            if self.fault_kind == 1:
                self.log(f"step {self.steps}: cannot take this step", Fmi3Status.warning)
                return False
            if self.fault_kind == 2:
                raise RuntimeError(f"valve model diverged at step {self.steps}")
            if self.fault_kind == 3:
                self.f1 = float("nan")
            if self.fault_kind == 4:
                self.log(f"step {self.steps}: a warning of the plant's own", Fmi3Status.warning)
        return True
