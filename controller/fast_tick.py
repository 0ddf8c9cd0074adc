"""One control tick of :class:`controller.loop.ControlLaw` as a single compiled call.

Engineering values [A.7, A.8], set-point, OATF (§3.3, [3-34]), PI (§4,
:func:`controller.pi.pi_joint`) and the 12-bit D/A, on preallocated state
arrays: the OATF's delay line and head and the PI's integrator and last
terms are the arrays :class:`~controller.oatf.OatfFilter` and
:class:`~controller.pi.PIController` hold, read and written in place.

The arithmetic is fixed so that a run's record has the same bits on every
host:

* the joint angle of a word (libm's ``pow`` and numpy's ``arccos``) is not
  recomputed in the kernel: it is looked up in a table filled, one word at
  a time the first time the word is seen, by
  :func:`controller.engineering.measure_values` (65536 words per channel
  at most);
* the OATF's weighted sum [3-34] is ``w0 x0 + w1 x1 + ...`` added left to
  right, each product and sum rounded (:func:`oatf_dot`), as
  :meth:`controller.oatf.OatfFilter.step` and ``process`` add it; no BLAS
  kernel takes part;
* numba runs without fastmath (no reassociation, no contraction into FMA);
  ``min``/``max`` are the comparisons Python's make (the first argument
  wins a tie) and rounding is ``np.rint`` (half to even).

The tests check the kernel against references built from scipy
(``tests/controller/test_law_reference.py``). :func:`warm_up` compiles (or
loads from numba's on-disk cache) the kernel.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from controller.engineering import _CHANNELS, measure_values
from controller.pi import _pmax, _pmin, cached_njit, pi_joint
from protocol.can_map import DAC12, WORD16_VOLTS_PER_LSB
from protocol.geometry import DELTA_RAD

__all__ = ["ANGLE_TABLE", "fill_angles", "law_consts", "law_tick", "oatf_dot", "warm_up"]

ANGLE_TABLE: np.ndarray = np.full((2, 65536), np.nan)
"""theta1, theta2 (rad) per INT16 word of channels 1 and 2 (index ``word + 32768``); NaN: not computed yet."""

# Status codes of law_tick (0: done).
MISSING_ANGLE = -1
"""A word's angle is not in :data:`ANGLE_TABLE` yet: nothing was changed; fill it and call again."""
NON_FINITE = -2
"""An angle error is not finite: the OATF stepped, the PI did not; the caller raises."""

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
STIMULUS = 7
"""ints[STIMULUS]: 0 (no stimulus), or :data:`STIMULUS_SLOTS`: the last slots of ``data`` hold this tick's stimulus."""
STIMULUS_SLOTS = 4
"""data[-4:] with a stimulus: the set-point offsets of joints 1 and 2 (rad), then the
valve overrides of valves 1 and 2 (V; NaN: no override, the command goes to the D/A)."""
N_INTS = 8
"""The length of ``ints``."""


@cached_njit
def oatf_dot(weights: np.ndarray, buf: np.ndarray, rows: np.ndarray, j: int) -> float:
    """Channel ``j`` of the OATF's weighted taps [3-34], ``w0 x0 + w1 x1 + ...`` left to
    right, each product and sum rounded."""
    t = weights[0] * buf[rows[0], j]
    for i in range(1, weights.shape[0]):
        t = t + weights[i] * buf[rows[i], j]
    return t


@cached_njit
def _oatf_step(buf: np.ndarray, tap_rows: np.ndarray, weights: np.ndarray, ints: np.ndarray, x0: float, x1: float) -> tuple[float, float]:
    """:meth:`OatfFilter.step` of two channels: push, then the weighted taps (the head in ``ints[HEAD]``)."""
    head = (ints[HEAD] + 1) % buf.shape[0]
    ints[HEAD] = head
    buf[head, 0] = x0
    buf[head, 1] = x1
    rows = tap_rows[head]
    return oatf_dot(weights, buf, rows, 0), oatf_dot(weights, buf, rows, 1)


@cached_njit
def _measure(w0: int, w1: int, w2: int, w3: int, t1: float, t2: float, consts: np.ndarray, row: np.ndarray) -> None:
    """The engineering values [A.7, A.8] of the four words into ``row[7:21]``:
    the joint angles ``t1, t2`` (from :data:`ANGLE_TABLE`), the inputs in
    inches and the words' volts, as :func:`measure_values` computes them."""
    c = _ENG
    lsb = consts[c]
    v0, v1, v2, v3 = w0 * lsb, w1 * lsb, w2 * lsb, w3 * lsb
    row[7] = t1
    row[8] = t2
    row[9] = v0 / consts[c + 1] + consts[c + 2]
    row[10] = v1 / consts[c + 3] + consts[c + 4]
    row[11] = v2 / consts[c + 5] + consts[c + 6]
    row[12] = v3 / consts[c + 7] + consts[c + 8]
    row[13] = w0
    row[14] = w1
    row[15] = w2
    row[16] = w3
    row[17] = v0
    row[18] = v1
    row[19] = v2
    row[20] = v3


