"""A run of internal steps of :class:`~plant_emulator.model.arm.RalfArm` as one compiled call.

Per internal step :func:`advance_steps` takes the two cylinders through
their exact lag solution with flow saturation and hard stops
(:func:`cylinder_step`, :mod:`.hydraulics`), the pin triangles' law of
cosines and lever arms (:func:`joint_angle_and_rate`), the flexible links'
exact modal step at the mid configuration (:func:`links_step`, with
:func:`modal_step`: the links' coefficients, thesis Ch. 3, as
:func:`link_coefficients`; their two
M-orthonormal modes, the closed-form 2x2 generalized eigenproblem of
:func:`eigenvalues` and :func:`mode_shape`; each damped mode's exact
step for a constant force), the cameras' bending fractions
(:func:`camera_fractions`) and the deflection anti-alias filters with their
input noise (:func:`antialias_step`). Compiled with numba, no fastmath (no
FMA contraction, no reassociation; libm's transcendental functions), so the
floats do not depend on the compiler's choices. One sample period (5
steps) costs one call (docs/timing.md). The scalar functions are
``register_jitable``: called from Python (the arm's ground truth, the
vectorised views of :mod:`.modes`) they run as Python on the same floats.

The call stops early, after the step, when a cylinder arrives at a hard
stop (the caller records the event at that step's time), and before a step
when the noise block lacks a pair of deviates (the caller refills it with
the noise source's own rule).

The arrays are laid out by the named offsets below: the state ``st``
(``ST_*``, :data:`STATE_SIZE` floats, updated in place), the hydraulic and
joint parameters ``hp`` (``HP_*``), the sensor parameters ``sp`` (``SP_*``)
and the modal step's constant arguments ``ma`` (``MA_*``, in
:func:`modal_step`'s order). One file, so numba's on-disk cache (keyed on
this file) is renewed whenever any of it changes.
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from numba import njit
from numba.extending import register_jitable

# --- the state vector st (per cylinder / joint / link j = 0, 1) ---------------------------
ST_EXTENSION: Final = 0
"""Cylinder j's extension (in) at ST_EXTENSION + ST_CYLINDER * j."""
ST_VELOCITY: Final = 1
"""Cylinder j's lagged velocity (in/s) at ST_VELOCITY + ST_CYLINDER * j."""
ST_STOP_SIDE: Final = 2
"""Cylinder j's stop, -1.0 / 0.0 / +1.0 (lower, free, upper), at ST_STOP_SIDE + ST_CYLINDER * j."""
ST_CYLINDER: Final = 3
"""Floats per cylinder."""
ST_THETA: Final = 6
"""Joint angles theta_j (rad) at ST_THETA + j."""
ST_THETA_DOT: Final = 8
"""Joint rates (rad/s) at ST_THETA_DOT + j."""
ST_BETA: Final = 10
"""Link bending coordinates beta_j (rad) at ST_BETA + j."""
ST_BETA_DOT: Final = 12
"""Their rates at ST_BETA_DOT + j."""
ST_FRACTION: Final = 14
"""The share of link j's tip deflection the camera sees at ST_FRACTION + j."""
ST_ANTIALIAS: Final = 16
"""Link j's anti-alias filter state (two floats; the first is the output) at ST_ANTIALIAS + 2 * j."""
STATE_SIZE: Final = 20

# --- the hydraulic and joint parameters hp ------------------------------------------------
HP_STEP: Final = 0
"""The internal step h (s)."""
HP_DECAY: Final = 1
"""exp(-h / tau)."""
HP_TAU: Final = 2
"""The valve time constant tau (s), both cylinders."""
HP_CYLINDER: Final = 3
"""Cylinder j's gain, speed limit, lower and upper extension limit at HP_CYLINDER + 4 * j + CYL_*."""
CYL_GAIN: Final = 0
CYL_VMAX: Final = 1
CYL_LO: Final = 2
CYL_HI: Final = 3
HP_JOINT: Final = 11
"""Joint j's pin-triangle constants (``arm._JOINT[j]``, JOINT_*) at HP_JOINT + 6 * j."""
JOINT_RETRACTED: Final = 0
JOINT_P2Q2: Final = 1
JOINT_TWO_P_Q: Final = 2
JOINT_OFFSET: Final = 3
JOINT_PQ: Final = 4
JOINT_TWO_PQ: Final = 5
HP_CAMERA_ON_LINK: Final = 23
"""1.0: the cameras see the bending only (``camera_on_link``)."""
HP_SENSOR_NOISE: Final = 24
"""1.0: noise at the anti-alias filters' input."""
HP_SIZE: Final = 25

