"""The OATF input-shaping filter (thesis §3.3, after Magee and Book).

One three-term stage per mode.  Its continuous impulse response [3-32] is

    f(t) = [d(t) - 2 cos(w_d T1) e^(-z w_n T1) d(t - T1) + e^(-2 z w_n T1) d(t - 2 T1)]
           / [1 - 2 cos(w_d T1) e^(-z w_n T1) + e^(-2 z w_n T1)]

with ``w_d = w_n sqrt(1 - z^2)``.  The discrete filter uses the integer delay
``n1 = int(T1 / Ts)`` [3-35] and computes the coefficients *from n1 Ts*
[3-34], so that

    F(z^-1) = [1 - 2 cos(w_d n1 Ts) e^(-z w_n n1 Ts) z^-n1 + e^(-2 z w_n n1 Ts) z^-2n1] / [same at z = 1].

Then ``z^n1 = e^(s n1 Ts)`` has the design pole ``s = -z w_n + j w_d`` among
its roots: ``F`` has a zero at ``z = e^(s Ts)`` for every integer ``n1 >= 1``,
so the residual vibration of the design mode is exactly zero whatever the
truncation (the other ``n1 - 1`` zeros of each factor need not sit at
multiples of the design frequency).  Coefficients computed from ``T1``
instead (:func:`design_stage_continuous`) misplace that zero: the thesis's
example is a 51 Hz mode at 500 Hz.  ``T1 = pi / w_d`` [3-33] is the robust
choice; with it the stage is Singer and Seering's ZVD shaper
``[1, 2K, K^2] / (1 + K)^2``, ``K = e^(-z w_n T1)``.  Several modes cascade
several stages; the cascade is one sparse FIR filter over a delay line of
past inputs.

Frequencies given to this module are natural frequencies ``w_n / 2 pi`` (Hz)
(what the identifier reports as a peak); ``w_d`` follows from the damping.

Where the filter goes (thesis Fig. 3.6; the loop decides, one location at a
time).  *Outer*: filter the joint set-points (theta or phi, rad) before the
PI: no delay inside the feedback loop, so closed-loop stability is the
unfiltered loop's; reset the delay line to the initial set-point
(:meth:`OatfFilter.reset`) so that the start is not a step from zero.
*Inner*: filter the PI's valve voltages before the D/A: everything the
actuators see is shaped, sensor noise included, but the filter's delay
(``2 n1 Ts`` per mode) and its gain (up to the sum of ``|a_i|``) sit inside
the loop and can destabilise it; reset to zero volts.  In both cases call
:meth:`OatfFilter.step` once per control tick with one value per channel.

Guards.  A stage's coefficients grow large and alternate in sign when
``w_d n1 Ts`` approaches a multiple of ``2 pi`` (delay about one period of
the mode or more, or much shorter than half a period): the denominator
``|1 - K e^(j w_d T)|^2`` vanishes.  Such a filter amplifies noise and makes
the shaped command overshoot and reverse.  A design whose ``sum |a_i|``
exceeds ``max_abs_coefficient_sum`` (default 4: accepts a fixed 0.05 s delay
for modes from 3 Hz up, at z = 0.09) or whose total delay exceeds
``max_total_delay_s`` is rejected with :class:`OatfDesignError`, and the
filter keeps its previous design.  :class:`OatfSupervisor` also ignores and
counts identified frequencies outside a plausible band or below a
confidence threshold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, model_validator

if TYPE_CHECKING:
    from protocol.messages import Interrupt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
ComplexArray = npt.NDArray[np.complex128]

__all__ = [
    "OatfConfig",
    "OatfDesignError",
    "OatfFilter",
    "OatfSupervisor",
    "PoleOffer",
    "StageDesign",
    "SupervisorCounts",
    "cascade_kernel",
    "damped_frequency_rad_s",
    "design_stage",
    "design_stage_continuous",
    "frequency_response",
    "integer_delay_samples",
    "kernel_impulses",
    "residual_vibration",
    "robust_delay_s",
    "three_term_coefficients",
    "transfer_function",
]

_DELAY_ROUNDING_EPS = 1e-9
"""``int(T1 / Ts + eps)``: 0.05 / 0.005 must give 10 even if the float
quotient lands at 9.999999999999998."""


class OatfDesignError(ValueError):
    """A requested OATF design is invalid or fails a guard; nothing was changed."""


# --------------------------------------------------------------------------- design


def damped_frequency_rad_s(frequency_hz: float, zeta: float) -> float:
    """``w_d = 2 pi f sqrt(1 - zeta^2)`` (rad/s) for a natural frequency ``f`` (Hz)."""
    _check_mode(frequency_hz, zeta)
    return 2.0 * math.pi * frequency_hz * math.sqrt(1.0 - zeta * zeta)


def robust_delay_s(frequency_hz: float, zeta: float) -> float:
    """The most robust delay ``T1 = pi / w_d`` [3-33] (s)."""
    return math.pi / damped_frequency_rad_s(frequency_hz, zeta)


def integer_delay_samples(delay_s: float, sample_period_s: float) -> int:
    """``n1 = int(T1 / Ts)`` [3-35], truncated, and at least 1.

    ``n1 = 0`` would make every tap coincide (the identity: no zero at all),
    so one sample is the shortest delay that places a zero.
    """
    if not (math.isfinite(delay_s) and delay_s > 0.0 and sample_period_s > 0.0):
        raise OatfDesignError(f"delay {delay_s!r} s and sample period {sample_period_s!r} s must be positive")
    return max(1, int(delay_s / sample_period_s + _DELAY_ROUNDING_EPS))


def three_term_coefficients(frequency_hz: float, zeta: float, delay_s: float) -> FloatArray:
    """Normalised coefficients ``[a0, a1, a2]`` of [3-32] for a delay ``T`` (unit DC gain).

    ``a = [1, -2 cos(w_d T) e^(-zeta w_n T), e^(-2 zeta w_n T)] / (sum of the same)``.
    """
    return np.array(_three_term(frequency_hz, zeta, delay_s))


def _three_term(frequency_hz: float, zeta: float, delay_s: float) -> tuple[float, float, float]:
    """:func:`three_term_coefficients` [3-32] on plain floats (the redesign on
    each interrupt: a fifth of the time of three-element numpy arrays); held
    against the ZVD shaper's closed form in tests/controller/test_oatf.py."""
    wn = 2.0 * math.pi * frequency_hz
    wd = damped_frequency_rad_s(frequency_hz, zeta)
    k = math.exp(-zeta * wn * delay_s)
    a1 = -2.0 * math.cos(wd * delay_s) * k
    a2 = k * k
    den = (1.0 + a1) + a2  # = |1 - K e^(j w_d T)|^2 >= 0
    if not den > 1e-12:
        raise OatfDesignError(f"degenerate OATF stage: {frequency_hz} Hz, zeta {zeta}, delay {delay_s} s (w_d T is a multiple of 2 pi with no damping)")
    return 1.0 / den, a1 / den, a2 / den


