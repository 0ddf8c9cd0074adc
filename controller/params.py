"""The controller's one path for run-time parameter changes (docs/calibration.md).

Every change of a calibration parameter of the XCP table
(:data:`controller.xcp_table.XCP_TABLE`: the PI gains, the OATF's first
stage, the dither's amplitude, the input monitors' limits), wherever it comes from, takes this path:

* **checked** against the table before it is taken: the value's limits and
  finiteness by the XCP map's own check
  (:meth:`service_kit.xcp.memory.MemoryLayout.check_write`, the value
  converted to its raw bytes as a master would write them), then the OATF's
  guards (a run without an OATF refuses its parameters; a design the
  filter's guards refuse, coefficient sum, delay, Nyquist, is refused),
  the dither's (a run started without one refuses its amplitude) and the
  input monitors' (a run without them refuses their limits; the limits
  together must pass their settings' checks: the range's low end below
  its high end);
* **queued** (at most :data:`PENDING_CAPACITY` changes waiting);
* **applied at a tick boundary**, before the tick that first uses it
  (:meth:`ParamPath.before_tick`): the PI integrators keep their state, the
  OATF its delay line and its stages' delays, the dither its phase in
  its period, the input monitors their counters and episodes;
* **recorded**: listed in the run's ``config_changes`` (kind ``xcp``,
  ``param`` or ``schedule``, who sent it, the simulated time of the first
  tick that uses it, the physical values), published as a
  :class:`~protocol.messages.ParamChanged` event (``controller/param_changes``,
  so a recording holds it) and counted.

Its sources: the XCP slave (:mod:`controller.xcp_link`, kind ``xcp``), a
``ralf-hil param set`` or the live view's parameter panel
(:mod:`service_kit.param_commands`, kind ``param``) and the run's
``param_schedule`` setting (kind ``schedule``: each step at the first tick
at or after its ``at_s``, in simulated time, so a lockstep or co-simulated
run with a schedule is reproducible tick for tick).

Parameters are named ``controller.<name>`` outside the controller; values
are physical, in the table's unit (the PI gains in mV/rad; the law holds
V/rad, the table's raw value).

The check, queue, record and events are every board's
(:mod:`service_kit.param_path`); what is the controller's here is the value
in effect, the guards and the change made to the law and the checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Final, Literal

from pydantic import ValidationError

from controller.dsp_side import ConfigChangeTaken
from controller.input_monitors import InputMonitorChecks
from controller.loop import ControlLaw
from controller.oatf import OatfDesignError
from controller.xcp_table import controller_layout
from protocol.messages import ParamAnswer
from protocol.param_schedule import ParamStep
from protocol.setting_groups import InputMonitors
from service_kit.param_path import PENDING_CAPACITY, ApplyFailed, Kind, ParamRefused, Pending, first_tick
from service_kit.param_path import ParamPath as BoardParamPath
from service_kit.xcp.memory import Variable, Write
from service_kit.xcp.packets import Err

__all__ = ["BOARD", "PENDING_CAPACITY", "Kind", "ParamPath", "ParamRefused", "Pending", "first_tick"]

BOARD: Final = "controller"
"""The prefix of the controller's parameter names (``controller.kp1``)."""
PI: Final[dict[str, tuple[Literal["kp", "ki"], int]]] = {"kp1": ("kp", 0), "kp2": ("kp", 1), "ki1": ("ki", 0), "ki2": ("ki", 1)}
OATF: Final = frozenset({"oatf_frequency_hz", "oatf_zeta"})
DITHER: Final = "dither_amplitude_v"
INPUTS: Final[dict[str, str]] = {
    "input_stuck_samples": "stuck_samples",
    "input_extension_rate_v_s": "extension_rate_v_s",
    "input_deflection_rate_v_s": "deflection_rate_v_s",
    "input_disagree_in": "disagree_in",
}
"""The input monitors' limits by their table name (their setting's key); the range's two ends follow."""
RANGE: Final[tuple[str, str]] = ("input_extension_lo_in", "input_extension_hi_in")