# --- the sensor parameters sp -------------------------------------------------------------
SP_LINK_LENGTH: Final = 0
"""L1, L2 (m) at SP_LINK_LENGTH + j."""
SP_INCH: Final = 2
SP_ZERO: Final = 3
"""The deflection sensors' zero (in) at SP_ZERO + j."""
SP_NOISE_STD: Final = 5
"""Input noise standard deviation (in) at SP_NOISE_STD + j."""
SP_FILTER: Final = 7
"""The anti-alias filter's a11, a12, a21, a22, b1, b2."""
SP_SIZE: Final = 13

# --- the modal step's constant arguments ma (those read here) -----------------------------
MA_KR1: Final = 6
MA_KC1: Final = 7
MA_KR2: Final = 8
MA_KBAR_R2: Final = 9
MA_BETA_C: Final = 10
MA_OFFSET1: Final = 15
MA_PQ: Final = 16
MA_PQ2: Final = 17
MA_SIZE: Final = 20
"""The modal step's constant arguments (:func:`~.modes.modal_arguments`); the arm's arrays add three after them:"""
MA_FORCE1: Final = 20
"""ma[MA_FORCE1], ma[MA_FORCE1 + 1]: the disturbance forces at the tips of links 1 and 2 (N), perpendicular to each link."""
MA_L2: Final = 22
"""ma[MA_L2]: link 2's length (m), the lever of its tip force."""
MA_SIZE_FORCES: Final = 23

STATUS_DONE: Final = 0
STATUS_NOISE: Final = 1
"""Stopped before a step: the noise block has fewer than two deviates left."""
STATUS_STOP: Final = 2
"""Stopped after a step in which a cylinder arrived at a hard stop."""


def _jitable(fn: Any) -> Any:
    """Callable from the compiled kernel and from Python."""
    return register_jitable(fn)


# --- the flexible links' modal data at one configuration --------------------------------


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
def eigenvalues(M11: float, M12: float, M22: float, K11: float, K12: float, K22: float) -> tuple[float, float]:
    """The two eigenvalues w^2 of K x = w^2 M x (2x2, symmetric, M positive definite),
    ascending: the roots of det(K - w^2 M) = 0 in closed form."""
    a = M11 * M22 - M12 * M12
    b = -(K11 * M22 + K22 * M11 - 2.0 * K12 * M12)
    c = K11 * K22 - K12 * K12
    d = b * b - 4.0 * a * c
    disc = math.sqrt(d) if d > 0.0 else 0.0
    return (-b - disc) / (2.0 * a), (-b + disc) / (2.0 * a)


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
    lam1, lam2 = eigenvalues(M11, M12, M22, K11, K12, K22)
    p11, p21 = mode_shape(lam1, 0, M11, M12, M22, K11, K12, K22)
    p12, p22 = mode_shape(lam2, 1, M11, M12, M22, K11, K12, K22)
    s1 = mode_step(lam1, z1, h)
    s2 = mode_step(lam2, z2, h)
    return (*co, p11, p21, p12, p22, *s1, *s2)


