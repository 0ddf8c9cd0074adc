"""One internal step's modal data, callable from the compiled period (:mod:`._period_kernel`).

:func:`modal_step` gives the flexible links' coefficients at a configuration
(:func:`link_coefficients`, thesis Ch. 3, as
:func:`plant_emulator.model.modes.coefficients_scalar`), their two
M-orthonormal modes (:func:`mode_shape`, the closed-form 2x2 generalized
eigenproblem of :func:`~plant_emulator.model.modes.eig2_scalar`) and each
damped mode's exact step over ``h`` for a constant force
(:func:`mode_step`). Compiled with numba inside the period kernel, no
fastmath (no FMA contraction, no reassociation; libm's sin/cos/exp, hardware
sqrt); without numba the same functions run as Python.
"""

from __future__ import annotations

import math
from typing import Any

try:  # numba is optional: the plain-Python functions give the same floats
    from numba.extending import register_jitable as _register_jitable
except ImportError:  # pragma: no cover - depends on the environment
    _register_jitable = None  # type: ignore[assignment]  # the compiler is absent: the Python functions run


def _jitable(fn: Any) -> Any:
    return fn if _register_jitable is None else _register_jitable(fn)


@_jitable
def link_coefficients(
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
    offset1: float,
    pq: float,
    pq2: float,
    inch: float,
    l1: float,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float]:
    """(M11, M12, M22, K11, K12, K22, E11, E12, E21, E22, G1, G2) at joint angles (tm1, tm2)."""
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
    return M11, M12, M22, K11, K12, K22, E11, E12, E21, E22, G1, G2


@_jitable
def mode_shape(lr: float, r: int, M11: float, M12: float, M22: float, K11: float, K12: float, K22: float) -> tuple[float, float]:
    """The M-normalized eigenvector of eigenvalue ``lr`` (mode ``r`` = 0, 1) of K x = lr M x."""
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
    return x / norm, y / norm


@_jitable
def mode_step(lr: float, zeta: float, h: float) -> tuple[float, float, float, float]:
    """A damped mode's exact step over ``h``: (w^2, zeta w, e^(-zeta w h) cos(wd h), e^(-zeta w h) sin(wd h) / wd)."""
    if lr < 0.0 or zeta * zeta > 1.0:  # math.sqrt's domain error, compiled or not
        raise ValueError("math domain error")
    w = math.sqrt(lr)
    sig = zeta * w
    wd = w * math.sqrt(1.0 - zeta * zeta)
    e = math.exp(-sig * h)
    return w * w, sig, e * math.cos(wd * h), e * math.sin(wd * h) / wd


@_jitable
def modal_step(
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
    """The 12 coefficients of :func:`link_coefficients`, the two mode shapes
    (p11, p21, p12, p22) and the two modes' :func:`mode_step` (24 floats)."""
    co = link_coefficients(tm1, tm2, I1, Mt, S, Ia, A1, kap, kr1, kc1, kr2, kbar_r2, beta_c, g, offset1, pq, pq2, inch, l1)
    M11, M12, M22, K11, K12, K22 = co[0], co[1], co[2], co[3], co[4], co[5]
    # the 2x2 generalized eigenvalues (eig2_scalar)
    a = M11 * M22 - M12 * M12
    b = -(K11 * M22 + K22 * M11 - 2.0 * K12 * M12)
    c = K11 * K22 - K12 * K12
    d = b * b - 4.0 * a * c
    disc = math.sqrt(d) if d > 0.0 else 0.0
    lam1 = (-b - disc) / (2.0 * a)
    lam2 = (-b + disc) / (2.0 * a)
    p11, p21 = mode_shape(lam1, 0, M11, M12, M22, K11, K12, K22)
    p12, p22 = mode_shape(lam2, 1, M11, M12, M22, K11, K12, K22)
    s1 = mode_step(lam1, z1, h)
    s2 = mode_step(lam2, z2, h)
    return (*co, p11, p21, p12, p22, *s1, *s2)


modal_step_jitable: Any = modal_step
"""The same function, callable from compiled code (``._period_kernel``) and from Python."""
