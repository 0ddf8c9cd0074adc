"""A run of internal steps of :class:`~plant_emulator.model.arm.RalfArm` as one compiled call.

:func:`advance_steps` is ``RalfArm._step`` (the reference, kept in Python
and tested against this) written out on floats and arrays: per internal step
the two cylinders (:meth:`CylinderAxis.step`, the exact lag solution with
flow saturation and hard stops), the pin triangles' law of cosines and lever
arms, the flexible links' exact modal step at the mid configuration
(:func:`._modal_kernel.modal_step`, inlined), the cameras' bending fractions
and the deflection anti-alias filters with their input noise. The same
operations in the same order (no fastmath: no FMA contraction, no
reassociation; libm's transcendental functions), so compiled it gives the
Python step's floats bit for bit. One sample period (5 steps) costs one
call instead of five Python steps (docs/timing.md).

The call stops early, after the step, when a cylinder arrives at a hard
stop (the caller records the event at that step's time), and before a step
when the noise block lacks a pair of deviates (the caller refills it with
the noise source's own rule). Without numba the same function runs as Python.

State ``st`` (float64[20], updated in place): extension, velocity and stop
side of cylinders 1 and 2 (0-5), theta (6, 7), theta' (8, 9), beta (10, 11),
beta' (12, 13), bending fractions (14, 15), anti-alias states (16-19).
Parameters ``hp`` (float64[25]): h, exp(-h/tau), tau, per cylinder gain,
v_max, lower and upper extension limits (3-10), per joint the pin triangle
constants of ``arm._JOINT`` (11-22), camera_on_link and sensor_noise as
0/1 (23, 24). ``sp`` (float64[13]): L1, L2, inch, zero 1 and 2, input
noise std 1 and 2, the anti-alias filter's a11, a12, a21, a22, b1, b2.
``ma``: the modal step's 20 constant arguments (``RalfArm._modal_args``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from plant_emulator.model import _modal_kernel

try:  # numba is optional: the plain-Python function gives the same floats
    from numba import njit as _njit
except ImportError:  # pragma: no cover - depends on the environment
    _njit = None  # type: ignore[assignment]

_modal = _modal_kernel.modal_step_jitable

STATUS_DONE = 0
STATUS_NOISE = 1
"""Stopped before a step: the noise block has fewer than two deviates left."""
STATUS_STOP = 2
"""Stopped after a step in which a cylinder arrived at a hard stop."""


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
    h = hp[0]
    a = hp[1]
    tau = hp[2]
    camera = hp[23] != 0.0
    noisy = hp[24] != 0.0
    l1 = sp[0]
    l2 = sp[1]
    inch = sp[2]
    z0 = sp[3]
    z1 = sp[4]
    dn0 = sp[5]
    dn1 = sp[6]
    a11 = sp[7]
    a12 = sp[8]
    a21 = sp[9]
    a22 = sp[10]
    fb1 = sp[11]
    fb2 = sp[12]
    n_noise = noise.shape[0]
    arr0 = 0
    arr1 = 0
    spd0 = 0.0
    spd1 = 0.0
    side_out0 = 0
    side_out1 = 0
    for i in range(n):
        if noisy and nxt + 2 > n_noise:
            return i, nxt, STATUS_NOISE, 0, 0.0, 0, 0, 0.0, 0
        th00 = st[6]
        th01 = st[7]
        thd00 = st[8]
        thd01 = st[9]
        new_theta0 = 0.0
        new_theta1 = 0.0
        new_rate0 = 0.0
        new_rate1 = 0.0
        any_arrival = False
        for j in range(2):
            # 1. hydraulics: CylinderAxis.step
            gain = hp[3 + 4 * j]
            vmax = hp[4 + 4 * j]
            lo = hp[5 + 4 * j]
            hi = hp[6 + 4 * j]
            volts = volts0 if j == 0 else volts1
            u = gain * volts
            u = vmax if u > vmax else (-vmax if u < -vmax else u)
            v0 = st[1 + 3 * j]
            e0 = st[3 * j]
            side = int(st[2 + 3 * j])
            arrived = False
            v_free = 0.0
            if (side > 0 and u >= 0.0) or (side < 0 and u <= 0.0):
                e1 = e0
                v1 = 0.0
                new_side = side
            else:
                v1 = u + (v0 - u) * a
                e1 = e0 + u * h + (v0 - u) * tau * (1.0 - a)
                new_side = 0
                v_free = v1
                if e1 >= hi:
                    e1 = hi
                    v1 = 0.0
                    new_side = 1
                    arrived = side != 1
                elif e1 <= lo:
                    e1 = lo
                    v1 = 0.0
                    new_side = -1
                    arrived = side != -1
            st[3 * j] = e1
            st[1 + 3 * j] = v1
            st[2 + 3 * j] = float(new_side)
            if arrived:
                any_arrival = True
                if j == 0:
                    arr0 = 1
                    spd0 = abs(v_free)
                    side_out0 = new_side
                else:
                    arr1 = 1
                    spd1 = abs(v_free)
                    side_out1 = new_side
            # RalfArm._angle and RalfArm._lever
            k = 11 + 6 * j
            retracted = hp[k]
            p2q2 = hp[k + 1]
            two_p_q = hp[k + 2]
            offset = hp[k + 3]
            pq = hp[k + 4]
            two_pq = hp[k + 5]
            length = e1 + retracted
            cg = (p2q2 - length * length) / two_p_q
            cl = cg if cg > -1.0 else -1.0  # max(-1.0, cg)
            cl = cl if cl < 1.0 else 1.0  # min(1.0, ...)
            th = math.acos(cl) - offset
            g = th + offset
            lever = pq * math.sin(g) / math.sqrt(p2q2 - two_pq * math.cos(g))
            if j == 0:
                new_theta0 = th
                new_rate0 = v1 / lever
            else:
                new_theta1 = th
                new_rate1 = v1 / lever
        # 2. joint acceleration over the step
        acc0 = (new_rate0 - thd00) / h
        acc1 = (new_rate1 - thd01) / h
        # 3. flexible links at the mid configuration
        r = _modal(
            0.5 * (th00 + new_theta0),
            0.5 * (th01 + new_theta1),
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
        E11 = r[6]
        E12 = r[7]
        E21 = r[8]
        E22 = r[9]
        G1 = r[10]
        G2 = r[11]
        f1 = G1 - E11 * acc0 - E12 * acc1
        f2 = G2 - E21 * acc0 - E22 * acc1
        b1 = st[10]
        b2 = st[11]
        vb1 = st[12]
        vb2 = st[13]
        mb1 = M11 * b1 + M12 * b2
        mb2 = M12 * b1 + M22 * b2
        mv1 = M11 * vb1 + M12 * vb2
        mv2 = M12 * vb1 + M22 * vb2
        f_0 = st[14]
        f_1 = st[15]
        w_old0 = f_0 * l1 * b1 / inch
        w_old1 = f_1 * l2 * b2 / inch
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
        st[10] = nb1
        st[11] = nb2
        st[12] = nv1
        st[13] = nv2
        st[6] = new_theta0
        st[7] = new_theta1
        st[8] = new_rate0
        st[9] = new_rate1
        # 4. bending fractions (modes.bending_fractions_scalar) and the anti-alias filters
        if camera:
            gamma = new_theta0 + ma[15]
            pq1 = ma[16]
            lever1_m = pq1 * math.sin(gamma) / math.sqrt(ma[17] - 2.0 * pq1 * math.cos(gamma)) * inch
            sbar = math.sin(new_theta1 + ma[10])
            kr1 = ma[6]
            kr2 = ma[8]
            k1 = 1.0 / (1.0 / kr1 + 1.0 / (ma[7] * lever1_m * lever1_m))
            k2 = 1.0 / (1.0 / kr2 + 1.0 / (ma[9] * sbar * sbar))
            f_0 = k1 / kr1
            f_1 = k2 / kr2
        else:
            f_0 = 1.0
            f_1 = 1.0
        st[14] = f_0
        st[15] = f_1
        w_new0 = f_0 * l1 * nb1 / inch
        w_new1 = f_1 * l2 * nb2 / inch
        if noisy:
            n0 = noise[nxt]
            n1 = noise[nxt + 1]
            nxt += 2
        else:
            n0 = 0.0
            n1 = 0.0
        u0 = 0.5 * (w_old0 + w_new0) - z0 + dn0 * n0
        u1 = 0.5 * (w_old1 + w_new1) - z1 + dn1 * n1
        x1a = st[16]
        x2a = st[17]
        st[16] = a11 * x1a + a12 * x2a + fb1 * u0
        st[17] = a21 * x1a + a22 * x2a + fb2 * u0
        x1b = st[18]
        x2b = st[19]
        st[18] = a11 * x1b + a12 * x2b + fb1 * u1
        st[19] = a21 * x1b + a22 * x2b + fb2 * u1
        if any_arrival:
            return i + 1, nxt, STATUS_STOP, arr0, spd0, side_out0, arr1, spd1, side_out1
    return n, nxt, STATUS_DONE, 0, 0.0, 0, 0, 0.0, 0


def _compiled() -> Any:
    if _njit is None:
        return _advance_steps
    try:
        return _njit(cache=True)(_advance_steps)
    except RuntimeError:  # no writable cache location: compile in memory only
        return _njit(_advance_steps)


advance_steps_py = _advance_steps
advance_steps: Any = _compiled()
"""Compiled when numba is installed (cached on disk; compiled by :func:`warm_up` before the first tick)."""


def warm_up() -> None:
    """Compile (or load from the cache) now, not in the first tick; a
    compiler that fails leaves the plain-Python function in place."""
    global advance_steps
    try:
        _warm(advance_steps)
    except Exception:  # noqa: BLE001 - numba's errors are many; Python gives the same floats
        advance_steps = _advance_steps
        _warm(advance_steps)


def _warm(fn: Any) -> None:
    st = np.zeros(20)
    st[0] = st[3] = 5.0
    hp = np.ones(25)
    hp[5] = hp[9] = 0.0
    hp[6] = hp[10] = 10.0
    hp[12] = hp[18] = 900.0
    hp[13] = hp[19] = 1700.0
    sp = np.ones(13)
    ma = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 1e4, 1e6, 1e4, 1e4, 0.1, 9.81, 0.02, 0.02, 1e-3, -0.5, 900.0, 1800.0, 0.0254, 1.0])
    fn(1, 0.0, 0.0, st, hp, sp, ma, np.zeros(4), 0)