@cached_njit
def _dac(x: float, consts: np.ndarray, codes: np.ndarray, j: int) -> None:
    """The 12-bit D/A of channel ``j`` (:data:`protocol.can_map.DAC12`): the
    code (``np.rint``, half to even as Python's ``round``) and whether it
    saturated, into ``codes[j]`` and ``codes[2 + j]``; NaN gives 0, saturated."""
    c = _DAC
    dlsb, bound, cmin, cmax = consts[c + 1], consts[c + 2], consts[c + 4], consts[c + 5]
    if x != x:
        codes[j] = 0
        codes[2 + j] = 1
        return
    code = np.rint(_pmin(bound, _pmax(-bound, x)) / dlsb)
    codes[2 + j] = 1 if (code < cmin or code > cmax) else 0
    codes[j] = int(_pmin(cmax, _pmax(cmin, code)))


@cached_njit
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
    """One control tick. ``data`` (float64): the constants (:func:`law_consts`),
    the PI's state (:attr:`controller.pi.PIController.state`), the row (the
    values of :data:`controller.loop.ROW_NAMES`, the words as floats), the
    lap's set-points, then the dither table (``ints[DITHER]`` ticks of two
    valve values, :mod:`controller.excitation`), then, with a stimulus
    (``ints[STIMULUS]``), this tick's :data:`STIMULUS_SLOTS` (:mod:`protocol.stimulus_eval`). ``ints`` (int64,
    :data:`N_INTS`): the D/A codes and their saturation flags
    ``(c0, c1, s0, s1)``, the OATF mode (0 none, 1 outer, 2 inner), the head
    of its delay line ``obuf`` (moved in place), the dither's length. Few
    arguments: each array costs the dispatcher ~0.1 µs. Returns 0, or a
    negative status (``MISSING_ANGLE``; ``NON_FINITE``: ``row[0:2]`` then
    holds the errors)."""
    consts = data[:PI_STATE]
    pi_state = data[PI_STATE:ROW]
    row = data[ROW:SETPOINTS]
    mode = ints[MODE]
    t1 = angles[0, w0 + 32768]
    t2 = angles[1, w1 + 32768]
    if t1 != t1 or t2 != t2:
        return MISSING_ANGLE
    phi1 = t1 - consts[_ENG + 9]
    phi2 = t2 + consts[_ENG + 9]
    n_dither = ints[DITHER]
    n_stim = ints[STIMULUS]
    ks = data.shape[0] - n_stim
    lap = (ks - SETPOINTS - 2 * n_dither) // 2
    k = SETPOINTS + 2 * (tick % lap)
    ref1 = data[k]
    ref2 = data[k + 1]
    if n_stim > 0:  # set-point offsets
        ref1 = ref1 + data[ks]
        ref2 = ref2 + data[ks + 1]
    sh1, sh2 = ref1, ref2
    if mode == 1:  # outer OATF, on the set-points [3-34]
        sh1, sh2 = _oatf_step(obuf, orows, oweights, ints, ref1, ref2)
    err0 = sh1 - phi1
    err1 = sh2 - phi2
    if not (math.isfinite(err0) and math.isfinite(err1)):
        row[0] = err0
        row[1] = err1
        return NON_FINITE
    u0 = pi_joint(consts, pi_state, 2, 0, err0)
    u1 = pi_joint(consts, pi_state, 2, 1, err1)
    if mode == 2:  # inner OATF, on the commands, then the D/A's full scale
        fs = consts[_DAC + 3]
        f0, f1 = _oatf_step(obuf, orows, oweights, ints, u0, u1)
        u0 = _pmin(_pmax(f0, -fs), fs)
        u1 = _pmin(_pmax(f1, -fs), fs)
    x0, x1 = u0, u1
    if n_dither > 0:
        kd = SETPOINTS + 2 * lap + 2 * (tick % n_dither)
        x0 = u0 + data[kd]
        x1 = u1 + data[kd + 1]
    if n_stim > 0:  # valve overrides replace the command (NaN: none)
        o0 = data[ks + 2]
        o1 = data[ks + 3]
        if o0 == o0:
            x0 = o0
        if o1 == o1:
            x1 = o1
    _dac(x0, consts, ints, 0)
    _dac(x1, consts, ints, 1)
    _measure(w0, w1, w2, w3, t1, t2, consts, row)
    row[0] = tick * consts[_DAC]
    row[1] = ref1
    row[2] = ref2
    row[3] = sh1
    row[4] = sh2
    row[5] = phi1
    row[6] = phi2
    row[21] = ints[0] * consts[_DAC + 1]
    row[22] = ints[1] * consts[_DAC + 1]
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
            *pi.consts.tolist(),
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


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) :func:`law_tick` and
    fill the 12-bit words' angles."""
    fill_12_bit_angles()
    data = np.ones(SETPOINTS + 2)
    ints = np.zeros(N_INTS, dtype=np.int64)
    ints[MODE] = 1
    law_tick(0, 0, 0, 0, 0, ANGLE_TABLE, data, ints, np.zeros((4, 2)), np.zeros((4, 1), dtype=np.int64), np.ones(1))
