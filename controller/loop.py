"""One control tick of the MVME CPU, pure and deterministic (thesis §4):

A/D words -> engineering values -> set-point from the trajectory -> OATF
(outer, on the set-points) -> PI -> OATF (inner, on the commands) -> D/A.

No I/O and no clocks here: the service feeds words and gets volts, so the
same law runs over CAN in three processes or directly against the plant
model in one.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from controller import fast_tick
from controller.excitation import DitherConfig, dither_table
from controller.oatf import OatfConfig, OatfFilter, OatfSupervisor
from controller.pi import PIConfig, PIController
from controller.trajectory import SampledTrajectory
from protocol.messages import Interrupt
from protocol.setting_groups import PiGains
from protocol.stimulus import StimulusPlan
from protocol.stimulus_eval import StimulusSource

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

ROW_NAMES: tuple[str, ...] = (
    "t_s",
    "phi_ref1",
    "phi_ref2",
    "phi_shaped1",
    "phi_shaped2",
    "phi1",
    "phi2",
    "theta1",
    "theta2",
    "ext1_in",
    "ext2_in",
    "defl1_in",
    "defl2_in",
    "ai1_word",
    "ai2_word",
    "ai3_word",
    "ai4_word",
    "ai1_v",
    "ai2_v",
    "ai3_v",
    "ai4_v",
    "u1_v",
    "u2_v",
    "pi1_v",
    "pi2_v",
)
"""The values of :meth:`ControlLaw.step_row`, in its order (the run record's
columns from ``t_s`` to ``pi2_v``; ``tick`` and ``oatf_hz`` are not in it)."""
ROW_VOLTS = ROW_NAMES.index("u1_v")
"""``row[ROW_VOLTS:ROW_VOLTS + 2]``: the valve voltages after D/A quantization."""
ROW_DEFLECTIONS = ROW_NAMES.index("defl1_in")
"""``row[ROW_DEFLECTIONS:ROW_DEFLECTIONS + 2]``: the two link deflections (in)."""
STIMULUS_NAMES: tuple[str, ...] = ("stim_phi1_rad", "stim_phi2_rad", "stim_u1_v", "stim_u2_v")
"""The run record's stimulus columns (only with a controller stimulus): :attr:`ControlLaw.stimulus_row`."""


@dataclass(frozen=True)
class LawConfig:
    """What the control law needs, in its own terms (the service maps its
    settings into it: :func:`controller.config.law_config`)."""

    sample_period_s: float
    oatf_mode: Literal["off", "fixed", "adaptive"] = "off"
    oatf_location: Literal["outer", "inner"] = "outer"
    oatf_frequency_hz: float = 4.4
    """The OATF's initial design (and the ``fixed`` fallback's)."""
    oatf_fallback: Literal["last", "fixed"] = "last"
    oatf: OatfConfig | None = None
    """The OATF's design rules (None: off)."""
    dither: DitherConfig = DitherConfig()
    """Persistent excitation added to the valve commands before the D/A (:mod:`controller.excitation`; off by default)."""
    pi_gains: PiGains = PiGains()
    """The joints' PI gains (the thesis's by default)."""
    stimulus: StimulusPlan = field(default_factory=StimulusPlan)
    """Stimulus profiles on the set-points and valves (:mod:`protocol.stimulus`; empty: off, the tick untouched)."""