@_jitable
def cylinder_step(st: npt.NDArray[np.float64], hp: npt.NDArray[np.float64], j: int, volts: float) -> tuple[bool, float, int]:
    """Cylinder j over one step of constant valve voltage (:mod:`.hydraulics`): the
    exact first-order lag solution, flow saturation, hard stops. Returns
    (arrived at a stop, the free speed it arrived with, the stop's side)."""
    h = hp[HP_STEP]
    a = hp[HP_DECAY]
    tau = hp[HP_TAU]
    k = HP_CYLINDER + 4 * j
    vmax = hp[k + CYL_VMAX]
    u = hp[k + CYL_GAIN] * volts
    u = vmax if u > vmax else (-vmax if u < -vmax else u)
    s = ST_CYLINDER * j
    e0 = st[s + ST_EXTENSION]
    v0 = st[s + ST_VELOCITY]
    side = int(st[s + ST_STOP_SIDE])
    arrived = False
    v_free = 0.0
    if (side > 0 and u >= 0.0) or (side < 0 and u <= 0.0):  # resting on a stop, pushed into it
        e1 = e0
        v1 = 0.0
        new_side = side
    else:
        v1 = u + (v0 - u) * a
        e1 = e0 + u * h + (v0 - u) * tau * (1.0 - a)
        new_side = 0
        v_free = v1
        if e1 >= hp[k + CYL_HI]:
            e1 = hp[k + CYL_HI]
            v1 = 0.0
            new_side = 1
            arrived = side != 1
        elif e1 <= hp[k + CYL_LO]:
            e1 = hp[k + CYL_LO]
            v1 = 0.0
            new_side = -1
            arrived = side != -1
    st[s + ST_EXTENSION] = e1
    st[s + ST_VELOCITY] = v1
    st[s + ST_STOP_SIDE] = float(new_side)
    return arrived, abs(v_free), new_side


@_jitable
def joint_angle_and_rate(hp: npt.NDArray[np.float64], j: int, extension: float, velocity: float) -> tuple[float, float]:
    """Joint j's angle (law of cosines in its pin triangle) and rate (cylinder velocity over the lever arm)."""
    k = HP_JOINT + 6 * j
    p2q2 = hp[k + JOINT_P2Q2]
    offset = hp[k + JOINT_OFFSET]
    length = extension + hp[k + JOINT_RETRACTED]
    cg = (p2q2 - length * length) / hp[k + JOINT_TWO_P_Q]
    cl = cg if cg > -1.0 else -1.0  # max(-1.0, cg)
    cl = cl if cl < 1.0 else 1.0  # min(1.0, ...)
    th = math.acos(cl) - offset
    g = th + offset
    lever = hp[k + JOINT_PQ] * math.sin(g) / math.sqrt(p2q2 - hp[k + JOINT_TWO_PQ] * math.cos(g))
    return th, velocity / lever


@_jitable
def links_step(st: npt.NDArray[np.float64], ma: npt.NDArray[np.float64], tm0: float, tm1: float, acc0: float, acc1: float) -> None:
    """The flexible links' exact modal step at the mid configuration (tm0, tm1)
    under the joints' acceleration: beta and beta' in ``st``. With the arm's
    tip forces (``ma[MA_FORCE1:MA_FORCE1 + 2]``, not zero) their generalized
    loads join the right side of M q'' + D q' + K q = E f [2-1, 2-2]: a force
    ``F1`` at link 1's tip does the virtual work ``F1 L1 dbeta1``, a force
    ``F2`` at link 2's tip ``F2 ((L1 cos theta2 + kappa L2) dbeta1 + L2 dbeta2)``
    (the tip's displacement perpendicular to link 2, as in ``M12``)."""
    r = modal_step(
        tm0,
        tm1,
        ma[0],
        ma[1],
        ma[2],
        ma[3],
        ma[4],
        ma[5],
        ma[6],
        ma[7],
        ma[8],
        ma[9],
        ma[10],
        ma[11],
        ma[12],
        ma[13],
        ma[14],
        ma[15],
        ma[16],
        ma[17],
        ma[18],
        ma[19],
    )
    M11 = r[0]
    M12 = r[1]
    M22 = r[2]
    f1 = r[10] - r[6] * acc0 - r[7] * acc1  # G1 - E11 acc0 - E12 acc1
    f2 = r[11] - r[8] * acc0 - r[9] * acc1  # G2 - E21 acc0 - E22 acc1
    if ma.shape[0] >= MA_SIZE_FORCES:  # tip forces: their generalized loads J^T F beside G [2-1, 2-2]
        fa = ma[MA_FORCE1]
        fb = ma[MA_FORCE1 + 1]
        if fa != 0.0 or fb != 0.0:
            l1 = ma[19]
            l2 = ma[MA_L2]
            f1 = f1 + fa * l1 + fb * (l1 * math.cos(tm1) + ma[5] * l2)
            f2 = f2 + fb * l2
    b1 = st[ST_BETA]
    b2 = st[ST_BETA + 1]
    vb1 = st[ST_BETA_DOT]
    vb2 = st[ST_BETA_DOT + 1]
    mb1 = M11 * b1 + M12 * b2
    mb2 = M12 * b1 + M22 * b2
    mv1 = M11 * vb1 + M12 * vb2
    mv2 = M12 * vb1 + M22 * vb2
    nb1 = 0.0
    nb2 = 0.0
    nv1 = 0.0
    nv2 = 0.0
    for m in range(2):
        pa = r[12 + 2 * m]
        pb = r[13 + 2 * m]
        w2 = r[16 + 4 * m]
        sig = r[17 + 4 * m]
        c = r[18 + 4 * m]
        s = r[19 + 4 * m]
        eta = pa * mb1 + pb * mb2
        eta_d = pa * mv1 + pb * mv2
        xs = (pa * f1 + pb * f2) / w2
        x0 = eta - xs
        x1 = c * x0 + s * (eta_d + sig * x0) + xs
        vv = c * eta_d - s * (sig * eta_d + w2 * x0)
        nb1 += pa * x1
        nb2 += pb * x1
        nv1 += pa * vv
        nv2 += pb * vv
    st[ST_BETA] = nb1
    st[ST_BETA + 1] = nb2
    st[ST_BETA_DOT] = nv1
    st[ST_BETA_DOT + 1] = nv2


