"""RALF's sensors and A/D converter (thesis §3.1.1).

Four analog inputs, in TPDO order (protocol.signals.ANALOG_INPUTS):

1. cylinder 1 extension, 2. cylinder 2 extension: Temposonics linear
   transducers, 0-20 in -> -10..+10 V (1 V/in);
3. link 1 tip deflection, 4. link 2 tip deflection: an infrared photodiode at
   the end of each link seen by a camera at its base, amplified and passed
   through an anti-alias filter; +-0.575 in and +-0.555 in -> +-10 V.

Chain per channel: engineering value (in) -> [deflections: anti-alias
filter, whose state the plant integrates every internal step, with the
sensor's broadband noise at its input] -> + noise -> volts
(protocol.signals) -> ``ConverterScale(bits).quantize`` (rounding, clipping
at full scale flagged as saturation, never wrapped).

Noise levels are the thesis's *measured* standard deviations at 12 bits,
which include the A/D's own quantization; the analog part is what remains,
``sigma_a = sqrt(sigma^2 - LSB^2/12)``, so a 12-bit reading at rest has the
thesis's standard deviation and a finer converter removes only the
quantization part:

=================  ===========  ==========  ===================
channel            thesis std   12-bit LSB  analog std (model)
=================  ===========  ==========  ===================
extension 1        5.4e-3 in    4.88e-3 in  5.21e-3 in
extension 2        4.6e-3 in    4.88e-3 in  4.38e-3 in
deflection 1       2.1e-3 in    2.81e-4 in  2.098e-3 in
deflection 2       3.8e-4 in    2.71e-4 in  3.72e-4 in
=================  ===========  ==========  ===================

(The thesis calls the extension noise "binary (quantization) noise"; a
rounding error alone cannot exceed half an LSB, 2.4e-3 in, so most of the
5.4e-3 in must be the transducer's own count jitter: that is what the
analog term models.)

The anti-alias filter is a 2nd-order Butterworth low-pass (default cutoff
40 Hz: -16 dB at the 100 Hz Nyquist frequency of 200 Hz sampling, 1 %
magnitude error and 10 deg of lag at 5 Hz), discretised exactly (zero-order
hold) for the plant's internal step.  The deflection noise enters before the
filter, so it is band-limited like a real amplifier's; its input level is
solved (discrete Lyapunov equation) so that the filtered output has the
analog std above.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.linalg

from protocol.can_map import ConverterScale
from protocol.signals import ANALOG_INPUTS

__all__ = ["AntiAliasFilter", "BlockNormals", "NoiseSources", "SensorReading", "analog_noise_std", "channel_lsb_in", "read_inputs"]

NOISE_BLOCK = 512
_VPU = np.array([ch.volts_per_unit for ch in ANALOG_INPUTS], dtype=np.float64)
_CENTRE = np.array([ch.centre for ch in ANALOG_INPUTS], dtype=np.float64)
"""protocol.signals' linear maps as arrays (``volts = (value - centre) * volts_per_unit``)."""
_MAPS: tuple[tuple[float, float], ...] = tuple((float(v), float(c)) for v, c in zip(_VPU.tolist(), _CENTRE.tolist(), strict=True))
"""The same maps as (volts per unit, centre) floats."""
"""Normal deviates drawn at a time for the per-step deflection noise."""


class SensorReading:
    """One A/D conversion of the four analog inputs (TPDO1 order).

    Built from plain floats and ints (what a tick needs: ``code_list`` and
    ``saturated_list``, the node packs them into TPDO1); the arrays below are
    made from them when first read, and kept."""

    __slots__ = ("time_s", "bits", "code_list", "saturated_list", "_analog", "_lsb", "_arrays")

    def __init__(self, time_s: float, code_list: list[int], saturated_list: list[bool], analog_volts: list[float], lsb_v: float, bits: int) -> None:
        self.time_s = time_s
        self.bits = bits
        self.code_list = code_list
        """Converter codes as ints, ``-2**(bits-1) .. 2**(bits-1)-1``."""
        self.saturated_list = saturated_list
        """Channels clipped at full scale, as bools."""
        self._analog = analog_volts
        self._lsb = lsb_v
        self._arrays: dict[str, npt.NDArray[Any]] = {}

    def _array(self, name: str) -> npt.NDArray[Any]:
        a = self._arrays.get(name)
        if a is None:
            if name == "codes":
                a = np.array(self.code_list, dtype=np.int64)
            elif name == "saturated":
                a = np.array(self.saturated_list, dtype=np.bool_)
            elif name == "volts":
                a = np.array(self._volts(), dtype=np.float64)
            elif name == "analog_volts":
                a = np.array(self._analog, dtype=np.float64)
            else:
                a = np.array([v / vpu + centre for v, (vpu, centre) in zip(self._volts(), _MAPS, strict=True)], dtype=np.float64)
            self._arrays[name] = a
        return a

    def _volts(self) -> list[float]:
        lsb = self._lsb
        return [float(c) * lsb for c in self.code_list]

    @property
    def codes(self) -> npt.NDArray[np.int64]:
        """Converter codes, ``-2**(bits-1) .. 2**(bits-1)-1``."""
        return self._array("codes")

    @property
    def saturated(self) -> npt.NDArray[np.bool_]:
        """Channels clipped at full scale."""
        return self._array("saturated")

    @property
    def volts(self) -> npt.NDArray[np.float64]:
        """The quantized voltages, ``codes * LSB``: what a receiver reconstructs."""
        return self._array("volts")

    @property
    def analog_volts(self) -> npt.NDArray[np.float64]:
        """The voltages at the converter's input (noise included, before rounding)."""
        return self._array("analog_volts")

    @property
    def values_in(self) -> npt.NDArray[np.float64]:
        """``volts`` in engineering units (in): extensions 1-2, deflections 1-2."""
        return self._array("values_in")

    def __repr__(self) -> str:
        return f"SensorReading(time_s={self.time_s!r}, codes={self.code_list!r}, saturated={self.saturated_list!r}, bits={self.bits})"