@dataclass(frozen=True)
class StageDesign:
    """One three-term stage: taps ``coefficients`` at delays ``0, n, 2n`` samples."""

    frequency_hz: float
    """Natural frequency the stage was designed for (Hz)."""
    zeta: float
    """Design damping ratio."""
    delay_samples: int
    """``n1`` [3-35]."""
    sample_period_s: float
    coefficients: tuple[float, float, float]
    """``(a0, a1, a2)``, summing to 1."""

    @property
    def delay_s(self) -> float:
        """``n1 Ts`` (s): the spacing of the taps."""
        return self.delay_samples * self.sample_period_s

    @property
    def abs_coefficient_sum(self) -> float:
        """``sum |a_i|``: the stage's worst-case gain (1 when no coefficient is negative)."""
        return float(sum(abs(a) for a in self.coefficients))


def design_stage(
    frequency_hz: float,
    zeta: float,
    sample_period_s: float,
    delay_s: float | None = None,
    *,
    delay_samples: int | None = None,
) -> StageDesign:
    """The discrete OATF stage [3-34, 3-35]: coefficients from ``n1 Ts``.

    The delay is ``delay_samples`` if given, else ``int(delay_s / Ts)`` with
    ``delay_s`` defaulting to the robust ``pi / w_d`` [3-33].
    """
    _check_mode(frequency_hz, zeta)
    _check_below_nyquist(frequency_hz, sample_period_s)
    n1 = _resolve_delay(frequency_hz, zeta, sample_period_s, delay_s, delay_samples)
    coeffs = _three_term(frequency_hz, zeta, n1 * sample_period_s)
    return StageDesign(float(frequency_hz), float(zeta), n1, float(sample_period_s), coeffs)