@_jitable
def camera_fractions(ma: npt.NDArray[np.float64], inch: float, theta0: float, theta1: float) -> tuple[float, float]:
    """The share of each tip deflection the cameras see, ``k_i / k_ri``
    (:func:`~plant_emulator.model.modes.bending_fractions` explains it)."""
    gamma = theta0 + ma[MA_OFFSET1]
    pq1 = ma[MA_PQ]
    lever1_m = pq1 * math.sin(gamma) / math.sqrt(ma[MA_PQ2] - 2.0 * pq1 * math.cos(gamma)) * inch
    sbar = math.sin(theta1 + ma[MA_BETA_C])
    kr1 = ma[MA_KR1]
    kr2 = ma[MA_KR2]
    k1 = 1.0 / (1.0 / kr1 + 1.0 / (ma[MA_KC1] * lever1_m * lever1_m))
    k2 = 1.0 / (1.0 / kr2 + 1.0 / (ma[MA_KBAR_R2] * sbar * sbar))
    return k1 / kr1, k2 / kr2


@_jitable
def antialias_step(st: npt.NDArray[np.float64], sp: npt.NDArray[np.float64], j: int, u: float) -> None:
    """Link j's anti-alias filter (``sensors.AntiAliasFilter``) over one step of input ``u``."""
    k = ST_ANTIALIAS + 2 * j
    x1 = st[k]
    x2 = st[k + 1]
    st[k] = sp[SP_FILTER] * x1 + sp[SP_FILTER + 1] * x2 + sp[SP_FILTER + 4] * u
    st[k + 1] = sp[SP_FILTER + 2] * x1 + sp[SP_FILTER + 3] * x2 + sp[SP_FILTER + 5] * u


@_jitable
def sensed_deflections(st: npt.NDArray[np.float64], sp: npt.NDArray[np.float64]) -> tuple[float, float]:
    """What the cameras see of the tip deflections (in): bending fraction x L x beta."""
    inch = sp[SP_INCH]
    w0 = st[ST_FRACTION] * sp[SP_LINK_LENGTH] * st[ST_BETA] / inch
    w1 = st[ST_FRACTION + 1] * sp[SP_LINK_LENGTH + 1] * st[ST_BETA + 1] / inch
    return w0, w1


