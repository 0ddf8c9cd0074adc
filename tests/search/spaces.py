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