def analog_noise_std(total_std: float, lsb: float) -> float:
    """The analog part of a noise std measured through a converter of step ``lsb``."""
    q2 = lsb * lsb / 12.0
    return math.sqrt(total_std * total_std - q2) if total_std * total_std > q2 else 0.0


def channel_lsb_in(channel: int, bits: int) -> float:
    """One LSB of ``bits`` resolution on input ``channel`` (0..3), in inches."""
    return ConverterScale(bits).lsb_v / ANALOG_INPUTS[channel].volts_per_unit


@functools.lru_cache(maxsize=8)
def _zoh_butterworth(cutoff_hz: float, step_s: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    """The filter's exact ZOH discretisation (Ad, Bd) and its output variance
    per unit-variance input, worked out once per (cutoff, step): every plant
    built in a process (a campaign's co-simulations) shares them, and the
    matrix exponential's BLAS call, which leaves a BLAS worker thread
    spinning on a core for a while, runs once."""
    wc = 2.0 * math.pi * cutoff_hz
    A = np.array([[0.0, 1.0], [-wc * wc, -math.sqrt(2.0) * wc]])
    B = np.array([[0.0], [wc * wc]])
    # exact ZOH: expm of the augmented matrix [[A, B], [0, 0]] h
    aug = np.zeros((3, 3))
    aug[:2, :2] = A
    aug[:2, 2:] = B
    ed = scipy.linalg.expm(aug * step_s)
    ad, bd = ed[:2, :2].copy(), ed[:2, 2].copy()
    # output (x1) variance per unit-variance white input held over each step
    P = scipy.linalg.solve_discrete_lyapunov(ad, np.outer(bd, bd))
    return ad, bd, float(P[0, 0])


class AntiAliasFilter:
    """Two independent 2nd-order Butterworth low-passes (the two deflection
    channels), discretised exactly for a fixed step with zero-order-hold input."""

    def __init__(self, cutoff_hz: float, step_s: float) -> None:
        if not 0 < cutoff_hz:
            raise ValueError("anti-alias cutoff must be positive")
        self.cutoff_hz = float(cutoff_hz)
        self.step_s = float(step_s)
        ad, bd, self.output_var_per_input_var = _zoh_butterworth(self.cutoff_hz, self.step_s)
        self.Ad = ad.copy()
        self.Bd = bd.copy()
        a = self.Ad
        b = self.Bd
        self._c = (float(a[0, 0]), float(a[0, 1]), float(a[1, 0]), float(a[1, 1]), float(b[0]), float(b[1]))
        self.state = [[0.0, 0.0], [0.0, 0.0]]

    def reset(self, outputs: tuple[float, float]) -> None:
        """Steady state at constant inputs ``outputs`` (DC gain 1)."""
        self.state = [[float(outputs[0]), 0.0], [float(outputs[1]), 0.0]]

    def input_std_for_output_std(self, output_std: float) -> float:
        return output_std / math.sqrt(self.output_var_per_input_var)


class NoiseSources:
    """The seeded generators: one for the per-step deflection noise (part of
    the integrated state), one for the per-sample extension noise, so how
    often the plant is sampled never changes its dynamics."""

    def __init__(self, seed: int) -> None:
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        process, sample = np.random.SeedSequence(int(seed)).spawn(2)
        self.process = np.random.Generator(np.random.PCG64(process))
        self.sample = BlockNormals(np.random.Generator(np.random.PCG64(sample)))
        self._block: npt.NDArray[np.float64] = np.zeros(0)
        self._next = 0

    def step_block(self) -> tuple[npt.NDArray[np.float64], int]:
        """The per-step deviates (a pair per internal step) as one array and the
        index of the next unused pair: a new block of :data:`NOISE_BLOCK` when
        fewer than two are left."""
        if self._next + 2 > len(self._block):
            self._block = self.process.standard_normal(NOISE_BLOCK)
            self._next = 0
        return self._block, self._next

    def step_used(self, nxt: int) -> None:
        """The deviates before ``nxt`` of the current block are used."""
        self._next = nxt


class BlockNormals:
    """Standard normal deviates from ``generator``, drawn :data:`NOISE_BLOCK`
    at a time and handed out in order: the same numbers, in the same order,
    as drawing them from the generator one call at a time (numpy's
    ``standard_normal(n)`` fills its output with n successive draws), without
    a call into numpy and an array per sample. Everything drawn from it goes
    through the block, so its stream stays the generator's."""

    def __init__(self, generator: np.random.Generator) -> None:
        self.generator = generator
        self._block: list[float] = []
        self._next = 0

    def pair(self) -> tuple[float, float]:
        """The next two deviates."""
        i = self._next
        block = self._block
        if i + 2 > len(block):
            return self._take(2)  # type: ignore[return-value]
        self._next = i + 2
        return block[i], block[i + 1]

    def _take(self, n: int) -> list[float]:
        out: list[float] = []
        while len(out) < n:
            if self._next >= len(self._block):
                self._block = self.generator.standard_normal(NOISE_BLOCK).tolist()
                self._next = 0
            k = min(n - len(out), len(self._block) - self._next)
            out += self._block[self._next : self._next + k]
            self._next += k
        return out

    def standard_normal(self, size: int | None = None) -> Any:
        """As :meth:`numpy.random.Generator.standard_normal` (a float, or a 1-D array of ``size``)."""
        if size is None:
            return self._take(1)[0]
        return np.array(self._take(int(size)), dtype=np.float64)


def read_inputs(
    time_s: float,
    extensions_in: tuple[float, float],
    deflections_in: tuple[float, float],
    extension_noise_std_in: tuple[float, float],
    scale: ConverterScale,
    rng: BlockNormals | np.random.Generator | None,
) -> SensorReading:
    """Convert the four engineering values (in) to a :class:`SensorReading`.

    ``deflections_in`` are the anti-alias filter outputs (their noise is
    already in them); the extensions get their per-sample noise here."""
    # Plain floats, element by element: the same IEEE operations as the
    # array form ``(values - centre) * vpu`` etc., without numpy's per-call cost.
    x0, x1 = extensions_in
    if rng is not None:
        n0, n1 = rng.pair() if type(rng) is BlockNormals else rng.standard_normal(2).tolist()
        x0 = float(x0) + extension_noise_std_in[0] * n0
        x1 = float(x1) + extension_noise_std_in[1] * n1
    (v0, c0), (v1, c1), (v2, c2), (v3, c3) = _MAPS
    analog = [(float(x0) - c0) * v0, (float(x1) - c1) * v1, (float(deflections_in[0]) - c2) * v2, (float(deflections_in[1]) - c3) * v3]
    codes, flags = scale.quantize_floats(analog)
    return SensorReading(time_s, codes, flags, analog, scale.lsb_v, scale.bits)


def read_codes(
    extensions_in: tuple[float, float],
    deflections_in: tuple[float, float],
    extension_noise_std_in: tuple[float, float],
    scale: ConverterScale,
    rng: BlockNormals | None,
) -> tuple[list[int], list[bool]]:
    """:func:`read_inputs`' codes and saturation flags only (what a SYNC's
    TPDO1 carries), without the :class:`SensorReading`: the same float
    operations in the same order, :meth:`ConverterScale.quantize_floats`
    written out for the four channels, the same deviates drawn."""
    x0, x1 = extensions_in
    if rng is not None:
        n0, n1 = rng.pair()
        x0 = float(x0) + extension_noise_std_in[0] * n0
        x1 = float(x1) + extension_noise_std_in[1] * n1
    (v0, c0), (v1, c1), (v2, c2), (v3, c3) = _MAPS
    hi = 2.0 * scale.full_scale_v
    lo = -hi
    lsb = scale.lsb_v
    cmin, cmax = scale.code_min, scale.code_max
    a0, a1, a2, a3 = (float(x0) - c0) * v0, (float(x1) - c1) * v1, (float(deflections_in[0]) - c2) * v2, (float(deflections_in[1]) - c3) * v3
    if lo < a0 < hi and lo < a1 < hi and lo < a2 < hi and lo < a3 < hi:  # the common case (NaN fails every comparison)
        # inside the rails the loop below rounds x / lsb as it is: the same codes
        k0, k1, k2, k3 = round(a0 / lsb), round(a1 / lsb), round(a2 / lsb), round(a3 / lsb)
        if cmin <= k0 <= cmax and cmin <= k1 <= cmax and cmin <= k2 <= cmax and cmin <= k3 <= cmax:
            return [k0, k1, k2, k3], [False, False, False, False]
    codes: list[int] = []
    flags: list[bool] = []
    for x in (a0, a1, a2, a3):
        if x != x:  # NaN
            codes.append(0)
            flags.append(True)
            continue
        x = x if x > lo else lo
        code = round((x if x < hi else hi) / lsb)
        if code < cmin:
            codes.append(cmin)
            flags.append(True)
        elif code > cmax:
            codes.append(cmax)
            flags.append(True)
        else:
            codes.append(code)
            flags.append(False)
    return codes, flags
