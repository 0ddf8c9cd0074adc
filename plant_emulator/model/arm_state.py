"""The arm's integrated state by name: a frozen view of the period kernel's
state vector (:mod:`.period_kernel`, its ``ST_*`` offsets), read when the
ground truth needs it and written once when the arm starts."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from plant_emulator.model import period_kernel as pk

Pair = tuple[float, float]


class ArmState(NamedTuple):
    """Per cylinder, joint and link (index 0, 1) at one grid point (a named
    tuple: read once per ground-truth sample, so built cheaply)."""

    extensions_in: Pair
    velocities_in_s: Pair
    """The cylinders' lagged velocities."""
    stop_sides: tuple[int, int]
    """-1 resting on the lower stop, +1 on the upper, 0 free."""
    theta_rad: Pair
    theta_dot_rad_s: Pair
    beta_rad: Pair
    """The links' bending coordinates (thesis Ch. 3)."""
    beta_dot_rad_s: Pair
    fractions: Pair
    """The share of each tip deflection the camera sees."""
    antialias: tuple[Pair, Pair]
    """Each deflection channel's anti-alias filter state; the first float is its output."""

    @classmethod
    def read(cls, st: npt.NDArray[np.float64]) -> ArmState:
        """The named values of the kernel's state vector ``st``."""
        v = st.tolist()

        def pair(at: int, stride: int = 1) -> Pair:
            return v[at], v[at + stride]

        c = pk.ST_CYLINDER
        a = pk.ST_ANTIALIAS
        return cls(
            pair(pk.ST_EXTENSION, c),
            pair(pk.ST_VELOCITY, c),
            (int(v[pk.ST_STOP_SIDE]), int(v[c + pk.ST_STOP_SIDE])),
            pair(pk.ST_THETA),
            pair(pk.ST_THETA_DOT),
            pair(pk.ST_BETA),
            pair(pk.ST_BETA_DOT),
            pair(pk.ST_FRACTION),
            ((v[a], v[a + 1]), (v[a + 2], v[a + 3])),
        )

    def write(self, st: npt.NDArray[np.float64]) -> None:
        """Into the kernel's state vector ``st`` (:data:`~.period_kernel.STATE_SIZE` floats)."""
        for j in (0, 1):
            k = pk.ST_CYLINDER * j
            st[k + pk.ST_EXTENSION], st[k + pk.ST_VELOCITY], st[k + pk.ST_STOP_SIDE] = self.extensions_in[j], self.velocities_in_s[j], self.stop_sides[j]
            st[pk.ST_THETA + j], st[pk.ST_THETA_DOT + j] = self.theta_rad[j], self.theta_dot_rad_s[j]
            st[pk.ST_BETA + j], st[pk.ST_BETA_DOT + j] = self.beta_rad[j], self.beta_dot_rad_s[j]
            st[pk.ST_FRACTION + j] = self.fractions[j]
            st[pk.ST_ANTIALIAS + 2 * j : pk.ST_ANTIALIAS + 2 * j + 2] = self.antialias[j]