def design_stage_continuous(
    frequency_hz: float,
    zeta: float,
    sample_period_s: float,
    delay_s: float | None = None,
) -> StageDesign:
    """For comparison only: coefficients from the continuous ``T1`` [3-32], taps at ``int(T1/Ts)``.

    This is the design the thesis warns against: the zero misses the mode
    unless ``T1`` happens to be a multiple of ``Ts``.
    """
    _check_mode(frequency_hz, zeta)
    t1 = robust_delay_s(frequency_hz, zeta) if delay_s is None else float(delay_s)
    n1 = integer_delay_samples(t1, sample_period_s)
    coeffs = three_term_coefficients(frequency_hz, zeta, t1)
    return StageDesign(float(frequency_hz), float(zeta), n1, float(sample_period_s), _as_triple(coeffs))


def cascade_kernel(stages: Sequence[StageDesign]) -> tuple[IntArray, FloatArray]:
    """Sparse FIR of a cascade: (delays in samples, weights), the product of the stages' polynomials.

    With no stages the kernel is the identity (delay 0, weight 1).
    """
    if len(stages) == 1:
        # One stage (the thesis's runs): its own taps, the zero ones left out,
        # exactly what the convolution below gives (1.0 * a is a).
        s = stages[0]
        n = s.delay_samples
        taps = [(d, a) for d, a in zip((0, n, 2 * n), s.coefficients, strict=True) if a != 0.0]
        return np.array([d for d, _ in taps], dtype=np.int64), np.array([a for _, a in taps], dtype=np.float64)
    dense = np.ones(1)
    for s in stages:
        poly = np.zeros(2 * s.delay_samples + 1)
        poly[[0, s.delay_samples, 2 * s.delay_samples]] = s.coefficients
        dense = np.convolve(dense, poly)
    delays = np.flatnonzero(dense)
    return delays.astype(np.int64), dense[delays]


def transfer_function(z: npt.ArrayLike, stages: Sequence[StageDesign]) -> ComplexArray:
    """``F(z)`` of the cascade evaluated at arbitrary complex ``z`` (e.g. a pole ``e^(s Ts)``)."""
    zz = np.asarray(z, dtype=complex)
    out = np.ones_like(zz)
    for s in stages:
        w = zz ** (-s.delay_samples)
        a0, a1, a2 = s.coefficients
        out = out * (a0 + a1 * w + a2 * w * w)
    return out


def frequency_response(freqs_hz: npt.ArrayLike, stages: Sequence[StageDesign]) -> ComplexArray:
    """Complex response ``F(e^(j 2 pi f Ts))`` of the discrete cascade at ``freqs_hz``."""
    if not stages:
        return np.ones(np.shape(freqs_hz), dtype=complex)
    ts = _common_sample_period(stages)
    return transfer_function(np.exp(2j * math.pi * np.asarray(freqs_hz, dtype=float) * ts), stages)


def residual_vibration(
    amplitudes: npt.ArrayLike,
    times_s: npt.ArrayLike,
    frequency_hz: npt.ArrayLike,
    zeta: float,
) -> FloatArray:
    """Percentage residual vibration (as a fraction) of impulses ``A_i`` at ``t_i`` on a mode.

    ``V = e^(-zeta w t_N) sqrt[(sum A_i e^(zeta w t_i) cos(w_d t_i))^2
    + (sum A_i e^(zeta w t_i) sin(w_d t_i))^2] / sum A_i`` (Singer and
    Seering; negative ``A_i`` allowed, so OATF taps work): the amplitude left
    after the last impulse relative to a single impulse of the same total
    applied at ``t_N``.  Vectorised over ``frequency_hz`` for sensitivity
    curves; returns an array of the frequencies' shape.
    """
    a = np.asarray(amplitudes, dtype=float).ravel()
    t = np.asarray(times_s, dtype=float).ravel()
    if a.shape != t.shape or a.size == 0:
        raise ValueError("amplitudes and times_s must be non-empty and of equal length")
    if not 0.0 <= zeta < 1.0:
        raise ValueError(f"zeta must be in [0, 1), got {zeta}")
    w = 2.0 * math.pi * np.asarray(frequency_hz, dtype=float)[..., None]
    wd = w * math.sqrt(1.0 - zeta * zeta)
    t_n = t.max()
    # e^(-zeta w t_N) e^(zeta w t_i) folded into one exponent, which stays <= 0.
    env = a * np.exp(zeta * w * (t - t_n))
    c = np.sum(env * np.cos(wd * t), axis=-1)
    s = np.sum(env * np.sin(wd * t), axis=-1)
    return np.asarray(np.hypot(c, s) / a.sum(), dtype=float)


