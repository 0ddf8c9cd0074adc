"""Search spaces of the rig tests: planted weaknesses with allowances read from the settings."""

from __future__ import annotations

from typing import Any

FAST = {"tf_download_samples": 0, "batch_size": 20}
FAST_DSP = {"fft_width": 256, "emulated_latency_s": 0.05}
SAMPLE_PERIOD_S = 1 / 200.0
BATCH_PERIOD_S = FAST["batch_size"] * SAMPLE_PERIOD_S
"""The DSP's period: one batch, one interrupt (l / 200 Hz)."""

STALE_AFTER_S = 0.5
"""The stale monitor's allowance (timeouts.stale_after_s): parameters older than this degrade the run."""
INTERRUPT_OUTAGE: dict[str, Any] = {
    "name": "interrupt-outage",
    "duration_s": [3.0, 5.0, 0.5],
    "link_faults": [{"link": "zenoh", "kinds": ["interrupt"], "start_s": [2.0, 3.0, 0.005], "length_s": [0.0, 2.0, 0.005]}],
    "max_link_faults": 2,
    "fixed": {"controller": {**FAST, "timeouts": {"stale_after_s": STALE_AFTER_S}}, "dsp": FAST_DSP},
}

PLANT_HEARTBEAT_S = 0.25
"""The controller's plant-loss allowance: TPDO1s missing in a row for longer than this end the run
(timeouts.plant_heartbeat_s; lockstep and co-simulation: at least lockstep_s, set equal). Longer
than the plant's heartbeat period (0x1017), so the heartbeat's age alone never trips it."""
TPDO_LOSS: dict[str, Any] = {
    "name": "tpdo-loss",
    "duration_s": [1.5, 3.0, 0.5],
    "link_faults": [{"link": "can", "kinds": ["tpdo"], "start_s": [1.0, 1.5, 0.005], "length_s": [0.0, 0.5, 0.005]}],
    "max_link_faults": 2,
    "fixed": {"controller": {**FAST, "timeouts": {"plant_heartbeat_s": PLANT_HEARTBEAT_S, "lockstep_s": PLANT_HEARTBEAT_S}}, "dsp": FAST_DSP},
}

DEFLECTION_BOUND_IN = 0.3
"""A bound on link 2's measured tip deflection that a push on its tip can break."""
PUSH: dict[str, Any] = {
    "name": "push-on-link-2",
    "duration_s": [2.0, 3.0, 0.5],
    "stimuli": [{"inputs": ["disturbance.link2"], "shape": "step", "start_s": [1.0, 1.5, 0.05], "length_s": [0.1, 1.0, 0.05], "params": {"size": [0, 100, 1]}}],
    "max_stimuli": 2,
    "fixed": {"controller": FAST, "dsp": FAST_DSP},
}

ALL_INPUT_MONITORS = "range=true,stuck=true,rate=true,disagree=true"
"""Every plausibility check on the controller's inputs (docs/fault-insertion.md), each under policy stop."""
OFFSET_STEP_V = 0.05
"""The offsets' grid step."""
VALVES_ZERO_MS = 50.0
"""The property's allowance: both valves at zero within this many ms of the first channel fault."""
BLIND_BAND: dict[str, Any] = {
    "name": "input-monitor-blind-band",
    "duration_s": [1.5, 2.0, 0.5],
    "channel_faults": [
        {"channels": ["AI3", "AI1"], "kind": "short_ground", "start_s": [1.0, 1.2, 0.05], "length_s": 1.0},
        {"channels": ["AI3", "AI1"], "kind": "offset", "start_s": [1.0, 1.2, 0.05], "length_s": 1.0, "params": {"offset_v": [-2.0, 0.0, OFFSET_STEP_V]}},
    ],
    "max_channel_faults": 1,
    "fixed": {
        "controller": {**FAST, "input_monitors": ALL_INPUT_MONITORS, "policies": "input_range=stop,input_stuck=stop,input_rate=stop,input_disagree=stop"},
        "dsp": FAST_DSP,
    },
}
"""Channel faults on a link-1 deflection input (AI3) and a cylinder-1 extension input (AI1) of an arm at
rest, from 1 s on to past the run's end: a short to ground (both inputs read well away from 0 V, the rate
monitor sees the step) or a downward offset of -2 V (seen at once) up to 0 V. Shrinking goes toward the
first template, the first channel and the most negative offset, so the minimal violation is the largest
offset the monitors let through."""
