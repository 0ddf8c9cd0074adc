"""Stimulus profiles evaluated at a simulated time: the one implementation
every clock uses (the controller's tick at ``tick * Ts``, the plant after
each SYNC's step at the model's time), so the co-simulation, lockstep and
real time see the same value at the same simulated instant.

:func:`profile_value` is pure: a profile, its precomputed table (a PRBS's
bits, a playback's samples: :func:`table`) and ``t`` give the value, in plain
float arithmetic in a fixed order. :class:`StimulusSource` sums the profiles
of each input in the order given and clips the sum to the input's range;
:meth:`StimulusSource.transitions` reports each profile's start and end once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.signal import max_len_seq

from protocol.stimulus import Chirp, Playback, Prbs, Profile, Ramp, Sine, Step, StimulusPlan
from protocol.stimulus_inputs import lookup

__all__ = ["EDGE_S", "StimulusSource", "Transition", "active", "prbs_bits", "profile_value", "table"]

FloatArray = npt.NDArray[np.float64]
EDGE_S: Final[float] = 1e-9
"""Tolerance of a window's edges (s), as the plant's scenario and channel faults use."""
TWO_PI: Final[float] = 2.0 * math.pi


def prbs_bits(register_bits: int, seed: int) -> FloatArray:
    """One period (``2**register_bits - 1``) of the maximal-length sequence
    (scipy.signal.max_len_seq) as +-1, its register started from ``seed``
    reduced to a non-zero state."""
    period = (1 << register_bits) - 1
    start = seed % period + 1
    state = np.array([(start >> k) & 1 for k in range(register_bits)], dtype=np.int8)
    seq, _ = max_len_seq(register_bits, state=state)
    return np.asarray(seq, dtype=np.float64) * 2.0 - 1.0


def table(profile: Profile) -> tuple[FloatArray, FloatArray] | None:
    """What :func:`profile_value` reads besides the profile: a PRBS's bits
    ``(bits, empty)``, a playback's samples ``(t, value)``; None for the others."""
    if isinstance(profile, Prbs):
        return prbs_bits(profile.register_bits, profile.seed), np.zeros(0)
    if isinstance(profile, Playback):
        return profile.samples()
    return None


def active(profile: Profile, end: float | None, t: float) -> bool:
    """Whether ``t`` is inside the profile's window ``[at_s, end)`` (edges within :data:`EDGE_S`)."""
    return t + EDGE_S >= profile.at_s and (end is None or t + EDGE_S < end)


def profile_value(profile: Profile, data: tuple[FloatArray, FloatArray] | None, t: float) -> float:
    """The profile's value at simulated ``t`` (0 outside its window); ``data``: :func:`table`'s."""
    end = profile.end
    if not active(profile, end, t):
        return 0.0
    tau = t - profile.at_s
    if tau < 0.0:  # within the edge tolerance before the start
        tau = 0.0
    if isinstance(profile, Step):
        return profile.size
    if isinstance(profile, Ramp):
        if profile.to is not None:
            over = float(profile.over_s or 1.0)
            return profile.to * (tau / over) if tau < over else profile.to
        return float(profile.slope or 0.0) * tau
    if isinstance(profile, Sine):
        return profile.offset + profile.amplitude * math.sin(TWO_PI * profile.f_hz * tau + profile.phase_rad)
    if isinstance(profile, Chirp):
        return profile.amplitude * math.cos(_chirp_phase(profile, tau) + profile.phase_deg * (math.pi / 180.0))
    if isinstance(profile, Prbs):
        assert data is not None
        bits = data[0]
        k = int(math.floor((tau + EDGE_S) / profile.bit_s)) % bits.shape[0]  # a bit edge within EDGE_S counts as reached
        return profile.amplitude * float(bits[k])
    assert isinstance(profile, Playback) and data is not None
    ts, vs = data
    if profile.hold == "linear":
        return float(np.interp(tau, ts, vs))
    i = int(np.searchsorted(ts, tau + EDGE_S, side="right")) - 1
    return float(vs[i if i > 0 else 0])


def _chirp_phase(p: Chirp, tau: float) -> float:
    """scipy.signal.chirp's phase (rad) at ``tau`` (its ``t``), without ``phi``."""
    f0, f1, t1 = p.f0_hz, p.f1_hz, p.duration_s
    if p.method == "linear":
        beta = (f1 - f0) / t1
        return TWO_PI * (f0 * tau + 0.5 * beta * tau * tau)
    if f0 == f1:
        return TWO_PI * f0 * tau
    beta = t1 / math.log(f1 / f0)
    return TWO_PI * beta * f0 * (math.pow(f1 / f0, tau / t1) - 1.0)


@dataclass(frozen=True)
class Transition:
    """Profile ``index`` (in the plan's order) started (``started``) or ended at ``time_s``."""

    time_s: float
    index: int
    profile: Profile
    started: bool

    def describe(self) -> str:
        return f"profile {self.index} {'started' if self.started else 'ended'}: {self.profile.describe()}"


class StimulusSource:
    """The plan's profiles, each with its table, evaluated input by input."""

    def __init__(self, plan: StimulusPlan, ranges: dict[str, tuple[float, float]] | None = None) -> None:
        """``ranges``: an input's range where it is not the table's (a channel fault's size: the fault's own)."""
        self.plan = plan
        self.inputs = plan.inputs()
        self._profiles = [(n, p, p.end, table(p)) for n, p in enumerate(plan.profiles)]
        self._by_input = {name: [(p, end, d) for _, p, end, d in self._profiles if p.input == name] for name in self.inputs}
        self._ranges = {name: _range(name, ranges or {}) for name in self.inputs}
        self._started = [False] * len(self._profiles)
        self._ended = [False] * len(self._profiles)

    def value(self, name: str, t: float) -> float:
        """The input's value at ``t``: its profiles' values added in the plan's order, clipped to its range."""
        total = 0.0
        for p, _, d in self._by_input.get(name, ()):
            total = total + profile_value(p, d, t)
        low, high = self._ranges[name] if name in self._ranges else _range(name, {})
        return high if total > high else (low if total < low else total)

    def any_active(self, name: str, t: float) -> bool:
        """Whether a profile on the input is inside its window at ``t``."""
        return any(active(p, end, t) for p, end, _ in self._by_input.get(name, ()))

    def transitions(self, t: float) -> list[Transition]:
        """The profiles that started or ended by ``t`` since the last call, in the plan's order."""
        out: list[Transition] = []
        for n, p, end, _ in self._profiles:
            if not self._started[n] and t + EDGE_S >= p.at_s:
                self._started[n] = True
                out.append(Transition(p.at_s, n, p, True))
            if self._started[n] and not self._ended[n] and end is not None and t + EDGE_S >= end:
                self._ended[n] = True
                out.append(Transition(end, n, p, False))
        return out


def _range(name: str, ranges: dict[str, tuple[float, float]]) -> tuple[float, float]:
    if name in ranges:
        return ranges[name]
    spec = lookup(name)
    assert spec is not None, name
    return spec.low, spec.high