def kernel_impulses(stages: Sequence[StageDesign]) -> tuple[FloatArray, FloatArray]:
    """The cascade as impulses for :func:`residual_vibration`: (amplitudes, times in s)."""
    delays, weights = cascade_kernel(stages)
    ts = _common_sample_period(stages) if stages else 0.0
    return weights, np.asarray(delays * ts, dtype=np.float64)


# --------------------------------------------------------------------------- filter


class OatfConfig(BaseModel):
    """Configuration of the OATF filter and of its supervisor (thesis §3.3, §4.2.3, §4.3)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    sample_period_s: float = Field(0.005, gt=0.0, description="Sample period Ts (s); 200 Hz in the thesis.")
    design_zeta: float = Field(0.09, ge=0.0, lt=1.0, description="Design damping ratio of every stage (thesis: 0.09; §4.4: 0.01).")
    delay_mode: Literal["robust", "fixed"] = Field(
        "robust",
        description="'robust': T1 = pi/w_d of each stage's design frequency [3-33]; 'fixed': T1 = fixed_delay_s.",
    )
    fixed_delay_s: float = Field(0.05, gt=0.0, description="T1 (s) when delay_mode is 'fixed' (thesis §4.3: 0.05).")
    adapt_delay: bool = Field(
        False,
        description=(
            "False (the thesis's experiments): a stage keeps its integer delay for the whole run and "
            "update_modes changes only the coefficients. True: the delay is recomputed on every update."
        ),
    )
    max_abs_coefficient_sum: float = Field(4.0, ge=1.0, description="Reject a stage whose sum |a_i| exceeds this (large alternating coefficients).")
    max_total_delay_s: float = Field(2.0, gt=0.0, description="Reject a cascade whose total delay (2 n1 Ts summed over stages) exceeds this (s).")
    plausible_band_hz: tuple[float, float] = Field((1.0, 20.0), description="OatfSupervisor ignores identified frequencies outside this band (Hz).")
    min_confidence: float = Field(0.0, description="OatfSupervisor ignores estimates whose confidence is below this.")
    max_stages: int = Field(
        1,
        ge=1,
        le=4,
        description=(
            "1 (the thesis's runs): one stage on the first identified mode. More: one further stage per "
            "confident extra pole (thesis §5.3), created and removed with hysteresis."
        ),
    )
    stage_on_confidence: float = Field(0.5, ge=0.0, le=1.0, description="An extra pole must be at least this confident to create a stage.")
    stage_off_confidence: float = Field(0.25, ge=0.0, le=1.0, description="An extra stage is removed once its pole is less confident than this (or gone).")
    stage_hold_offers: int = Field(5, ge=1, description="Consecutive offers a pole must be confident (or absent) before its stage is created (or removed).")
    stage_match_tolerance: float = Field(0.15, gt=0.0, lt=1.0, description="Relative frequency distance within which a pole continues a stage's track.")
    adapt_damping: bool = Field(False, description="Adapt each stage's design damping to the identified damping ratio (else design_zeta).")
    damping_limits: tuple[float, float] = Field((0.005, 0.3), description="Identified damping ratios are clipped to this range when adapt_damping is on.")

    @model_validator(mode="after")
    def _band_ordered(self) -> OatfConfig:
        lo, hi = self.plausible_band_hz
        if not 0.0 <= lo < hi:
            raise ValueError(f"plausible_band_hz must satisfy 0 <= low < high, got {self.plausible_band_hz}")
        if self.stage_off_confidence > self.stage_on_confidence:
            raise ValueError("stage_off_confidence must not exceed stage_on_confidence (hysteresis)")
        zlo, zhi = self.damping_limits
        if not 0.0 <= zlo <= zhi < 1.0:
            raise ValueError(f"damping_limits must satisfy 0 <= low <= high < 1, got {self.damping_limits}")
        return self

    @property
    def capacity_samples(self) -> int:
        """Delay-line length: enough for any cascade the delay guard admits."""
        return int(self.max_total_delay_s / self.sample_period_s + _DELAY_ROUNDING_EPS) + 1


class OatfFilter:
    """A cascade of OATF stages over any number of channels, with a delay line of past inputs.

    ``step(x)`` filters one tick (``x`` has one value per channel);
    ``process(block)`` filters a ``(n_samples, n_channels)`` block exactly as
    repeated ``step`` calls would.  :meth:`update_modes` recomputes the
    coefficients for new frequencies without touching the delay line.
    """

    def __init__(
        self,
        frequencies_hz: Sequence[float],
        n_channels: int = 2,
        config: OatfConfig | None = None,
        *,
        zetas: Sequence[float] | None = None,
        initial: npt.ArrayLike = 0.0,
    ) -> None:
        if n_channels < 1:
            raise ValueError("n_channels must be >= 1")
        self.config: OatfConfig = config or OatfConfig()
        self.n_channels = n_channels
        self._capacity = self.config.capacity_samples
        self._buf: FloatArray = np.zeros((self._capacity, n_channels))
        self.head_state: IntArray = np.zeros(1, dtype=np.int64)
        """``[head]``: the delay line's newest row (an array: the compiled tick, controller/fast_tick.py, moves it in place)."""
        self._stages: tuple[StageDesign, ...] = ()
        self._delays: IntArray = np.zeros(1, dtype=np.int64)
        self._weights: FloatArray = np.ones(1)
        self._weight_list: list[float] = [1.0]
        """``_weights`` as floats (the per-tick sums read them)."""
        self._tap_rows: IntArray = np.ascontiguousarray(np.arange(self._capacity, dtype=np.int64)[:, None])
        """Per head position, the delay-line rows of the taps: ``(head - delays) % capacity``."""
        self.update_modes(frequencies_hz, zetas)
        self.reset(initial)

    @property
    def _head(self) -> int:
        return int(self.head_state[0])

    @_head.setter
    def _head(self, value: int) -> None:
        self.head_state[0] = value

    # -- design ----------------------------------------------------------------
    @property
    def stages(self) -> tuple[StageDesign, ...]:
        return self._stages

    @property
    def kernel(self) -> tuple[IntArray, FloatArray]:
        """The active sparse FIR: (delays in samples, weights)."""
        return self._delays.copy(), self._weights.copy()

    @property
    def total_delay_samples(self) -> int:
        return int(self._delays.max())

    def design(self, frequencies_hz: Sequence[float], zetas: Sequence[float] | None = None) -> tuple[StageDesign, ...]:
        """The stages :meth:`update_modes` would install, checked against the guards; changes nothing."""
        cfg = self.config
        freqs = [float(f) for f in frequencies_hz]
        zs = [cfg.design_zeta] * len(freqs) if zetas is None else [float(z) for z in zetas]
        if len(zs) != len(freqs):
            raise OatfDesignError("zetas must match frequencies_hz in length")
        stages = []
        for i, (f, z) in enumerate(zip(freqs, zs, strict=True)):
            keep = None if cfg.adapt_delay or i >= len(self._stages) else self._stages[i].delay_samples
            if keep is not None:
                stage = design_stage(f, z, cfg.sample_period_s, delay_samples=keep)
            else:
                t1 = robust_delay_s(f, z) if cfg.delay_mode == "robust" else cfg.fixed_delay_s
                stage = design_stage(f, z, cfg.sample_period_s, t1)
            if stage.abs_coefficient_sum > cfg.max_abs_coefficient_sum:
                raise OatfDesignError(
                    f"stage {i} ({f:.3g} Hz, zeta {z:.3g}, delay {stage.delay_s:.4g} s): sum|a| = "
                    f"{stage.abs_coefficient_sum:.3g} exceeds {cfg.max_abs_coefficient_sum:.3g}"
                )
            stages.append(stage)
        total = sum(2 * s.delay_samples for s in stages)
        if total > self._capacity - 1:
            raise OatfDesignError(f"total OATF delay {total * cfg.sample_period_s:.3f} s exceeds max_total_delay_s {cfg.max_total_delay_s} s")
        return tuple(stages)

    def update_modes(self, frequencies_hz: Sequence[float], zetas: Sequence[float] | None = None) -> tuple[StageDesign, ...]:
        """Install new design frequencies (Hz), one stage each; the delay line is untouched.

        Stage ``i`` keeps its integer delay unless ``adapt_delay`` (new
        stages get the configured delay).  On :class:`OatfDesignError`
        nothing changes.  An empty list makes the filter the identity.
        """
        stages = self.design(frequencies_hz, zetas)
        self._stages = stages
        delays, self._weights = cascade_kernel(stages)
        self._weight_list = self._weights.tolist()
        if delays.shape != self._delays.shape or delays.tolist() != self._delays.tolist():  # a few ints: lists compare faster than arrays
            self._tap_rows = (np.arange(self._capacity)[:, None] - delays[None, :]) % self._capacity
        self._delays = delays
        return stages

    # -- state -----------------------------------------------------------------
    def reset(self, value: npt.ArrayLike = 0.0) -> None:
        """Fill the delay line with ``value`` (per channel): the filter's steady state for that input."""
        self._buf[:] = np.broadcast_to(np.asarray(value, dtype=float), (self.n_channels,))
        self._head = 0

    def history(self, n: int | None = None) -> FloatArray:
        """The last ``n`` inputs (default: the whole delay line), oldest first, ``(n, n_channels)``."""
        n = self._capacity if n is None else n
        idx = (self._head - np.arange(n - 1, -1, -1)) % self._capacity
        return self._buf[idx].copy()

    def step(self, x: npt.ArrayLike) -> FloatArray:
        """Filter one tick: push ``x`` (one value per channel) and return the filtered values."""
        if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (self.n_channels,):
            xv = x  # already one float64 per channel: skip broadcast_to's view machinery
        else:
            xv = np.broadcast_to(np.asarray(x, dtype=float), (self.n_channels,))
        head = self._head = (self._head + 1) % self._capacity
        self._buf[head] = xv
        taps = self._buf[self._tap_rows[head]]
        w = self._weight_list
        out = w[0] * taps[0]
        for i in range(1, len(w)):
            out = out + w[i] * taps[i]
        return out

    def process(self, block: npt.ArrayLike) -> FloatArray:
        """Filter a block ``(n_samples, n_channels)`` (or 1-D for one channel) with the current design."""
        xb = np.asarray(block, dtype=float)
        one_d = xb.ndim == 1
        if (one_d and self.n_channels != 1) or (not one_d and (xb.ndim != 2 or xb.shape[1] != self.n_channels)):
            raise ValueError(f"block must be (n_samples, {self.n_channels}) (1-D only for one channel), got {xb.shape}")
        xb = xb.reshape(-1, self.n_channels)
        n = xb.shape[0]
        past = self._capacity - 1
        ext = np.concatenate([self.history(past), xb])
        d0 = int(self._delays[0])
        out = self._weights[0] * ext[past - d0 : past - d0 + n]  # the taps in step's order
        for d, w in zip(self._delays[1:], self._weights[1:], strict=True):
            out += w * ext[past - d : past - d + n]
        keep = min(n, self._capacity)
        idx = (self._head + 1 + np.arange(n - keep, n)) % self._capacity
        self._buf[idx] = xb[n - keep :]
        self._head = (self._head + n) % self._capacity
        return out.ravel() if one_d else out

    def frequency_response(self, freqs_hz: npt.ArrayLike) -> ComplexArray:
        """Complex response of the active design at ``freqs_hz``."""
        return frequency_response(freqs_hz, self._stages)