class ParamPath(BoardParamPath):
    """The controller's parameter path (module docstring): the PI gains and the OATF's first stage."""

    def __init__(
        self,
        law: ControlLaw,
        period_s: float,
        config_changes: list[ConfigChangeTaken],
        schedule: Sequence[ParamStep] = (),
        *,
        counted: bool = False,
        publish: Callable[[bytes], None] | None = None,
        answer: Callable[[ParamAnswer], None] | None = None,
        inputs: InputMonitorChecks | None = None,
    ) -> None:
        self.law = law
        self.inputs = inputs
        """The input monitors' checks (None: a run without them refuses their limits)."""
        self.config_changes = config_changes
        self.pi_gains = {name: law.pi_gain(term, joint) for name, (term, joint) in PI.items()}
        """The PI gains in effect (V/rad, raw), as the law holds them."""

        def record(sim_time_s: float, kind: str, fields: dict[str, float], who: str) -> None:
            config_changes.append(ConfigChangeTaken(sim_time_s, kind, dict[str, Any](fields), who))

        super().__init__(BOARD, controller_layout(), period_s, record, schedule, counted=counted, publish=publish, answer=answer)

    def value_raw(self, v: Variable) -> float:
        """The raw value in effect (NaN: a parameter of a part this run does not have)."""
        law = self.law
        if v.name in PI:
            return self.pi_gains[v.name]
        if v.name == DITHER:
            return law.dither_amplitude_v if law.config.dither.enabled else math.nan
        if v.name in INPUTS or v.name in RANGE:
            if self.inputs is None:
                return math.nan
            limits = self.inputs.limits
            return float(getattr(limits, INPUTS[v.name])) if v.name in INPUTS else limits.extension_range_in[RANGE.index(v.name)]
        if law.oatf is None or not law.oatf.stages:
            return math.nan
        stage = law.oatf.stages[0]
        return stage.frequency_hz if v.name == "oatf_frequency_hz" else stage.zeta

    # -- the guards -----------------------------------------------------------------------
    def guard(self, changes: Sequence[Write]) -> None:
        """The guards on a change (the limits are the map's): the dither's and the input monitors'
        (their part in this run; the limits together as their settings take them), the OATF's;
        :class:`ParamRefused` if refused."""
        for w in changes:
            self.guard_step(w)
        if any(w.variable.name in INPUTS or w.variable.name in RANGE for w in changes):
            self._input_limits(changes)
        oatf = {w.variable.name: float(w.raw) for w in changes if w.variable.name in OATF}
        if not oatf:
            return
        if self.law.oatf is None:
            raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no OATF (oatf_mode off)")
        try:
            self.law.oatf.design(*self._oatf_design(oatf))
        except (OatfDesignError, ValueError) as exc:
            raise ParamRefused(Err.ERR_OUT_OF_RANGE, f"OATF design refused: {exc}") from exc

    def guard_step(self, w: Write) -> None:
        name = w.variable.name
        if name in OATF and self.law.oatf is None:
            raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no OATF (oatf_mode off)")
        if name == DITHER and not self.law.config.dither.enabled:
            raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no dither (dither.amplitude_v 0 at start)")
        if (name in INPUTS or name in RANGE) and self.inputs is None:
            raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no input monitors (input_monitors turns none on)")

    def _input_limits(self, changes: Sequence[Write]) -> InputMonitors:
        """The input monitors' limits with ``changes`` made, as their settings take them
        (the range's low end below its high end); :class:`ParamRefused` otherwise."""
        assert self.inputs is not None
        limits = self.inputs.limits
        values = limits.model_dump()
        lo, hi = limits.extension_range_in
        for w in changes:
            name = w.variable.name
            if name in INPUTS:
                values[INPUTS[name]] = w.raw
            elif name == RANGE[0]:
                lo = float(w.raw)
            elif name == RANGE[1]:
                hi = float(w.raw)
        values["extension_range_in"] = (lo, hi)
        try:
            return InputMonitors.model_validate(values)
        except ValidationError as exc:
            reason = "; ".join(str(e["msg"]).removeprefix("Value error, ") for e in exc.errors())
            raise ParamRefused(Err.ERR_OUT_OF_RANGE, f"input monitors' limits refused: {reason}") from None

    def _oatf_design(self, change: dict[str, float]) -> tuple[list[float], list[float]]:
        """The stages' frequencies and damping ratios with the first stage changed."""
        oatf = self.law.oatf
        assert oatf is not None
        stages = oatf.stages
        freqs = [s.frequency_hz for s in stages] or [self.law.config.oatf_frequency_hz]
        zetas = [s.zeta for s in stages] or [oatf.config.design_zeta]
        freqs[0] = change.get("oatf_frequency_hz", freqs[0])
        zetas[0] = change.get("oatf_zeta", zetas[0])
        return freqs, zetas

    # -- the loop's side ------------------------------------------------------------------
    def apply_changes(self, pending: Pending, tick: int) -> None:
        """The law's gains and the OATF's first stage, the raw values as written: the PI
        integrators keep their state, the OATF its delay line and its stages' delays."""
        law = self.law
        oatf = {w.variable.name: float(w.raw) for w in pending.changes if w.variable.name in OATF}
        if any(w.variable.name in INPUTS or w.variable.name in RANGE for w in pending.changes) and self.inputs is not None:
            try:  # each change was checked when taken; another may have moved the range since
                self.inputs.set_limits(self._input_limits(pending.changes))
            except ParamRefused as exc:
                raise ApplyFailed(f"at tick {tick}: {exc}") from exc
        if oatf and law.oatf is not None:
            try:
                law.oatf.update_modes(*self._oatf_design(oatf))
            except (OatfDesignError, ValueError) as exc:  # the design moved since the check (adaptive mode)
                raise ApplyFailed(f"OATF design refused at tick {tick}: {exc}") from exc
        for w in pending.changes:
            if w.variable.name in PI:
                term, joint = PI[w.variable.name]
                law.set_pi_gain(term, joint, float(w.raw))
                self.pi_gains[w.variable.name] = law.pi_gain(term, joint)
            elif w.variable.name == DITHER:
                law.set_dither_amplitude(float(w.raw))
