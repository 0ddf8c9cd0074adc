"""An FMI co-simulation FMU as the plant behind the node's I/O
(:class:`~plant_emulator.plant_model.PlantModel`).

Time.  The FMU is stepped in whole sample periods only: :meth:`FmuPlant.advance`
adds ``dt`` (integer ns) to the remainder carried from earlier calls and
runs one ``doStep`` of exactly one period for every period that covers,
from ``t = steps x period``. Lockstep and co-simulation advance one period
per SYNC, so each SYNC is one ``doStep``; real time catches up to the wall
clock at each SYNC and RPDO, which is one ``doStep`` per SYNC at the SYNC
rate. The valve voltages of the last RPDO1 (after the D/A) are the FMU's
inputs for the whole step.

A/D.  After each step the mapped outputs become volts (``scale x value +
offset``) and the node's A/D quantizes them (:class:`ConverterScale`:
rounding, clipping at full scale flagged as saturation).

Faults.  Each ``doStep`` (with its input set and output get) is timed with
the injected stopwatch: a step longer than the sample period is counted as
an overrun (the plant's own health says so). A step that returns Discard,
Error or Fatal, or outputs that are not finite, is counted, holds the last
good outputs, and is reported through ``on_fault`` (the plant raises EMCY
``PLANT_MODEL_FAULT``; the next good step clears it). After Error or Fatal
FMI allows no further step: the FMU is not stepped again, the outputs stay
held and the fault stays active until the plant stops.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from plant_emulator.fmu.instance import STATUS_DISCARD, STATUS_ERROR, STATUS_OK, STATUS_TERMINATED, FmuInstance
from plant_emulator.plant_model import TruthSummary
from protocol.can_map import FULL_SCALE_V, ConverterScale
from protocol.messages import LatencyStats
from service_kit.runtime import LatencyTracker

__all__ = ["FAULT_DISCARD", "FAULT_ERROR", "FAULT_NON_FINITE", "FAULT_TERMINATED", "FmuPlant"]

log = logging.getLogger(__name__)
NS_PER_S = 1_000_000_000

FAULT_ERROR = 1
FAULT_DISCARD = 2
FAULT_NON_FINITE = 3
FAULT_TERMINATED = 4
"""The cause byte of the EMCY's vendor field (doStep Error/Fatal, Discard, a non-finite output, FMI 3.0 terminateSimulation)."""

FaultHook = Callable[[int, bool, str], None]
"""``on_fault(cause, active, detail)``: a fault appeared (``active``) or cleared."""


