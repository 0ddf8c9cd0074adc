"""One control tick of :class:`controller.loop.ControlLaw` as a single compiled call.

Engineering values [A.7, A.8], set-point, OATF (§3.3, [3-34]), PI (§4) and
the 12-bit D/A, on preallocated state arrays: the state the Python forms
keep (the OATF's delay line and head, the PI's integrator and last terms)
is the state this kernel reads and writes, so either form may run any tick.

Bit for bit the Python per-tick form (``ControlLaw._compute``), by
construction where a compiler could change the arithmetic:

* the joint angle of a word (``_angle``: libm's ``pow`` and numpy's
  ``arccos``, which may differ from ``x * x`` and ``math.acos``) is not
  recomputed: it is looked up in a table filled, one word at a time the
  first time the word is seen, by :func:`controller.engineering.measure_values`
  itself (65536 words per channel at most);
* the OATF's weighted sum is the one :meth:`controller.oatf.OatfFilter.step_values`
  defines: products added left to right, each rounded (:func:`oatf_dot`).
  No BLAS kernel takes part, so the bits do not depend on the host's
  library; :func:`sum_matches` still checks the compiled sum against the
  Python one when the kernels are warmed up (a compiler that fused a
  multiply-add would fail it), and the law keeps the Python form where it
  does not hold;
* everything else is the same IEEE operations in the same order (numba
  without fastmath: no reassociation, no contraction into FMA); Python's
  ``min``/``max`` are spelled out as the comparisons they make (the first
  argument wins a tie, so signed zeros come out as in Python) and
  ``round`` as ``np.rint`` (both round half to even; the codes are small).

:func:`warm_up` compiles (or loads from numba's on-disk cache) the kernel
and runs the sum check.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from controller.engineering import _CHANNELS, measure_values
from protocol.can_map import DAC12, WORD16_VOLTS_PER_LSB
from protocol.geometry import DELTA_RAD

__all__ = ["ANGLE_TABLE", "fill_angles", "law_consts", "law_tick", "oatf_dot", "sum_matches", "warm_up"]

ANGLE_TABLE: np.ndarray = np.full((2, 65536), np.nan)
"""theta1, theta2 (rad) per INT16 word of channels 1 and 2 (index ``word + 32768``); NaN: not computed yet."""

# Status codes of law_tick (0: done).
MISSING_ANGLE = -1
"""A word's angle is not in :data:`ANGLE_TABLE` yet: nothing was changed; fill it and call again."""
NON_FINITE = -2
"""An angle error is not finite: the OATF stepped (as in Python), the PI did not; the caller raises."""

_PI_CONSTS = 6
"""consts[0:6]: decay, scale, limit, threshold, floor, anti_windup (0/1); then kp, ki per joint."""
_DAC = _PI_CONSTS + 4
"""consts[_DAC:_DAC + 6]: ts, the D/A's LSB, its quantizer's bound, full scale, code min and max."""
_ENG = _DAC + 6
"""consts[_ENG:_ENG + 10]: volts per word LSB, (volts per unit, centre) of the four inputs, delta (rad)."""
N_CONSTS = _ENG + 10
PI_STATE = N_CONSTS
"""data[PI_STATE:ROW]: the PI's state (:attr:`controller.pi.PIController.state`, two joints)."""
ROW = PI_STATE + 16
"""data[ROW:SETPOINTS]: the tick's row."""
SETPOINTS = ROW + 25
"""data[SETPOINTS:]: the lap's set-points, (phi1, phi2) per tick."""
MODE = 4
"""ints[MODE]: the OATF's place (0 none, 1 outer, 2 inner)."""
HEAD = 5
"""ints[HEAD]: the OATF's delay-line head (:attr:`controller.oatf.OatfFilter.head_state`)."""
DITHER = 6
"""ints[DITHER]: the dither table's length in ticks (0: none); the table, (d0, d1) per tick, follows the set-points in ``data``."""
N_INTS = 7
"""The length of ``ints``."""


def _jit(fn: Any) -> Any:
    """``@njit(cache=True)``; compiled in memory only where numba finds no writable cache location."""
    try:
        return njit(cache=True)(fn)
    except RuntimeError:
        return njit(fn)


@_jit
def _pmin(a: float, b: float) -> float:
    """Python's ``min(a, b)``: ``a`` unless ``b < a``."""
    return b if b < a else a


@_jit
def _pmax(a: float, b: float) -> float:
    """Python's ``max(a, b)``: ``a`` unless ``b > a``."""
    return b if b > a else a


@_jit
def oatf_dot(weights: np.ndarray, buf: np.ndarray, rows: np.ndarray, j: int) -> float:
    """Channel ``j`` of the OATF's weighted taps [3-34], ``w0 x0 + w1 x1 + ...`` left to
    right (:meth:`controller.oatf.OatfFilter.step_values`' order and roundings)."""
    t = weights[0] * buf[rows[0], j]
    for i in range(1, weights.shape[0]):
        t = t + weights[i] * buf[rows[i], j]
    return t


