"""The plant model's figures and measured numbers (docs/plant-model.md):
:mod:`.report` draws the workspace maps, the loop and the transfer functions
and runs the unfiltered battery; :mod:`.speed_probe` measures the candidate
mechanisms of the speed dependence. Both drive the arm under a plain PI in
lockstep, with no CAN and no controller service: ``ralf-hil plant``."""