class FmuPlant:
    """The FMU behind the node: D/A volts in, A/D codes out, one ``doStep`` per sample period."""

    def __init__(
        self,
        instance: FmuInstance,
        sample_period_s: float,
        adc_bits: int = 12,
        stopwatch: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.instance = instance
        self._period_ns = int(round(sample_period_s * NS_PER_S))
        if self._period_ns <= 0:
            raise ValueError("sample period too small")
        self._h = self._period_ns / NS_PER_S
        self._steps = 0
        self._pending_ns = 0
        self._volts = [0.0, 0.0]
        self._scale = ConverterScale(int(adc_bits))
        mapping = instance.mapping
        self._maps = [(ch.scale, ch.offset) for ch in mapping.outputs]
        truth = mapping.truth
        self._n_freq = len(truth.modal_frequencies_hz)
        self._n_damp = len(truth.damping_ratios)
        self._pairs = [p is not None for p in (truth.deflections_in, truth.theta_rad, truth.tip_in)]
        values = instance.read()
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{instance.path}: outputs after initialization are not finite: {values}")
        self._values = values
        self.stopwatch = stopwatch
        self.on_fault: FaultHook | None = None
        self.step_time = LatencyTracker()
        """Wall time of each step (inputs set, ``doStep``, outputs read)."""
        self.steps_done = 0
        self.overruns = 0
        """Steps that took longer than the sample period."""
        self.faults = {"error": 0, "discard": 0, "non_finite": 0, "terminated": 0}
        self.fault_active = False
        self.failed = False
        """True after Error/Fatal/terminate: FMI allows no further ``doStep``."""
        self.last_problem: str | None = None
        self._closed = False

    # -- PlantModel ------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return (self._steps * self._period_ns + self._pending_ns) / NS_PER_S

    @property
    def hard_stop_count(self) -> int:
        return 0

    @property
    def adc_bits(self) -> int:
        return self._scale.bits

    def set_valve_voltages(self, volts: npt.ArrayLike) -> None:
        v = np.asarray(volts, dtype=np.float64)
        if v.shape != (2,):
            raise ValueError(f"two valve voltages expected, got shape {v.shape}")
        self.set_valve_values(float(v[0]), float(v[1]))

    def set_valve_values(self, volts0: float, volts1: float) -> None:
        if not (math.isfinite(volts0) and math.isfinite(volts1)):
            raise ValueError("valve voltages must be finite")
        lo, hi = -FULL_SCALE_V, FULL_SCALE_V
        self._volts = [min(hi, max(lo, volts0)), min(hi, max(lo, volts1))]

    def advance(self, dt: float) -> None:
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"advance needs a finite dt >= 0, got {dt!r}")
        total = self._pending_ns + int(round(dt * NS_PER_S))
        n, self._pending_ns = divmod(total, self._period_ns)
        for _ in range(n):
            self._step()

    def sample_codes(self) -> tuple[list[int], list[bool]]:
        v = self._values
        (s0, o0), (s1, o1), (s2, o2), (s3, o3) = self._maps
        return self._scale.quantize_floats((s0 * v[0] + o0, s1 * v[1] + o1, s2 * v[2] + o2, s3 * v[3] + o3))

    def sample_volts(self) -> list[float]:
        """The four A/D inputs' voltages now, before the converter: the mapped outputs."""
        v = self._values
        (s0, o0), (s1, o1), (s2, o2), (s3, o3) = self._maps
        return [s0 * v[0] + o0, s1 * v[1] + o1, s2 * v[2] + o2, s3 * v[3] + o3]

    @property
    def adc_scale(self) -> ConverterScale:
        """The A/D converter (its resolution follows :meth:`set_adc_bits`)."""
        return self._scale

    def truth_summary(self) -> TruthSummary:
        v = self._values
        i = 4
        freqs = tuple(v[i : i + self._n_freq])
        i += self._n_freq
        damps = tuple(v[i : i + self._n_damp])
        i += self._n_damp
        pairs: list[tuple[float, float]] = []
        for present in self._pairs:
            if present:
                pairs.append((v[i], v[i + 1]))
                i += 2
            else:
                pairs.append((0.0, 0.0))
        return freqs, damps, pairs[0], pairs[1], pairs[2], False

    def attach_payload(self, attached: bool) -> None:
        """No payload in a mapped FMU: its parameters are set by the mapping at start."""
        log.warning("payload command ignored: the FMU plant takes its parameters from its mapping")

    def set_adc_bits(self, bits: int) -> None:
        self._scale = ConverterScale(int(bits))

    def reseed(self, seed: int) -> None:
        """An FMU's noise, if it has any, is seeded once, through the mapping's ``seed_variable``."""
        if int(seed) < 0:
            raise ValueError("seed must be non-negative")
        log.warning("reseed ignored: the FMU plant's seed is set once at start (seed_variable)")

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.instance.close()

    # -- health ----------------------------------------------------------------------------
    def health_counters(self) -> dict[str, int]:
        return {
            "fmu_steps": self.steps_done,
            "fmu_step_overruns": self.overruns,
            "fmu_step_errors": self.faults["error"],
            "fmu_step_discards": self.faults["discard"],
            "fmu_non_finite_outputs": self.faults["non_finite"],
            "fmu_terminated": self.faults["terminated"],
        }

    def health_latencies(self) -> dict[str, LatencyStats]:
        return {"fmu_step": self.step_time.stats()}

    # -- internals -------------------------------------------------------------------------
    def _step(self) -> None:
        t = self._steps * self._period_ns / NS_PER_S
        self._steps += 1
        if self.failed:
            return
        sw = self.stopwatch
        started = sw()
        status = self.instance.step(t, self._h, self._volts[0], self._volts[1])
        elapsed = sw() - started
        self.step_time.add(elapsed)
        self.steps_done += 1
        if elapsed > self._h:
            self.overruns += 1
            self.last_problem = f"FMU step at {t:.3f} s took {elapsed * 1e3:.2f} ms, longer than the {self._h * 1e3:g} ms period"
        if status == STATUS_OK:
            values = self.instance.values
            if all(math.isfinite(x) for x in values):
                self._values = values
                if self.fault_active and not self.failed:
                    self._report(0, False, f"FMU step at {t:.3f} s good again")
                return
            self.faults["non_finite"] += 1
            self._report(FAULT_NON_FINITE, True, f"FMU step at {t:.3f} s gave non-finite outputs; last outputs held")
            return
        if status == STATUS_DISCARD:
            self.faults["discard"] += 1
            said = f" ({self.instance.step_message})" if self.instance.step_message else ""
            self._report(FAULT_DISCARD, True, f"FMU doStep at {t:.3f} s returned discard{said}; last outputs held")
            return
        if status == STATUS_TERMINATED:
            self.faults["terminated"] += 1
            cause = FAULT_TERMINATED
        else:
            self.faults["error"] += 1
            cause = FAULT_ERROR
        self.failed = True
        label = "asked to terminate" if status == STATUS_TERMINATED else f"returned {'fatal' if status > STATUS_ERROR else 'error'}"
        said = f" ({self.instance.step_message})" if self.instance.step_message else ""
        self._report(cause, True, f"FMU doStep at {t:.3f} s {label}{said}: no further steps; outputs held")

    def _report(self, cause: int, active: bool, detail: str) -> None:
        if active:
            self.last_problem = detail
            if self.fault_active:
                return  # one EMCY per fault episode (the counters keep counting)
        self.fault_active = active
        if active:
            log.warning("%s", detail)
        hook = self.on_fault
        if hook is not None:
            hook(cause, active, detail)
