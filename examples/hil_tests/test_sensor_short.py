"""A short to ground on the link-1 deflection sensor is caught within 20 ms
and the valves go to zero.

At 5 s of simulated time, the arm following the thesis's trajectory, the
link-1 deflection input (AI3) is shorted to ground through the plant's
failure insertion unit (``rig.fiu``). With the controller's input
monitors on and their policy ``stop``, the controller must end the run
within 20 ms of the short, before the faulted sample reaches a valve, and
leave both valves at 0 V: the last RPDO1 on the bus (read from the run's
recording, decoded with cantools and the project's DBC) commands zero.
"""

from __future__ import annotations

from importlib.resources import files

import cantools
import pytest

from workbench.recording.reader import Recording

SHORT_AT_S = 5.0
TS = 0.005


@pytest.mark.rig_settings(
    controller={
        "input_monitors": "range=true,stuck=true,rate=true,disagree=true",
        "policies": "input_range=stop,input_stuck=stop,input_rate=stop,input_disagree=stop",
    },
)
def test_short_to_ground_on_link1_deflection_stops_the_valves_within_20_ms(rig):
    rig.fiu.short("AI3", to="ground", at_s=SHORT_AT_S)
    record = rig.run(duration_s=SHORT_AT_S + 1.0)

    assert record.error is not None and "stopped by monitor policy: input_" in record.error
    assert "AI3" in record.error
    caught_at_s = (record.ticks + 1) * TS  # the sample of the tick that fired (tick k samples at (k + 1) Ts)
    assert SHORT_AT_S <= caught_at_s <= SHORT_AT_S + 0.020
    assert record.health["controller"].counters["valves_zeroed"] == 1
    dbc = cantools.database.load_string(files("protocol").joinpath("ralf.dbc").read_text(), "dbc")
    rpdo1 = dbc.get_message_by_name("RPDO1_AnalogOutputs16")
    frames = [f for f in Recording.load(record.recording, only=("can",)).can_frames() if f["arbitration_id"] == rpdo1.frame_id]
    valves = [rpdo1.decode(bytes(f["data"])) for f in frames]
    assert max(abs(v) for command in valves[:-1] for v in command.values()) > 0.1  # the valves were driven before
    assert frames[-1]["tick"] == record.ticks  # the last command, at the tick that fired ...
    assert all(v == 0 for v in valves[-1].values())  # ... puts both valves at 0 V
