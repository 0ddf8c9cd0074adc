"""Per-joint PI control from angle error (rad) to valve voltage (V) (thesis §4).

The thesis's joint controller: proportional gains 7500 and 6250 mV/rad,
integral gains 5000 and 4166 mV/rad (joints 1 and 2); the integrator is a
plain sum windowed exponentially with a forgetting factor of 0.0001, and it
stops summing while the error exceeds 0.04 rad.  The output goes to a D/A
with a limited range.  Written here as, per joint and per tick k,

    e_k = r_k - y_k                                   (angle error, rad)
    I_k = (1 - lambda) I_{k-1} + s e_k g_k            (windowed sum)
    u_k = clip(Kp e_k + Ki I_k, -U, +U)               (valve voltage, V)

with ``lambda`` the forgetting factor, ``s = Ts`` or ``1`` (see
``integral_time_scaled`` below) and the gate ``g_k = 0`` while
``|e_k| > 0.04 rad``, else 1.  The forgetting applies on every tick, gated
or not: ``I_k`` is the exponentially windowed sum of the admitted errors,
the gated samples counting as zero.  Anti-windup (conditional integration):
an increment that would carry ``Kp e_k + Ki I_k`` past the D/A limit in the
direction it pushes is cut at the limit, so the integrator never integrates
further into saturation, and a saturated joint leaves saturation as soon as
its error reverses.

Integral scaling.  The thesis does not say whether ``Ki`` multiplies the raw
sum or the sum times ``Ts``.  The default here is the time-scaled form
(``integral_time_scaled=True``, ``I`` in rad*s), i.e. the textbook discrete
PI ``Kp + Ki Ts / (1 - z^-1)``: in continuous terms ``Kp + Ki/s`` with an
integral time ``Kp / Ki`` = 1.5 s for both joints.  The raw-sum reading is
``Kp + Ki'/s`` with ``Ki' = Ki / Ts`` = 1000 V/(rad*s) at 200 Hz, an integral
time of only 7.5 ms.  Why that matters: the valve voltage commands cylinder
*velocity* (thesis §3, actuators), so the joint is an integrator with a short
valve lag ``tau`` (under 20 ms; 50 ms in the §4.3 simulation),
``G / (s (tau s + 1))``.  With a PI the loop is type 2 and its characteristic
polynomial ``tau s^3 + s^2 + G Kp s + G Ki'`` is, by Routh, stable if and
only if ``Kp / Ki' > tau``: the integral time must exceed the valve lag,
whatever the velocity gain ``G``.  The raw sum fails that (7.5 ms against
20-50 ms, before counting the sample-and-hold delay): it would limit-cycle
between the 0.04 rad gate and the D/A limits (an error just under the gate
ramps the output by 40 V/s).  The time-scaled form passes it by a factor of
30 or more and makes the integral what the thesis uses it for, a slow trim of
the error that the proportional term leaves on ramps and against offsets.
The raw sum remains available (``integral_time_scaled=False``) for comparison;
``tests/controller/test_pi.py`` shows both behaviours on a lagged integrator.
"""

from __future__ import annotations

import math
from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit
from pydantic import BaseModel, ConfigDict, Field, model_validator

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = ["PIConfig", "PIController", "cached_njit", "pi_joint", "pi_step"]

_CONSTS = 6
"""consts[0:6]: decay, scale, limit, threshold, floor, anti-windup (1.0/0.0); then Kp and Ki per joint."""


