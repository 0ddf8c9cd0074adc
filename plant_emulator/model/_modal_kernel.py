"""One internal step's modal data as a single compiled call.

:func:`modal_step` is :func:`plant_emulator.model.modes.coefficients_scalar`,
:func:`~plant_emulator.model.modes.eig2_scalar` and the per-mode exact-step
coefficients of :meth:`RalfArm._modal`, written out on floats with the same
operations in the same order, so compiled (numba, no fastmath: no FMA
contraction, no reassociation; libm's sin/cos/exp, hardware sqrt) it gives
the Python expressions' results bit for bit (checked over the co-simulation
run and a sweep of configurations, ``tests/plant``). Without numba the same
function runs as Python.
"""

from __future__ import annotations

import math
from typing import Any

try:  # numba is optional: the plain-Python function gives the same floats
    from numba import njit as _njit
    from numba.extending import register_jitable as _register_jitable
except ImportError:  # pragma: no cover - depends on the environment
    _njit = None  # type: ignore[assignment]  # the compiler is absent: the Python function runs
    _register_jitable = None  # type: ignore[assignment]


def _modal_step(
    tm1: float,
    tm2: float,
    I1: float,
    Mt: float,
    S: float,
    Ia: float,
    A1: float,
    kap: float,
    kr1: float,
    kc1: float,
    kr2: float,
    kbar_r2: float,
    beta_c: float,
    g: float,
    z1: float,
    z2: float,
    h: float,
    offset1: float,
    pq: float,
    pq2: float,
    inch: float,
    l1: float,
) -> tuple[float, ...]:
    # coefficients_scalar
    gamma = tm1 + offset1
    length = math.sqrt(pq2 - 2.0 * pq * math.cos(gamma))
    lever1_m = pq * math.sin(gamma) / length * inch
    t12 = tm1 + tm2
    c1 = math.cos(tm1)
    s1 = math.sin(tm1)
    c12 = math.cos(t12)
    s12 = math.sin(t12)
    c2 = math.cos(tm2)
    sbar = math.sin(tm2 + beta_c)
    # _coefficients
    LS = l1 * S
    base = I1 + Mt * l1 * l1
    M11 = base + 2.0 * kap * LS * c2 + kap * kap * Ia
    M12 = LS * c2 + kap * Ia
    M22 = Ia + 0.0 * c2
    E11 = base + (1.0 + kap) * LS * c2 + kap * Ia
    E12 = LS * c2 + kap * Ia
    E21 = LS * c2 + Ia
    E22 = Ia + 0.0 * c2
    k1 = 1.0 / (1.0 / kr1 + 1.0 / (kc1 * lever1_m * lever1_m))
    k2 = 1.0 / (1.0 / kr2 + 1.0 / (kbar_r2 * sbar * sbar))
    gs = g * S * s12
    K11 = k1 - g * A1 * s1 - kap * kap * gs
    K12 = -kap * gs
    K22 = k2 - gs
    G1 = -g * (A1 * c1 + kap * S * c12)
    G2 = -g * S * c12
    # eig2_scalar
    a = M11 * M22 - M12 * M12
    b = -(K11 * M22 + K22 * M11 - 2.0 * K12 * M12)
    c = K11 * K22 - K12 * K12
    d = b * b - 4.0 * a * c
    disc = math.sqrt(d) if d > 0.0 else 0.0
    lam1 = (-b - disc) / (2.0 * a)
    lam2 = (-b + disc) / (2.0 * a)
    p = [0.0, 0.0, 0.0, 0.0]
    st = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    for r in range(2):
        lr = lam1 if r == 0 else lam2
        r11 = K11 - lr * M11
        r12 = K12 - lr * M12
        r22 = K22 - lr * M22
        if r11 * r11 + r12 * r12 >= r12 * r12 + r22 * r22:
            x = -r12
            y = r11
        else:
            x = r22
            y = -r12
        if x == 0.0 and y == 0.0:
            if r == 0:
                x = 1.0
                y = 0.0
            else:
                x = 0.0
                y = 1.0
        norm = math.sqrt(x * x * M11 + 2.0 * x * y * M12 + y * y * M22)
        p[2 * r] = x / norm
        p[2 * r + 1] = y / norm
        # the exact step of the damped mode (RalfArm._modal)
        zeta = z1 if r == 0 else z2
        if lr < 0.0 or zeta * zeta > 1.0:  # math.sqrt's domain error, compiled or not
            raise ValueError("math domain error")
        w = math.sqrt(lr)
        sig = zeta * w
        wd = w * math.sqrt(1.0 - zeta * zeta)
        e = math.exp(-sig * h)
        st[4 * r] = w * w
        st[4 * r + 1] = sig
        st[4 * r + 2] = e * math.cos(wd * h)
        st[4 * r + 3] = e * math.sin(wd * h) / wd
    return (
        M11,
        M12,
        M22,
        K11,
        K12,
        K22,
        E11,
        E12,
        E21,
        E22,
        G1,
        G2,
        p[0],
        p[1],
        p[2],
        p[3],
        st[0],
        st[1],
        st[2],
        st[3],
        st[4],
        st[5],
        st[6],
        st[7],
    )


def _compiled() -> Any:
    if _njit is None:
        return _modal_step
    try:
        return _njit(cache=True)(_modal_step)
    except RuntimeError:  # no writable cache location: compile in memory only
        return _njit(_modal_step)


modal_step_py = _modal_step
modal_step_jitable: Any = _modal_step if _register_jitable is None else _register_jitable(_modal_step)
"""The same function, callable from compiled code (``._period_kernel``) and from Python."""
modal_step: Any = _compiled()
"""Compiled when numba is installed (cached on disk; compiled by :func:`warm_up` before the first tick)."""


def warm_up() -> None:
    """Compile (or load from the cache) now, not in the first tick; a
    compiler that fails leaves the plain-Python function in place."""
    global modal_step
    try:
        _warm(modal_step)
    except Exception:  # noqa: BLE001 - numba's errors are many; Python gives the same floats
        modal_step = _modal_step
        _warm(modal_step)


def _warm(fn: Any) -> None:
    fn(1.0, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 1e4, 1e6, 1e4, 1e4, 0.1, 9.81, 0.02, 0.02, 1e-3, -0.5, 900.0, 1800.0, 0.0254, 1.0)