@_jit
def _oatf_step(buf: np.ndarray, tap_rows: np.ndarray, weights: np.ndarray, ints: np.ndarray, x0: float, x1: float) -> tuple[float, float]:
    """:meth:`OatfFilter.step_values` of two channels: push, then the weighted taps (the head in ``ints[HEAD]``)."""
    head = (ints[HEAD] + 1) % buf.shape[0]
    ints[HEAD] = head
    buf[head, 0] = x0
    buf[head, 1] = x1
    rows = tap_rows[head]
    return oatf_dot(weights, buf, rows, 0), oatf_dot(weights, buf, rows, 1)


@_jit
def law_tick(
    tick: int,
    w0: int,
    w1: int,
    w2: int,
    w3: int,
    angles: np.ndarray,
    data: np.ndarray,
    ints: np.ndarray,
    obuf: np.ndarray,
    orows: np.ndarray,
    oweights: np.ndarray,
) -> int:
    """One tick of ``ControlLaw._compute``. ``data`` (float64, see
    :func:`law_data`): the constants (:func:`law_consts`), the PI's state
    (integrator per joint, then per joint the last terms: error, P, I,
    output, saturated, integrating, limited), the row (the values of
    :data:`controller.loop.ROW_NAMES`, the words as floats), the lap's
    set-points, then the dither table (``ints[DITHER]`` ticks of two valve
    values, :mod:`controller.excitation`). ``ints`` (int64, :data:`N_INTS`): the
    D/A codes and their saturation flags ``(c0, c1, s0, s1)``, the OATF mode
    (0 none, 1 outer, 2 inner), the head of its delay line ``obuf`` (moved in
    place), the dither's length. Few arguments: each
    array costs the dispatcher ~0.1 µs. Returns 0, or a negative status
    (``MISSING_ANGLE``; ``NON_FINITE``: ``row[0:2]`` then holds the errors)."""
    consts = data[:PI_STATE]
    pi_state = data[PI_STATE:ROW]
    row = data[ROW:SETPOINTS]
    codes = ints
    mode = ints[MODE]
    t1 = angles[0, w0 + 32768]
    t2 = angles[1, w1 + 32768]
    if t1 != t1 or t2 != t2:
        return MISSING_ANGLE
    c = _ENG
    lsb = consts[c]
    v0, v1, v2, v3 = w0 * lsb, w1 * lsb, w2 * lsb, w3 * lsb
    e0 = v0 / consts[c + 1] + consts[c + 2]
    e1 = v1 / consts[c + 3] + consts[c + 4]
    d0 = v2 / consts[c + 5] + consts[c + 6]
    d1 = v3 / consts[c + 7] + consts[c + 8]
    delta = consts[c + 9]
    phi1 = t1 - delta
    phi2 = t2 + delta
    n_dither = ints[DITHER]
    lap = (data.shape[0] - SETPOINTS - 2 * n_dither) // 2
    k = SETPOINTS + 2 * (tick % lap)
    ref1 = data[k]
    ref2 = data[k + 1]
    sh1, sh2 = ref1, ref2
    if mode == 1:
        sh1, sh2 = _oatf_step(obuf, orows, oweights, ints, ref1, ref2)
    err0 = sh1 - phi1
    err1 = sh2 - phi2
    if not (math.isfinite(err0) and math.isfinite(err1)):
        row[0] = err0
        row[1] = err1
        return NON_FINITE
    decay, scale, limit, threshold, floor = consts[0], consts[1], consts[2], consts[3], consts[4]
    anti_windup = consts[5] != 0.0
    u0 = 0.0
    u1 = 0.0
    for j in range(2):
        e = err0 if j == 0 else err1
        kpj = consts[_PI_CONSTS + j]
        kij = consts[_PI_CONSTS + 2 + j]
        decayed = decay * pi_state[j]
        p = kpj * e
        admit = abs(e) <= threshold
        value = decayed + scale * e if admit else decayed
        limited = False
        if anti_windup:
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
        pi_state[j] = value
        b = 2 + 7 * j
        pi_state[b] = e
        pi_state[b + 1] = p
        pi_state[b + 2] = i_term
        pi_state[b + 3] = out
        pi_state[b + 4] = 1.0 if abs(unclipped) >= floor else 0.0
        pi_state[b + 5] = 1.0 if admit and not limited else 0.0
        pi_state[b + 6] = 1.0 if limited else 0.0
        if j == 0:
            u0 = out
        else:
            u1 = out
    c = _DAC
    ts, dlsb, bound, fs, cmin, cmax = consts[c], consts[c + 1], consts[c + 2], consts[c + 3], consts[c + 4], consts[c + 5]
    if mode == 2:
        f0, f1 = _oatf_step(obuf, orows, oweights, ints, u0, u1)
        u0 = _pmin(_pmax(f0, -fs), fs)
        u1 = _pmin(_pmax(f1, -fs), fs)
    x0, x1 = u0, u1
    if n_dither > 0:
        kd = SETPOINTS + 2 * lap + 2 * (tick % n_dither)
        x0 = u0 + data[kd]
        x1 = u1 + data[kd + 1]
    for j in range(2):
        x = x0 if j == 0 else x1
        if x != x:
            code = 0.0
            sat = 1
        else:
            code = np.rint(_pmin(bound, _pmax(-bound, x)) / dlsb)
            sat = 1 if (code < cmin or code > cmax) else 0
            code = _pmin(cmax, _pmax(cmin, code))
        codes[j] = int(code)
        codes[2 + j] = sat
    row[0] = tick * ts
    row[1] = ref1
    row[2] = ref2
    row[3] = sh1
    row[4] = sh2
    row[5] = phi1
    row[6] = phi2
    row[7] = t1
    row[8] = t2
    row[9] = e0
    row[10] = e1
    row[11] = d0
    row[12] = d1
    row[13] = w0
    row[14] = w1
    row[15] = w2
    row[16] = w3
    row[17] = v0
    row[18] = v1
    row[19] = v2
    row[20] = v3
    row[21] = codes[0] * dlsb
    row[22] = codes[1] * dlsb
    row[23] = u0
    row[24] = u1
    return 0