@dataclass
class SupervisorCounts:
    """How the identified frequencies offered to :class:`OatfSupervisor` were handled."""

    offers: int = 0
    updates: int = 0
    estimates_used: int = 0
    non_finite: int = 0
    out_of_band: int = 0
    low_confidence: int = 0
    extra_estimates: int = 0
    design_rejected: int = 0
    stages_created: int = 0
    stages_removed: int = 0
    last_rejection: str = field(default="")


class OatfSupervisor:
    """Feeds identified frequencies to an :class:`OatfFilter`, ignoring implausible ones.

    Estimate ``i`` is for stage ``i``.  An estimate that is not finite, lies
    outside ``config.plausible_band_hz`` or comes with a confidence below
    ``config.min_confidence`` is ignored (stage ``i`` keeps its frequency)
    and counted; estimates beyond the filter's number of stages are counted
    as extra.  A merged design that fails the filter's guards is counted as
    rejected and leaves the filter unchanged.  Never raises on bad estimates.
    """

    def __init__(self, oatf: OatfFilter) -> None:
        self.oatf = oatf
        self.counts = SupervisorCounts()
        self._tracks: list[_Track] = []

    def offer_poles(self, poles: Sequence[PoleOffer], confidence: float | None = None) -> bool:
        """Offer every identified pole (first mode first); True if the design changed.

        Stage 0 follows ``poles[0]`` exactly as :meth:`offer` does (with
        ``confidence``, the interrupt's, when given). With ``max_stages > 1``
        every further pole in the band, not within ``stage_match_tolerance`` of
        stage 0, continues or opens a track; a track becomes a stage after
        ``stage_hold_offers`` consecutive offers at confidence ≥
        ``stage_on_confidence`` and is removed after as many offers without
        its pole at ≥ ``stage_off_confidence`` (thesis §5.3: zeros created
        and removed as poles appear and vanish; the two thresholds and the
        count keep them from flickering). With ``adapt_damping`` each stage's
        damping follows its pole's, clipped to ``damping_limits``.
        """
        return _offer_poles(self, poles, confidence)

    def offer_interrupt(self, interrupt: Interrupt) -> bool:
        """:meth:`offer_poles` with a DSP interrupt's poles (per-pole confidence, else the interrupt's)."""
        offers = [
            PoleOffer(
                frequency_hz=p.frequency_hz,
                damping_ratio=p.damping_ratio,
                confidence=interrupt.confidence if p.confidence is None else p.confidence,
            )
            for p in interrupt.poles
        ]
        return self.offer_poles(offers, interrupt.confidence)

    def _offer_first(self, frequency_hz: float, confidence: float, zetas: Sequence[float] | None) -> bool:
        """Stage 0 only, through :meth:`offer` (which keeps the other stages as they are)."""
        return self.offer([frequency_hz], confidence=confidence, zetas=zetas)

    def offer(
        self,
        frequencies_hz: Sequence[float],
        confidence: float | Sequence[float] | None = None,
        zetas: Sequence[float] | None = None,
    ) -> bool:
        """Offer one identification result; True if the filter's design changed."""
        cfg = self.oatf.config
        c = self.counts
        c.offers += 1
        stages = self.oatf.stages
        freqs = [s.frequency_hz for s in stages]
        zs = [s.zeta for s in stages]
        n_est = len(frequencies_hz)
        if confidence is None:
            conf = [math.inf] * n_est
        elif isinstance(confidence, (int, float)):
            conf = [float(confidence)] * n_est
        else:
            conf = [float(x) for x in confidence]
            if len(conf) != n_est:  # an estimate without a confidence counts as low confidence
                conf = (conf + [-math.inf] * n_est)[:n_est]
        used = 0
        for i, f in enumerate(frequencies_hz):
            f = float(f)
            if i >= len(freqs):
                c.extra_estimates += 1
                continue
            if not math.isfinite(f):
                c.non_finite += 1
                continue
            if not cfg.plausible_band_hz[0] <= f <= cfg.plausible_band_hz[1]:
                c.out_of_band += 1
                continue
            if not conf[i] >= cfg.min_confidence:
                c.low_confidence += 1
                continue
            freqs[i] = f
            if zetas is not None and i < len(zetas) and math.isfinite(float(zetas[i])):
                zs[i] = float(zetas[i])
            used += 1
        if used == 0:
            return False
        try:
            new = self.oatf.update_modes(freqs, zs)
        except OatfDesignError as exc:
            c.design_rejected += 1
            c.last_rejection = str(exc)
            return False
        c.estimates_used += used
        changed = new != stages
        c.updates += int(changed)
        return changed