def _advance_steps(
    n: int,
    volts0: float,
    volts1: float,
    st: npt.NDArray[np.float64],
    hp: npt.NDArray[np.float64],
    sp: npt.NDArray[np.float64],
    ma: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    nxt: int,
) -> tuple[int, int, int, int, float, int, int, float, int]:
    h = hp[HP_STEP]
    camera = hp[HP_CAMERA_ON_LINK] != 0.0
    noisy = hp[HP_SENSOR_NOISE] != 0.0
    arr0, spd0, side0, arr1, spd1, side1 = False, 0.0, 0, False, 0.0, 0
    for i in range(n):
        if noisy and nxt + 2 > noise.shape[0]:
            return i, nxt, STATUS_NOISE, 0, 0.0, 0, 0, 0.0, 0
        th00 = st[ST_THETA]
        th01 = st[ST_THETA + 1]
        # 1. hydraulics, then the joints they drive
        arr0, spd0, side0 = cylinder_step(st, hp, 0, volts0)
        arr1, spd1, side1 = cylinder_step(st, hp, 1, volts1)
        th0, rate0 = joint_angle_and_rate(hp, 0, st[ST_EXTENSION], st[ST_VELOCITY])
        th1, rate1 = joint_angle_and_rate(hp, 1, st[ST_CYLINDER + ST_EXTENSION], st[ST_CYLINDER + ST_VELOCITY])
        # 2. joint acceleration over the step; 3. flexible links at the mid configuration
        acc0 = (rate0 - st[ST_THETA_DOT]) / h
        acc1 = (rate1 - st[ST_THETA_DOT + 1]) / h
        w_old0, w_old1 = sensed_deflections(st, sp)
        links_step(st, ma, 0.5 * (th00 + th0), 0.5 * (th01 + th1), acc0, acc1)
        st[ST_THETA] = th0
        st[ST_THETA + 1] = th1
        st[ST_THETA_DOT] = rate0
        st[ST_THETA_DOT + 1] = rate1
        # 4. bending fractions and the anti-alias filters, noise at their input
        f0, f1 = camera_fractions(ma, sp[SP_INCH], th0, th1) if camera else (1.0, 1.0)
        st[ST_FRACTION] = f0
        st[ST_FRACTION + 1] = f1
        w_new0, w_new1 = sensed_deflections(st, sp)
        n0 = 0.0
        n1 = 0.0
        if noisy:
            n0 = noise[nxt]
            n1 = noise[nxt + 1]
            nxt += 2
        antialias_step(st, sp, 0, 0.5 * (w_old0 + w_new0) - sp[SP_ZERO] + sp[SP_NOISE_STD] * n0)
        antialias_step(st, sp, 1, 0.5 * (w_old1 + w_new1) - sp[SP_ZERO + 1] + sp[SP_NOISE_STD + 1] * n1)
        if arr0 or arr1:
            return i + 1, nxt, STATUS_STOP, int(arr0), spd0 if arr0 else 0.0, side0 if arr0 else 0, int(arr1), spd1 if arr1 else 0.0, side1 if arr1 else 0
    return n, nxt, STATUS_DONE, 0, 0.0, 0, 0, 0.0, 0


def _compiled() -> Any:
    try:
        return njit(cache=True)(_advance_steps)
    except RuntimeError:  # no writable cache location: compile in memory only
        return njit(_advance_steps)


advance_steps: Any = _compiled()
"""Compiled (cached on disk; compiled by :func:`warm_up` before the first tick)."""


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) now, not in the first tick:
    images and CI call it once at install time so no service spends its
    start-up compiling."""
    _warm(advance_steps)


def _warm(fn: Any) -> None:
    st = np.zeros(STATE_SIZE)
    st[ST_EXTENSION] = st[ST_CYLINDER + ST_EXTENSION] = 5.0
    hp = np.ones(HP_SIZE)
    for j in (0, 1):
        hp[HP_CYLINDER + 4 * j + CYL_LO] = 0.0
        hp[HP_CYLINDER + 4 * j + CYL_HI] = 10.0
        hp[HP_JOINT + 6 * j + JOINT_P2Q2] = 900.0
        hp[HP_JOINT + 6 * j + JOINT_TWO_P_Q] = 1700.0
    sp = np.ones(SP_SIZE)
    ma = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 1e4, 1e6, 1e4, 1e4, 0.1, 9.81, 0.02, 0.02, 1e-3, -0.5, 900.0, 1800.0, 0.0254, 1.0])
    fn(1, 0.0, 0.0, st, hp, sp, ma, np.zeros(4), 0)