def fill_angles(w0: int, w1: int) -> None:
    """Put the angles of words ``w0`` (channel 1) and ``w1`` (channel 2) in
    :data:`ANGLE_TABLE`, computed by :func:`measure_values` itself."""
    values = measure_values((w0, w1, 0, 0))
    ANGLE_TABLE[0, w0 + 32768] = values[8]
    ANGLE_TABLE[1, w1 + 32768] = values[9]


def law_consts(pi: Any, sample_period_s: float) -> np.ndarray:
    """The constants :func:`law_tick` takes: a :class:`~controller.pi.PIController`'s,
    the D/A's, the analog inputs' (as :func:`measure_values` reads them).
    Passed, not read as globals: numba's cache would keep stale values."""
    return np.array(
        [
            pi._decay,
            pi._scale,
            pi._limit,
            pi._threshold,
            pi._floor,
            1.0 if pi._anti_windup else 0.0,
            *pi._kp_list,
            *pi._ki_list,
            sample_period_s,
            DAC12.lsb_v,
            2.0 * DAC12.full_scale_v,
            DAC12.full_scale_v,
            float(DAC12.code_min),
            float(DAC12.code_max),
            WORD16_VOLTS_PER_LSB,
            *(x for ch in _CHANNELS for x in ch),
            DELTA_RAD,
        ],
        dtype=np.float64,
    )


_checked: bool | None = None


def sum_matches(samples: int = 64, max_taps: int = 12) -> bool:
    """Whether :func:`oatf_dot` gives the bits of the Python sum
    (:meth:`controller.oatf.OatfFilter.step_values`) on this host: random
    weights and delay lines, 1 to ``max_taps`` taps; computed once."""
    global _checked
    if _checked is None:
        rng = np.random.default_rng(20240521)
        ok = True
        for k in range(1, max_taps + 1):
            for _ in range(samples):
                w = rng.normal(size=k)
                buf = rng.normal(size=(k + 3, 2))
                rows = rng.permutation(k + 3)[:k].astype(np.int64)
                taps = buf.take(rows, 0).tolist()
                ref = [w[0] * v for v in taps[0]]
                for i in range(1, k):
                    ref = [o + w[i] * v for o, v in zip(ref, taps[i], strict=True)]
                if [oatf_dot(w, buf, rows, 0), oatf_dot(w, buf, rows, 1)] != ref:
                    ok = False
                    break
            if not ok:
                break
        _checked = ok
    return _checked


def fill_12_bit_angles() -> None:
    """:func:`fill_angles` of every word a 12-bit A/D sends (``code << 4``,
    the plant's default resolution): 4096 calls once per process (~25 ms)
    instead of a first-tick miss per word during the runs."""
    global _filled_12_bit
    if not _filled_12_bit:
        for code in range(-2048, 2048):
            fill_angles(code << 4, code << 4)
        _filled_12_bit = True


_filled_12_bit = False


def warm_up() -> bool:
    """Compile (or load from the cache) :func:`law_tick`, check the
    sum (:func:`sum_matches`) and fill the 12-bit words' angles; False:
    the law keeps its Python form."""
    try:
        fill_12_bit_angles()
        data = np.ones(SETPOINTS + 2)
        ints = np.zeros(N_INTS, dtype=np.int64)
        ints[MODE] = 1
        law_tick(0, 0, 0, 0, 0, ANGLE_TABLE, data, ints, np.zeros((4, 2)), np.zeros((4, 1), dtype=np.int64), np.ones(1))
        return sum_matches()
    except Exception:  # noqa: BLE001 - numba's errors are many; the Python form gives the same floats
        return False