class PIConfig(BaseModel):
    """Configuration of the per-joint PI controllers (thesis §4, controller).

    Gains are given per joint, in the thesis's units (mV/rad); the number of
    joints is the length of the gain tuples.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kp_mv_per_rad: tuple[float, ...] = Field(
        (7500.0, 6250.0),
        description="Proportional gain per joint, mV of valve voltage per rad of angle error (thesis: 7500, 6250).",
    )
    ki_mv_per_rad: tuple[float, ...] = Field(
        (5000.0, 4166.0),
        description=(
            "Integral gain per joint (thesis: 5000, 4166 'mV/rad'). Multiplies the windowed sum of errors; "
            "with integral_time_scaled=True the sum is of e*Ts (so the unit is really mV/(rad*s))."
        ),
    )
    integral_time_scaled: bool = Field(
        True,
        description=(
            "True: the integrator sums e_k*Ts (textbook discrete PI, integral time Kp/Ki = 1.5 s). "
            "False: it sums the raw e_k (at 200 Hz, 200x more integral action). See the module docstring."
        ),
    )
    sample_period_s: float = Field(0.005, gt=0.0, description="Control sample period Ts (s); 200 Hz in the thesis.")
    forgetting_factor: float = Field(
        1e-4,
        ge=0.0,
        lt=1.0,
        description="Exponential window of the integrator: I_k = (1 - forgetting_factor) I_{k-1} + ... (thesis: 0.0001).",
    )
    integrate_threshold_rad: float = Field(0.04, gt=0.0, description="The integrator stops summing while |error| exceeds this (rad) (thesis: 0.04).")
    output_limit_v: float = Field(10.0, gt=0.0, description="D/A range: the output is clipped to +/- this (V).")
    anti_windup: bool = Field(
        True,
        description="Do not integrate further in the direction of saturation (conditional integration).",
    )

    @model_validator(mode="after")
    def _same_joint_count(self) -> PIConfig:
        if len(self.kp_mv_per_rad) != len(self.ki_mv_per_rad) or len(self.kp_mv_per_rad) == 0:
            raise ValueError("kp_mv_per_rad and ki_mv_per_rad must be non-empty and of equal length")
        if any(g < 0.0 for g in (*self.kp_mv_per_rad, *self.ki_mv_per_rad)):
            raise ValueError("PI gains must be non-negative")
        return self

    @property
    def n_joints(self) -> int:
        return len(self.kp_mv_per_rad)

    @property
    def kp_v_per_rad(self) -> FloatArray:
        return np.asarray(self.kp_mv_per_rad, dtype=float) * 1e-3

    @property
    def ki_v_per_rad(self) -> FloatArray:
        return np.asarray(self.ki_mv_per_rad, dtype=float) * 1e-3

    @property
    def integral_scale(self) -> float:
        """``s`` in ``I_k = (1 - lambda) I_{k-1} + s e_k``: ``Ts`` or 1."""
        return self.sample_period_s if self.integral_time_scaled else 1.0


class PIController:
    """Vectorised per-joint PI with a windowed, gated, anti-windup integrator.

    Call :meth:`update` once per control tick with the set-points and the
    measured joint angles (rad, one entry per joint); it returns the clipped
    valve voltages (V).  The last tick's terms are kept for recording.
    """

    def __init__(self, config: PIConfig | None = None) -> None:
        self.config: PIConfig = config or PIConfig()
        self._kp = self.config.kp_v_per_rad
        self._ki = self.config.ki_v_per_rad
        self._kp_list: list[float] = self._kp.tolist()
        self._ki_list: list[float] = self._ki.tolist()
        self._decay = 1.0 - self.config.forgetting_factor
        self._scale = self.config.integral_scale
        self._limit = self.config.output_limit_v
        self._threshold = self.config.integrate_threshold_rad
        self._anti_windup = self.config.anti_windup
        self._floor = self._limit * (1.0 - 1e-12)
        self.consts: FloatArray = np.array(
            [self._decay, self._scale, self._limit, self._threshold, self._floor, 1.0 if self._anti_windup else 0.0, *self._kp_list, *self._ki_list]
        )
        """What :func:`pi_joint` reads: decay, scale, limit, threshold, floor, anti-windup, then Kp and Ki per joint."""
        self.state: FloatArray = np.zeros(8 * self.config.n_joints)
        """Integrator per joint, then each joint's last terms (see the properties)."""
        self.reset()

    # The state, in one float64 array (the compiled tick, controller/fast_tick.py,
    # writes it in place): the integrator per joint, then per joint the last
    # tick's terms (error, P term, I term, output, saturated, integrating,
    # windup-limited; the flags as 1.0/0.0). Read as arrays on access: the
    # loop itself never needs them.
    @property
    def integral(self) -> FloatArray:
        """Windowed error sum ``I`` per joint (rad*s if time-scaled, else rad)."""
        return self.state[: self.n_joints].copy()

    def _term(self, k: int, dtype: type) -> npt.NDArray[Any]:
        n = self.n_joints
        return self.state[n + k : n + 7 * n : 7].astype(dtype)

    @property
    def error(self) -> FloatArray:
        return self._term(0, np.float64)

    @property
    def p_term_v(self) -> FloatArray:
        return self._term(1, np.float64)

    @property
    def i_term_v(self) -> FloatArray:
        return self._term(2, np.float64)

    @property
    def output_v(self) -> FloatArray:
        return self._term(3, np.float64)

    @property
    def saturated(self) -> BoolArray:
        return self._term(4, np.bool_)

    @property
    def integrating(self) -> BoolArray:
        """Whether the last tick's error was admitted whole into the sum."""
        return self._term(5, np.bool_)

    @property
    def windup_limited(self) -> BoolArray:
        """Whether anti-windup cut the last tick's increment (at the D/A limit)."""
        return self._term(6, np.bool_)

    @property
    def n_joints(self) -> int:
        return self.config.n_joints

    def reset(self, integral: npt.ArrayLike | None = None) -> None:
        """Clear the integrator (or preset it, e.g. for a bumpless start) and the last-tick terms."""
        n = self.n_joints
        values = np.zeros(n) if integral is None else np.broadcast_to(np.asarray(integral, float), (n,))
        self._store(values.tolist(), [(0.0, 0.0, i_term, 0.0, False, False, False) for i_term in (self._ki * values).tolist()])

    def _store(self, integral: list[float], terms: list[tuple[float, float, float, float, bool, bool, bool]]) -> None:
        """The integrator and, per joint, the last tick's (error, P term, I term, output, saturated, integrating, windup-limited)."""
        self.state[:] = [*integral, *chain.from_iterable(terms)]  # bools stored as 1.0 / 0.0

    def update(self, setpoint_rad: npt.ArrayLike, measured_rad: npt.ArrayLike) -> FloatArray:
        """One control tick from set-points and measurements (rad); returns volts."""
        return self.step(np.asarray(setpoint_rad, dtype=float) - np.asarray(measured_rad, dtype=float))

    def step(self, error_rad: npt.ArrayLike) -> FloatArray:
        """One control tick from the angle errors ``e = r - y`` (rad); returns volts.

        The gate, per joint: admit ``e`` into the windowed sum unless
        ``|e| > integrate_threshold_rad``; with ``anti_windup`` an increment
        that would carry ``Kp e + Ki I`` past the D/A limit is cut at the
        limit (an increment pulling back from saturation is never cut).
        One call of :func:`pi_step` (the kernel the compiled tick runs too).
        """
        errors = np.ascontiguousarray(np.broadcast_to(np.asarray(error_rad, dtype=np.float64), (self.n_joints,)))
        if not np.all(np.isfinite(errors)):
            raise ValueError(f"non-finite angle error {errors!r}")
        out = np.empty(self.n_joints)
        pi_step(self.consts, self.state, errors, out)
        return out