class ControlLaw:
    """Trajectory, OATF and PI for the two joints."""

    def __init__(self, config: LawConfig, trajectory: SampledTrajectory) -> None:
        self.config = config
        self.trajectory = trajectory
        self.setpoints = self.trajectory.joints.phi
        self.lap_ticks = len(self.setpoints)
        self._ts = config.sample_period_s
        self._outer = config.oatf_location == "outer"
        gains = config.pi_gains
        self.pi = PIController(PIConfig(sample_period_s=config.sample_period_s, kp_mv_per_rad=gains.kp_mv_per_rad, ki_mv_per_rad=gains.ki_mv_per_rad))
        self.degraded = False
        self.oatf: OatfFilter | None = None
        self.supervisor: OatfSupervisor | None = None
        if config.oatf_mode != "off":
            if config.oatf is None:
                raise ValueError(f"OATF mode {config.oatf_mode!r} needs its design rules (LawConfig.oatf)")
            initial = self.setpoints[0] if config.oatf_location == "outer" else 0.0
            self.oatf = OatfFilter([config.oatf_frequency_hz], n_channels=2, config=config.oatf, initial=initial)
            self.supervisor = OatfSupervisor(self.oatf)
        fast_tick.warm_up()
        # The tick's state in two arrays (fast_tick.law_tick): the PI's state,
        # the OATF's head and the row are views into them.
        f = fast_tick
        dither = dither_table(config.dither, self._ts) if config.dither.enabled else np.zeros((0, 2))
        self.stimulus = StimulusSource(config.stimulus) if config.stimulus else None
        """The controller's stimulus (None: none; the compiled tick then reads no slot)."""
        self.stimulus_row: list[float] = [0.0, 0.0, math.nan, math.nan] if self.stimulus is not None else []
        """This tick's stimulus as applied (:data:`STIMULUS_NAMES`): set-point offsets (rad), valve overrides (V; NaN: none); empty without a stimulus."""
        self.stimulus_events: list[dict[str, Any]] = []
        """Each profile's start and end: ``time_s``, ``tick``, ``profile`` (its index), ``input``, ``event`` (start, end), ``detail``."""
        n_stim = f.STIMULUS_SLOTS if self.stimulus is not None else 0
        data = np.zeros(f.SETPOINTS + 2 * self.lap_ticks + dither.size + n_stim)
        data[: f.PI_STATE] = f.law_consts(self.pi, self._ts)
        data[f.PI_STATE : f.ROW] = self.pi.state
        self.pi.state = data[f.PI_STATE : f.ROW]
        data[f.SETPOINTS : f.SETPOINTS + 2 * self.lap_ticks] = np.asarray(self.setpoints, dtype=np.float64).ravel()
        data[f.SETPOINTS + 2 * self.lap_ticks : data.size - n_stim] = dither.ravel()
        self._data = data
        self._dither = data[f.SETPOINTS + 2 * self.lap_ticks : data.size - n_stim]
        """The dither's table in the compiled tick's data (empty without a dither)."""
        self.dither_amplitude_v = config.dither.amplitude_v
        """The dither's RMS in effect (V; :meth:`set_dither_amplitude`)."""
        self.row = data[f.ROW : f.SETPOINTS]
        """The tick's row (:data:`ROW_NAMES`, the words as floats), rewritten each tick."""
        self.ints = np.zeros(f.N_INTS, dtype=np.int64)
        self.codes = self.ints[:4]
        """The tick's D/A codes and saturation flags ``(c0, c1, s0, s1)``."""
        self.ints[f.MODE] = 0 if self.oatf is None else (1 if self._outer else 2)
        self.ints[f.DITHER] = len(dither)
        self.ints[f.STIMULUS] = n_stim
        if self.oatf is not None:
            self.ints[f.HEAD] = self.oatf.head_state[0]
            self.oatf.head_state = self.ints[f.HEAD : f.HEAD + 1]
        self._no_oatf = (np.zeros((1, 2)), np.zeros((1, 1), dtype=np.int64), np.ones(1))

    def set_dither_amplitude(self, amplitude_v: float) -> None:
        """The dither's RMS from the next tick on (a run started with a dither only): the same
        multisine (band, period, seed) rescaled, its table recomputed from its settings as at
        start, so a run taking the change at one tick is reproducible bit for bit; 0 mutes it."""
        if not self._dither.size:
            raise ValueError("this run has no dither (dither.amplitude_v 0 at start)")
        config = replace(self.config.dither, amplitude_v=amplitude_v)
        self._dither[:] = dither_table(config, self._ts).ravel()
        self.dither_amplitude_v = amplitude_v

    @property
    def oatf_frequency_hz(self) -> float:
        """The OATF's current design frequency (NaN when off)."""
        oatf = self.oatf
        stages = oatf._stages if oatf is not None else ()  # read every tick: one attribute, not two properties
        return float(stages[0].frequency_hz) if stages else math.nan

    def setpoint(self, tick: int) -> FloatArray:
        """phi set-points at ``tick``; the closed loop repeats lap after lap."""
        return np.asarray(self.setpoints[tick % self.lap_ticks], dtype=np.float64)

    def tick_compiled(self, tick: int, w0: int, w1: int, w2: int, w3: int) -> None:
        """One tick from the four TPDO1 words, in one compiled call
        (:func:`controller.fast_tick.law_tick`): engineering values [A.7, A.8],
        set-point, OATF (§3.3, [3-34]), PI (§4), 12-bit D/A. :attr:`row` and
        :attr:`codes` hold the result."""
        if self.stimulus is not None:
            self._apply_stimulus(tick)
        oatf = self.oatf
        if oatf is not None:
            buf, rows, weights = oatf._buf, oatf._tap_rows, oatf._weights
        else:
            buf, rows, weights = self._no_oatf
        status = fast_tick.law_tick(tick, w0, w1, w2, w3, fast_tick.ANGLE_TABLE, self._data, self.ints, buf, rows, weights)
        if status == fast_tick.MISSING_ANGLE:  # a word seen for the first time: its angle, then the tick
            fast_tick.fill_angles(w0, w1)
            status = fast_tick.law_tick(tick, w0, w1, w2, w3, fast_tick.ANGLE_TABLE, self._data, self.ints, buf, rows, weights)
        if status == fast_tick.NON_FINITE:
            raise ValueError(f"non-finite angle error {np.asarray(self.row[:2].tolist())!r}")
        if status < 0:
            raise RuntimeError(f"the compiled tick failed with status {status}")

    def _apply_stimulus(self, tick: int) -> None:
        """This tick's stimulus at ``t = tick * Ts`` (the record's ``t_s``) into the compiled tick's slots."""
        stim = self.stimulus
        assert stim is not None
        t = tick * self._ts
        for change in stim.transitions(t):
            p = change.profile
            event = "start" if change.started else "end"
            self.stimulus_events.append(
                {"time_s": change.time_s, "tick": tick, "profile": change.index, "input": p.input, "event": event, "detail": p.describe()}
            )
            log.info("stimulus %s at %.3f s: %s", event, t, change.describe())
        u1 = stim.value("valve.u1", t) if stim.any_active("valve.u1", t) else math.nan
        u2 = stim.value("valve.u2", t) if stim.any_active("valve.u2", t) else math.nan
        values = [stim.value("setpoint.phi1", t), stim.value("setpoint.phi2", t), u1, u2]
        self.stimulus_row = values
        self._data[-len(values) :] = values

    def _row_and_flags(self, tick: int, w: list[int]) -> tuple[list[Any], bool, bool]:
        """:meth:`tick_compiled`, read back as floats (the words as ints) and the two D/A saturation flags."""
        w0, w1, w2, w3 = w
        self.tick_compiled(tick, w0, w1, w2, w3)
        row = self.row.tolist()
        row[13:17] = w
        _, _, s0, s1 = self.codes.tolist()
        return row, bool(s0), bool(s1)

    def step_row(self, tick: int, words: list[int]) -> list[Any]:
        """One tick from the four TPDO1 words (plain ints): the values named
        by :data:`ROW_NAMES`, as floats (the words as ints)."""
        return self._row_and_flags(tick, words)[0]

    def set_degraded(self, degraded: bool) -> None:
        """While degraded the OATF stops adapting; with the ``fixed`` fallback
        it also returns to the configured design frequency."""
        if degraded and not self.degraded and self.oatf is not None and self.config.oatf_fallback == "fixed":
            self.oatf.update_modes([self.config.oatf_frequency_hz])
        self.degraded = degraded

    def _pi_index(self, term: Literal["kp", "ki"], joint: int) -> int:
        n = self.pi.n_joints
        if not 0 <= joint < n:
            raise ValueError(f"joint {joint} outside 0..{n - 1}")
        return len(self.pi.consts) - 2 * n + (0 if term == "kp" else n) + joint

    def pi_gain(self, term: Literal["kp", "ki"], joint: int) -> float:
        """One PI gain (V/rad) as the compiled tick reads it."""
        return float(self._data[self._pi_index(term, joint)])

    def set_pi_gain(self, term: Literal["kp", "ki"], joint: int, v_per_rad: float) -> None:
        """Change one PI gain (V/rad) from the next tick on (§4): the compiled tick
        reads it from its constants; the integrator's state is kept."""
        i = self._pi_index(term, joint)
        self.pi.consts[i] = v_per_rad
        self._data[i] = v_per_rad

    def apply_interrupt(self, interrupt: Interrupt) -> bool:
        """Adaptive OATF: offer the identified first mode; True if the filter changed."""
        if self.supervisor is None or self.config.oatf_mode != "adaptive" or not interrupt.poles or self.degraded:
            return False
        return self.supervisor.offer_interrupt(interrupt)