@dataclass
class _Track:
    """An extra pole followed across offers (hysteresis of :meth:`OatfSupervisor.offer_poles`)."""

    frequency_hz: float
    zeta: float
    active: bool = False
    seen: int = 0  #: consecutive offers with the pole confident
    missed: int = 0  #: consecutive offers without it (or not confident enough)


class PoleOffer(BaseModel):
    """One identified pole as the supervisor takes it (frequency, damping, confidence)."""

    model_config = ConfigDict(frozen=True)

    frequency_hz: float
    damping_ratio: float = math.nan
    confidence: float = math.inf


def _offer_poles(sup: OatfSupervisor, poles: Sequence[PoleOffer], confidence: float | None) -> bool:
    """The body of :meth:`OatfSupervisor.offer_poles`."""
    oatf = sup.oatf
    cfg = oatf.config
    c = sup.counts
    if cfg.max_stages <= 1 and not poles:
        return False
    overall = math.inf if confidence is None else float(confidence)

    def conf_of(p: PoleOffer) -> float:
        return min(float(p.confidence), overall)

    def zeta_of(p: PoleOffer, fallback: float) -> float:
        z = float(p.damping_ratio)
        if not cfg.adapt_damping or not math.isfinite(z):
            return fallback
        return min(max(z, cfg.damping_limits[0]), cfg.damping_limits[1])

    primary = poles[0] if poles else None
    stages_before = oatf.stages
    changed = False
    if primary is not None:
        z0 = stages_before[0].zeta if stages_before else cfg.design_zeta
        zs = [zeta_of(primary, z0)] if cfg.adapt_damping else None
        changed = sup._offer_first(primary.frequency_hz, overall if confidence is not None else conf_of(primary), zs)
    if cfg.max_stages <= 1:
        return changed
    # extra poles: every other pole, confident, in band, not the first mode's
    f0 = oatf.stages[0].frequency_hz if oatf.stages else math.nan
    lo, hi = cfg.plausible_band_hz
    tol = cfg.stage_match_tolerance
    extras = [p for p in poles[1:] if math.isfinite(p.frequency_hz) and lo <= p.frequency_hz <= hi and not abs(p.frequency_hz - f0) <= tol * f0]
    seen_tracks: set[int] = set()
    for p in extras:
        best = None
        for k, t in enumerate(sup._tracks):
            near = k not in seen_tracks and abs(p.frequency_hz - t.frequency_hz) <= tol * t.frequency_hz
            if near and (best is None or abs(p.frequency_hz - t.frequency_hz) < abs(p.frequency_hz - sup._tracks[best].frequency_hz)):
                best = k
        q = conf_of(p)
        keep_level = cfg.stage_off_confidence if best is not None and sup._tracks[best].active else cfg.stage_on_confidence
        if not q >= keep_level:
            continue
        if best is None:
            sup._tracks.append(_Track(p.frequency_hz, zeta_of(p, cfg.design_zeta)))
            best = len(sup._tracks) - 1
        t = sup._tracks[best]
        t.frequency_hz = p.frequency_hz
        t.zeta = zeta_of(p, cfg.design_zeta)
        t.missed = 0
        t.seen += 1
        seen_tracks.add(best)
    for k, t in enumerate(sup._tracks):
        if k not in seen_tracks:
            t.missed += 1
            t.seen = 0
        if abs(t.frequency_hz - f0) <= tol * f0:  # the first mode's stage took it over
            t.missed = cfg.stage_hold_offers
    before = [t for t in sup._tracks if t.active]
    for t in sup._tracks:
        if not t.active and t.seen >= cfg.stage_hold_offers:
            t.active = True
            c.stages_created += 1
        elif t.active and t.missed >= cfg.stage_hold_offers:
            t.active = False
            c.stages_removed += 1
    sup._tracks = [t for t in sup._tracks if t.active or t.missed < cfg.stage_hold_offers]
    active = [t for t in sup._tracks if t.active][: cfg.max_stages - 1]
    if not active and not before and len(oatf.stages) <= 1:
        return changed
    head = oatf.stages[:1]
    freqs = [s.frequency_hz for s in head] + [t.frequency_hz for t in active]
    zs = [s.zeta for s in head] + [t.zeta for t in active]
    try:
        new = oatf.update_modes(freqs, zs)
    except OatfDesignError as exc:
        c.design_rejected += 1
        c.last_rejection = str(exc)
        return changed
    return changed or new != stages_before