def cached_njit(fn: Any) -> Any:
    """``@njit(cache=True)``; compiled in memory only where numba finds no writable cache location."""
    try:
        return njit(cache=True)(fn)
    except RuntimeError:
        return njit(fn)


@cached_njit
def _pmin(a: float, b: float) -> float:
    """Python's ``min(a, b)``: ``a`` unless ``b < a`` (the first argument wins a tie: signed zeros as in Python)."""
    return b if b < a else a


@cached_njit
def _pmax(a: float, b: float) -> float:
    """Python's ``max(a, b)``: ``a`` unless ``b > a``."""
    return b if b > a else a


@cached_njit
def pi_joint(consts: np.ndarray, state: np.ndarray, n: int, j: int, e: float) -> float:
    """Joint ``j`` of ``n`` for one tick (thesis §4): windowed, gated,
    anti-windup integrator and clipped output, written into ``state``
    (:attr:`PIController.state`); returns the valve voltage (V).
    ``consts``: :attr:`PIController.consts`. Plain IEEE arithmetic in a
    fixed order (numba without fastmath: no reassociation, no FMA)."""
    decay, scale, limit, threshold, floor = consts[0], consts[1], consts[2], consts[3], consts[4]
    kpj = consts[_CONSTS + j]
    kij = consts[_CONSTS + n + j]
    decayed = decay * state[j]
    p = kpj * e
    admit = abs(e) <= threshold
    value = decayed + scale * e if admit else decayed
    limited = False
    if consts[5] != 0.0:  # anti-windup: cut an increment where Kp e + Ki I crosses the limit, never reverse it
        if kij > 0.0:
            hi = (limit - p) / kij
            lo = (-limit - p) / kij
        else:
            hi = math.inf
            lo = -math.inf
        cut = _pmax(decayed, _pmin(value, hi)) if value > decayed else _pmin(decayed, _pmax(value, lo))
        limited = cut != value
        value = cut
    i_term = kij * value
    unclipped = p + i_term
    out = _pmin(_pmax(unclipped, -limit), limit)
    state[j] = value
    b = n + 7 * j
    state[b] = e
    state[b + 1] = p
    state[b + 2] = i_term
    state[b + 3] = out
    state[b + 4] = 1.0 if abs(unclipped) >= floor else 0.0
    state[b + 5] = 1.0 if admit and not limited else 0.0
    state[b + 6] = 1.0 if limited else 0.0
    return out


@cached_njit
def pi_step(consts: np.ndarray, state: np.ndarray, errors: np.ndarray, out: np.ndarray) -> None:
    """:func:`pi_joint` of every joint: ``out[j]`` the valve voltage of joint ``j``."""
    n = errors.shape[0]
    for j in range(n):
        out[j] = pi_joint(consts, state, n, j, errors[j])
