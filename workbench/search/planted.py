"""Planted weaknesses: search spaces whose allowances are read from the settings, the property
each breaks, and the minimal violation known from the allowance.

One place for both ``tests/search`` (each weakness found and shrunk within a budget) and
``python -m workbench.search.measure --planted`` (how many runs each needs from a random start).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from protocol.setting_groups import InputMonitors
from workbench.search.strategies import Candidate

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


RATE_LIMIT_V = InputMonitors().deflection_rate_v_s * SAMPLE_PERIOD_S
"""The rate monitor's largest step on a deflection input in one sample period (0.5 V)."""


def _near(value: float, known: float, step: float) -> bool:
    return abs(value - known) <= step + 1e-9


def _outage_differs(c: Candidate, known_length_s: float, start_s: float, duration_s: float, step_s: float) -> str | None:
    faults = c.scenario.get("faults") or []
    if len(faults) != 1 or c.channel_faults or c.stimulus:
        return f"{len(faults)} link faults, {len(c.channel_faults)} channel faults, {len(c.stimulus)} stimuli (known: one link fault)"
    (f,) = faults
    length = f["stop_s"] - f["start_s"]
    if not (_near(length, known_length_s, step_s) and _near(f["start_s"], start_s, step_s) and c.duration_s == duration_s):
        return f"outage {length:.3f} s at {f['start_s']:g} s on {c.duration_s:g} s (known: {known_length_s:g} s at {start_s:g} s on {duration_s:g} s)"
    return None


def interrupt_outage_differs(c: Candidate) -> str | None:
    """None when ``c`` is the known minimal interrupt outage within one grid step: one outage of
    the stale allowance (stale_after_s = 0.5 s) at the earliest start (2 s) on the shortest run (3 s)."""
    return _outage_differs(c, STALE_AFTER_S, 2.0, 3.0, 0.005)


TPDO_LOSS_MINIMAL_S = (round(PLANT_HEARTBEAT_S / SAMPLE_PERIOD_S) + 1) * SAMPLE_PERIOD_S
"""The shortest TPDO1 outage that trips the plant-loss allowance: its periods plus one (51 x 5 ms)."""


def tpdo_dropped(c: Candidate) -> int:
    """The TPDO1s a single CAN outage of ``c`` drops: sample periods its window spans."""
    (f,) = c.scenario["faults"]
    return math.ceil((f["stop_s"] - f["start_s"]) / SAMPLE_PERIOD_S - 1e-6)


def tpdo_loss_differs(c: Candidate) -> str | None:
    """None when ``c`` is the known minimal TPDO1 outage within one grid step: one outage of the
    plant-loss allowance's periods plus one (0.255 s) at 1 s on the shortest run (1.5 s)."""
    return _outage_differs(c, TPDO_LOSS_MINIMAL_S, 1.0, 1.5, 0.005)


def push_differs(c: Candidate, threshold_n: float) -> str | None:
    """None when ``c`` is the known minimal push within one grid step: one step force at the
    earliest start (1 s), the shortest length (0.1 s), on the shortest run (2 s), of the smallest
    force ``threshold_n`` that breaks the deflection bound at that length (measured by bisection:
    the bound is on the plant's response, not on a setting)."""
    if len(c.stimulus) != 1 or c.scenario.get("faults") or c.channel_faults:
        return f"{len(c.stimulus)} stimuli (known: one push)"
    (p,) = c.stimulus
    if not (p["at_s"] == 1.0 and _near(p["for_s"], 0.1, 0.05) and c.duration_s == 2.0 and _near(p["size"], threshold_n, 1)):
        return f"{p['size']:g} N for {p['for_s']:g} s at {p['at_s']:g} s on {c.duration_s:g} s (known: {threshold_n:g} N for 0.1 s at 1 s on 2 s)"
    return None


BLIND_BAND_MINIMAL_V = -RATE_LIMIT_V + OFFSET_STEP_V
"""The largest downward offset on the grid inside the rate monitor's step (-0.45 V): -0.5 V is seen."""


def blind_band_differs(c: Candidate) -> str | None:
    """None when ``c`` is the known minimal escape within one grid step: an offset on AI3 (the first
    channel) of the largest grid step inside the rate limit (-0.45 V), at 1 s on the 1.5 s run."""
    if len(c.channel_faults) != 1 or c.scenario.get("faults") or c.stimulus:
        return f"{len(c.channel_faults)} channel faults (known: one)"
    (f,) = c.channel_faults
    ok = (f["channel"], f["kind"], f["start_s"], c.duration_s) == ("AI3", "offset", 1.0, 1.5) and _near(f["offset_v"], BLIND_BAND_MINIMAL_V, OFFSET_STEP_V)
    if not ok:
        return f"{c.describe()} (known: AI3 offset {BLIND_BAND_MINIMAL_V:g} V at 1 s on 1.5 s)"
    return None


@dataclass(frozen=True)
class Planted:
    """A planted weakness: its space, the property it breaks, and how the known minimal is judged."""

    name: str
    space: dict[str, Any]
    property_text: str
    known: str
    """The known minimal violation and why (from the allowance)."""
    differs: Callable[[Candidate], str | None] | None
    """None for the push, whose force threshold is measured: :func:`push_differs`."""


WEAKNESSES: tuple[Planted, ...] = (
    Planted(
        "interrupt-outage",
        INTERRUPT_OUTAGE,
        "within(counters.stale_episodes, 0, 0)",
        f"one zenoh interrupt outage of {STALE_AFTER_S:g} s (timeouts.stale_after_s) from 2 s on a 3 s run",
        interrupt_outage_differs,
    ),
    Planted(
        "tpdo-loss",
        TPDO_LOSS,
        "no_error()",
        f"one CAN TPDO1 outage of {TPDO_LOSS_MINIMAL_S:g} s (timeouts.plant_heartbeat_s = {PLANT_HEARTBEAT_S:g} s = "
        f"{round(PLANT_HEARTBEAT_S / SAMPLE_PERIOD_S)} periods, plus one) from 1 s on a 1.5 s run",
        tpdo_loss_differs,
    ),
    Planted(
        "push-on-link-2",
        PUSH,
        f"within(defl2_in, -{DEFLECTION_BOUND_IN}, {DEFLECTION_BOUND_IN})",
        f"one push of 0.1 s from 1 s on a 2 s run, of the smallest force breaking ±{DEFLECTION_BOUND_IN:g} in (bisected)",
        None,
    ),
    Planted(
        "input-monitor-blind-band",
        BLIND_BAND,
        f"valves_zero_within(events.channel_fault, {VALVES_ZERO_MS:g})",
        f"an AI3 offset of {BLIND_BAND_MINIMAL_V:g} V (the rate monitor's step, {RATE_LIMIT_V:g} V, less one grid step) from 1 s on a 1.5 s run",
        blind_band_differs,
    ),
)
PLANTED: dict[str, Planted] = {w.name: w for w in WEAKNESSES}
"""The weaknesses by name."""