# --------------------------------------------------------------------------- helpers


def _check_mode(frequency_hz: float, zeta: float) -> None:
    if not (math.isfinite(frequency_hz) and frequency_hz > 0.0):
        raise OatfDesignError(f"design frequency must be positive and finite, got {frequency_hz!r}")
    if not (math.isfinite(zeta) and 0.0 <= zeta < 1.0):
        raise OatfDesignError(f"design damping must be in [0, 1), got {zeta!r}")


def _check_below_nyquist(frequency_hz: float, sample_period_s: float) -> None:
    if not frequency_hz < 0.5 / sample_period_s:
        raise OatfDesignError(f"design frequency {frequency_hz} Hz is not below Nyquist ({0.5 / sample_period_s} Hz)")


def _resolve_delay(frequency_hz: float, zeta: float, sample_period_s: float, delay_s: float | None, delay_samples: int | None) -> int:
    if delay_samples is not None:
        if delay_samples < 1:
            raise OatfDesignError(f"delay_samples must be >= 1, got {delay_samples}")
        return int(delay_samples)
    t1 = robust_delay_s(frequency_hz, zeta) if delay_s is None else float(delay_s)
    return integer_delay_samples(t1, sample_period_s)


def _as_triple(c: FloatArray) -> tuple[float, float, float]:
    return float(c[0]), float(c[1]), float(c[2])


def _common_sample_period(stages: Sequence[StageDesign]) -> float:
    periods = {s.sample_period_s for s in stages}
    if len(periods) != 1:
        raise ValueError(f"stages have different sample periods: {sorted(periods)}")
    return periods.pop()
