"""The CAN map of the rig: CANopen (CiA 301) framing with the CiA 401 analog
I/O profile, and the volts <-> counts scaling of the ±10 V converters.

Frames (node id ``n``, default :data:`DEFAULT_NODE_ID`):

=========  ============  =====  =============================================
frame      COB-ID        DLC    payload
=========  ============  =====  =============================================
NMT        0x000         2      command, node id (0 = all)
SYNC       0x080         0/1    counter 1..240 (CiA 301 SYNC counter), or none
EMCY       0x080 + n     8      error code (u16), error register, 5 vendor bytes
TPDO1      0x180 + n     8      analog inputs 1-4, 0x6401 sub 1-4 (INT16 LE)
TPDO2      0x280 + n     8      analog inputs 1-2, 0x6402 sub 1-2 (INT32 LE)
TPDO3      0x380 + n     8      analog inputs 3-4, 0x6402 sub 3-4 (INT32 LE)
RPDO1      0x200 + n     4      analog outputs 1-2, 0x6411 sub 1-2 (INT16 LE)
SDO tx     0x580 + n     8      server -> client
SDO rx     0x600 + n     8      client -> server
heartbeat  0x700 + n     1      NMT state
=========  ============  =====  =============================================

CiA 401 carries converter values *left-justified*: a 12-bit value ``c`` in
``[-2048, 2047]`` travels as the INT16 ``c << 4``, so every consumer can read
volts as ``raw16 * 10 V / 32768`` whatever the converter's resolution.
Resolutions above 16 bits (the thesis's 20-bit future work) travel in the
32-bit objects 0x6402 on TPDO2/TPDO3, left-justified in INT32.

Analog inputs (channel -> signal), see docs for the volts per unit:

1. cylinder 1 extension, 2. cylinder 2 extension,
3. link 1 tip deflection, 4. link 2 tip deflection.

Analog outputs: 1. valve 1 voltage, 2. valve 2 voltage.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.errors import FrameError

DEFAULT_NODE_ID: Final[int] = 1

NMT_COB_ID: Final[int] = 0x000
SYNC_COB_ID: Final[int] = 0x080
EMCY_BASE: Final[int] = 0x080
TPDO1_BASE: Final[int] = 0x180
RPDO1_BASE: Final[int] = 0x200
TPDO2_BASE: Final[int] = 0x280
TPDO3_BASE: Final[int] = 0x380
SDO_TX_BASE: Final[int] = 0x580
SDO_RX_BASE: Final[int] = 0x600
HEARTBEAT_BASE: Final[int] = 0x700

SYNC_COUNTER_OVERFLOW: Final[int] = 240
"""CiA 301 object 0x1019: the SYNC counter runs 1..240 and wraps to 1."""

N_ANALOG_INPUTS: Final[int] = 4
N_ANALOG_OUTPUTS: Final[int] = 2
FULL_SCALE_V: Final[float] = 10.0
"""Both converters span ±10 V."""

OD_ANALOG_INPUT_16: Final[int] = 0x6401
OD_ANALOG_INPUT_32: Final[int] = 0x6402
OD_ANALOG_OUTPUT_16: Final[int] = 0x6411

OD_RPDO1_COMM: Final[int] = 0x1400
"""RPDO1 communication parameter."""
OD_RPDO_EVENT_TIMER_SUB: Final[int] = 5
"""0x1400 sub 5, UNSIGNED16 ms: RPDO1 deadline monitoring (CiA 301 RPDO event timer), 0 = off."""

# Manufacturer-specific objects of the plant node (protocol/ralf_io.eds), which
# the controller configures by SDO before it starts the node.
OD_SAMPLE_PERIOD: Final[int] = 0x2000
"""UNSIGNED32, µs: the nominal SYNC period; the plant steps by it and its watchdog counts in it."""
OD_ADC_RESOLUTION: Final[int] = 0x2001
"""UNSIGNED8, bits: one of :data:`ADC_RESOLUTIONS`."""
OD_VALVE_LIMIT: Final[int] = 0x2002
"""REAL32, V: analog outputs are clipped to ± this."""
OD_WATCHDOG_PERIODS: Final[int] = 0x2003
"""UNSIGNED16: SYNC watchdog in sample periods; 0 disables it (refused while OPERATIONAL)."""
OD_DIAGNOSTICS: Final[int] = 0x2010
"""ARRAY of UNSIGNED32: the node's diagnostic counters."""

ADC_RESOLUTIONS: Final[tuple[int, ...]] = (12, 16, 20)
"""A/D resolutions the plant node offers on 0x2001 (above 16 bits TPDO2/3 carry 0x6402)."""


class NmtCommand(enum.IntEnum):
    """CiA 301 NMT node-control commands."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class NmtState(enum.IntEnum):
    """States as the heartbeat reports them."""

    BOOT_UP = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


class EmcyCode(enum.IntEnum):
    """Emergency error codes used by the plant node (CiA 301 / 401)."""

    NO_ERROR = 0x0000
    OUTPUT_CLIPPED = 0x2310
    """An analog output command outside ±full scale was clipped (current/voltage range)."""
    INPUT_SATURATED = 0x5010
    """An analog input reached full scale (saturation is flagged, never wrapped)."""
    PDO_LENGTH = 0x8210
    """A PDO with the wrong length was received and ignored."""
    CAN_ERROR_PASSIVE = 0x8120
    """The node's CAN controller is error passive (CiA 301 "CAN in error passive mode"): raised on entry,
    cleared (error reset) when it is error active again."""
    SYNC_TIMEOUT = 0x8130
    """No SYNC for the watchdog time: valves held at zero. CiA 301's "life guard error or heartbeat
    error": the node's monitoring of its master (here by the SYNC it consumes) timed out."""
    CAN_BUS_OFF_RECOVERED = 0x8140
    """The node's CAN controller has recovered from bus off (CiA 301 "recovered from bus off"),
    followed by the error reset once it is error active."""
    CAN_ID_COLLISION = 0x8150
    """A frame on one of the node's own COB-IDs (heartbeat, EMCY, TPDO, SDO reply) that it did not
    send: another node transmits with its identifiers (CiA 301 "CAN-ID collision"). Vendor bytes:
    that frame's COB-ID (u16), its DLC and its first two data bytes."""
    RPDO_TIMEOUT = 0x8250
    """SYNC present but no RPDO1 within its event timer (0x1400 sub 5): valves held at zero
    (CiA 301 "RPDO timeout")."""
    JOINT_LIMIT = 0xFF01
    """A joint reached a hard stop (manufacturer specific)."""
    SYNC_CONFLICT = 0xFF02
    """SYNC counters that one producer cannot give (a repeat, a jump back, counter and no counter
    mixed): a second SYNC producer on the bus (manufacturer specific)."""
    RPDO_CONFLICT = 0xFF03
    """More RPDO1 frames in one SYNC period than SYNCs in it: a second RPDO producer (manufacturer specific)."""
    PLANT_MODEL_FAULT = 0x6200
    """The plant model's step failed (an FMU's doStep returned Discard, Error or Fatal, or non-finite
    outputs): the last outputs are held (CiA 301 "user software"; vendor byte 0: the cause)."""


MODEL_FAULT_CAUSES: Final[dict[int, str]] = {1: "error or fatal", 2: "discard", 3: "non-finite outputs", 4: "terminated"}
"""EMCY PLANT_MODEL_FAULT's vendor byte 0: why the plant model's step failed."""
MODEL_DEAD_CAUSES: Final[frozenset[int]] = frozenset({1, 4})
"""Causes after which the model makes no further step (FMI allows no doStep after Error, Fatal or
Terminate): the plant's samples are frozen for the rest of the run, the plant model is dead."""


def cob_ids(node_id: int = DEFAULT_NODE_ID) -> dict[str, int]:
    """All COB-IDs of a node, by frame name."""
    if not 1 <= node_id <= 127:
        raise ValueError(f"CANopen node id must be 1..127, got {node_id}")
    return {
        "nmt": NMT_COB_ID,
        "sync": SYNC_COB_ID,
        "emcy": EMCY_BASE + node_id,
        "tpdo1": TPDO1_BASE + node_id,
        "tpdo2": TPDO2_BASE + node_id,
        "tpdo3": TPDO3_BASE + node_id,
        "rpdo1": RPDO1_BASE + node_id,
        "sdo_tx": SDO_TX_BASE + node_id,
        "sdo_rx": SDO_RX_BASE + node_id,
        "heartbeat": HEARTBEAT_BASE + node_id,
    }


# --- converter scaling ---------------------------------------------------------


@dataclass(frozen=True)
class Quantized:
    """Converter codes and which channels hit full scale."""

    counts: npt.NDArray[np.int64]
    saturated: npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ConverterScale:
    """A bipolar converter of ``bits`` resolution over ±``full_scale_v``.

    Codes run from ``-2**(bits-1)`` to ``2**(bits-1) - 1``; one LSB is
    ``2 * full_scale_v / 2**bits`` (4.883 mV at 12 bits and ±10 V).
    """

    bits: int = 12
    full_scale_v: float = FULL_SCALE_V

    def __post_init__(self) -> None:
        if not 8 <= self.bits <= 32:
            raise ValueError(f"converter resolution must be 8..32 bits, got {self.bits}")
        if self.full_scale_v <= 0:
            raise ValueError("full scale must be positive")

    # Computed once per scale (read on every conversion of a tick).
    @cached_property
    def lsb_v(self) -> float:
        return 2.0 * self.full_scale_v / (1 << self.bits)

    @cached_property
    def code_min(self) -> int:
        return -(1 << (self.bits - 1))

    @cached_property
    def code_max(self) -> int:
        return (1 << (self.bits - 1)) - 1

    def quantize(self, volts: npt.ArrayLike) -> Quantized:
        """Round to the nearest code (error at most half an LSB inside the
        range); values beyond full scale are clipped to the end codes and
        flagged, never wrapped. NaN is treated as out of range (flagged, 0)."""
        if type(volts) is np.ndarray and volts.dtype == np.float64 and volts.ndim == 1 and volts.size <= 8:
            return self._quantize_small(volts.tolist())
        v = np.asarray(volts, dtype=np.float64)
        nan = np.isnan(v)
        # Bounding first keeps infinities (-> end codes) and huge values from overflowing.
        bounded = np.clip(np.where(nan, 0.0, v), -2.0 * self.full_scale_v, 2.0 * self.full_scale_v)
        codes = np.rint(bounded / self.lsb_v)
        saturated = (codes < self.code_min) | (codes > self.code_max) | nan
        codes = np.clip(codes, self.code_min, self.code_max).astype(np.int64)
        return Quantized(counts=codes, saturated=np.asarray(saturated))

    def _quantize_small(self, values: list[float]) -> Quantized:
        """:meth:`quantize` on a few floats (the 2-/4-vectors of a tick)."""
        counts, flags = self.quantize_floats(values)
        return Quantized(counts=np.array(counts, dtype=np.int64), saturated=np.array(flags, dtype=np.bool_))

    def quantize_floats(self, values: Iterable[float]) -> tuple[list[int], list[bool]]:
        """:meth:`quantize` on plain floats, giving plain ints and bools: the
        same operations per element without numpy's per-call overhead (the
        2-/4-vectors of a tick). ``round`` rounds half to even like
        ``np.rint``; the conditional expressions clip like ``np.clip`` for
        every non-NaN value (NaN is handled first): each is what
        ``min(hi, max(lo, x))`` returns, without the two calls."""
        hi = 2.0 * self.full_scale_v
        lo = -hi
        lsb = self.lsb_v
        cmin, cmax = self.code_min, self.code_max
        counts: list[int] = []
        flags: list[bool] = []
        for x in values:
            if x != x:  # NaN
                counts.append(0)
                flags.append(True)
                continue
            x = x if x > lo else lo
            code = round((x if x < hi else hi) / lsb)
            if code < cmin:
                flags.append(True)
                counts.append(cmin)
            elif code > cmax:
                flags.append(True)
                counts.append(cmax)
            else:
                flags.append(False)
                counts.append(code)
        return counts, flags

    def to_volts(self, counts: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return np.asarray(counts, dtype=np.float64) * self.lsb_v

    def shift(self, word_bits: int) -> int:
        if self.bits > word_bits:
            raise ValueError(f"a {self.bits}-bit value does not fit a {word_bits}-bit word")
        return word_bits - self.bits

    def left_justify(self, counts: npt.ArrayLike, word_bits: int = 16) -> npt.NDArray[np.int64]:
        """CiA 401 left-justified word of a code (``code << (word_bits - bits)``)."""
        return np.asarray(counts, dtype=np.int64) << self.shift(word_bits)

    def from_left_justified(self, words: npt.ArrayLike, word_bits: int = 16) -> npt.NDArray[np.int64]:
        """Code from a left-justified word; the padding bits are discarded."""
        return np.asarray(words, dtype=np.int64) >> self.shift(word_bits)


ADC12: Final[ConverterScale] = ConverterScale(12)
DAC12: Final[ConverterScale] = ConverterScale(12)
WORD16_VOLTS_PER_LSB: Final[float] = FULL_SCALE_V / 32768.0
"""Volts per unit of any left-justified INT16 analog value (used in the DBC)."""
WORD32_VOLTS_PER_LSB: Final[float] = FULL_SCALE_V / 2147483648.0


# --- frame packing -------------------------------------------------------------

_INT16X4 = struct.Struct("<4h")
_INT16X2 = struct.Struct("<2h")
_INT32X2 = struct.Struct("<2i")
_EMCY = struct.Struct("<HB5s")


def _pack(fmt: struct.Struct, what: str, *values: int | bytes) -> bytes:
    try:
        return fmt.pack(*values)
    except struct.error as exc:
        raise ValueError(f"{what}: value out of range for the frame: {exc}") from None


def _check_len(data: bytes | bytearray, expected: int, what: str) -> None:
    if len(data) != expected:
        raise FrameError(f"{what}: expected {expected} data bytes, got {len(data)}")


def encode_sync(counter: int) -> bytes:
    """SYNC payload: the counter byte 1..240."""
    if not 1 <= counter <= SYNC_COUNTER_OVERFLOW:
        raise ValueError(f"SYNC counter must be 1..{SYNC_COUNTER_OVERFLOW}, got {counter}")
    return bytes([counter])


def decode_sync(data: bytes | bytearray) -> int:
    _check_len(data, 1, "SYNC")
    counter = data[0]
    if not 1 <= counter <= SYNC_COUNTER_OVERFLOW:
        raise FrameError(f"SYNC counter {counter} outside 1..{SYNC_COUNTER_OVERFLOW}")
    return counter


def next_sync_counter(counter: int) -> int:
    """The counter after ``counter`` (wraps 240 -> 1)."""
    return counter % SYNC_COUNTER_OVERFLOW + 1


def sync_gap(previous: int, current: int) -> int:
    """How many SYNCs were missed between two received counters (0 = none;
    a repeated counter is a duplicate, not 239 missed SYNCs)."""
    if current == previous:
        return 0
    return (current - previous - 1) % SYNC_COUNTER_OVERFLOW


def encode_analog_inputs_16(words: npt.ArrayLike) -> bytes:
    """TPDO1 payload from four left-justified INT16 words."""
    if type(words) is list and len(words) == N_ANALOG_INPUTS:
        try:
            return _INT16X4.pack(*words)  # plain ints (the node's path): no array round trip
        except struct.error:
            pass  # not four INT16 integers: the checked path below converts or says why
    w = np.asarray(words, dtype=np.int64)
    if w.shape != (N_ANALOG_INPUTS,):
        raise ValueError(f"TPDO1 carries {N_ANALOG_INPUTS} inputs, got shape {w.shape}")
    return _pack(_INT16X4, "TPDO1", *(int(x) for x in w))


def decode_analog_inputs_16(data: bytes | bytearray) -> npt.NDArray[np.int64]:
    _check_len(data, 8, "TPDO1")
    return np.array(_INT16X4.unpack(bytes(data)), dtype=np.int64)


def encode_analog_inputs_32(words: npt.ArrayLike) -> tuple[bytes, bytes]:
    """TPDO2 and TPDO3 payloads from four left-justified INT32 words."""
    w = np.asarray(words, dtype=np.int64)
    if w.shape != (N_ANALOG_INPUTS,):
        raise ValueError(f"TPDO2/3 carry {N_ANALOG_INPUTS} inputs, got shape {w.shape}")
    return _pack(_INT32X2, "TPDO2", int(w[0]), int(w[1])), _pack(_INT32X2, "TPDO3", int(w[2]), int(w[3]))


def decode_analog_inputs_32(data: bytes | bytearray) -> npt.NDArray[np.int64]:
    _check_len(data, 8, "TPDO2/3")
    return np.array(_INT32X2.unpack(bytes(data)), dtype=np.int64)


def encode_analog_outputs(words: npt.ArrayLike) -> bytes:
    """RPDO1 payload from two left-justified INT16 words."""
    w = np.asarray(words, dtype=np.int64)
    if w.shape != (N_ANALOG_OUTPUTS,):
        raise ValueError(f"RPDO1 carries {N_ANALOG_OUTPUTS} outputs, got shape {w.shape}")
    return _pack(_INT16X2, "RPDO1", *(int(x) for x in w))


def decode_analog_outputs(data: bytes | bytearray) -> npt.NDArray[np.int64]:
    _check_len(data, 4, "RPDO1")
    return np.array(_INT16X2.unpack(bytes(data)), dtype=np.int64)


def volts_to_output_frame(volts: npt.ArrayLike, scale: ConverterScale = DAC12) -> tuple[bytes, npt.NDArray[np.bool_]]:
    """Quantize two valve voltages and pack RPDO1; returns (payload, clipped flags)."""
    q = scale.quantize(volts)
    return encode_analog_outputs(scale.left_justify(q.counts)), q.saturated


def output_frame_to_volts(data: bytes | bytearray, scale: ConverterScale = DAC12) -> npt.NDArray[np.float64]:
    return scale.to_volts(scale.from_left_justified(decode_analog_outputs(data)))


def encode_nmt(command: NmtCommand, node_id: int) -> bytes:
    if not 0 <= node_id <= 127:
        raise ValueError(f"NMT node id must be 0..127, got {node_id}")
    return bytes([int(command), node_id])


def decode_nmt(data: bytes | bytearray) -> tuple[NmtCommand, int]:
    _check_len(data, 2, "NMT")
    try:
        command = NmtCommand(data[0])
    except ValueError:
        raise FrameError(f"unknown NMT command 0x{data[0]:02x}") from None
    if data[1] > 127:
        raise FrameError(f"NMT node id {data[1]} outside 0..127")
    return command, data[1]


def encode_heartbeat(state: NmtState) -> bytes:
    return bytes([int(state)])


def encode_collision_evidence(cob_id: int, data: bytes | bytearray) -> bytes:
    """The five vendor bytes of EMCY CAN_ID_COLLISION: the foreign frame's COB-ID (u16 LE), DLC, first two data bytes."""
    return struct.pack("<HB", cob_id & 0x7FF, len(data) & 0xFF) + bytes(data[:2]).ljust(2, b"\x00")


def decode_collision_evidence(vendor: bytes | bytearray) -> tuple[int, int, bytes]:
    """(COB-ID, DLC, first data bytes, at most two and at most DLC) from EMCY CAN_ID_COLLISION's vendor bytes."""
    cob_id, dlc = struct.unpack_from("<HB", bytes(vendor).ljust(5, b"\x00"))
    return cob_id, dlc, bytes(vendor[3 : 3 + min(dlc, 2)])


def decode_heartbeat(data: bytes | bytearray) -> NmtState:
    _check_len(data, 1, "heartbeat")
    try:
        return NmtState(data[0] & 0x7F)
    except ValueError:
        raise FrameError(f"unknown heartbeat state 0x{data[0]:02x}") from None


@dataclass(frozen=True)
class Emergency:
    """A decoded EMCY frame."""

    code: int
    register: int
    vendor: bytes

    @property
    def name(self) -> str:
        try:
            return EmcyCode(self.code).name
        except ValueError:
            return f"0x{self.code:04x}"


def encode_emcy(code: EmcyCode | int, register: int = 0x01, vendor: bytes = b"") -> bytes:
    """EMCY payload: code, error register (bit 0 = generic error), 5 vendor bytes."""
    if len(vendor) > 5:
        raise ValueError("EMCY carries at most 5 vendor bytes")
    return _pack(_EMCY, "EMCY", int(code), register & 0xFF, vendor.ljust(5, b"\x00"))


def decode_emcy(data: bytes | bytearray) -> Emergency:
    _check_len(data, 8, "EMCY")
    code, register, vendor = _EMCY.unpack(bytes(data))
    return Emergency(code=code, register=register, vendor=vendor)


# --- per-tick forms on plain numbers (the controller's hot path) ------------------


class ValueQuantizer:
    """:meth:`ConverterScale.quantize` of a few plain floats, its constants
    read once: the same rule (round half to even, clip to the end codes and
    flag; NaN flagged, code 0) returning ``(codes, saturated)`` as lists of
    plain ints and bools, without building arrays."""

    __slots__ = ("_bound", "_cmax", "_cmin", "_lsb")

    def __init__(self, scale: ConverterScale) -> None:
        self._bound = 2.0 * scale.full_scale_v
        self._lsb = scale.lsb_v
        self._cmin = scale.code_min
        self._cmax = scale.code_max

    def __call__(self, values: list[float]) -> tuple[list[int], list[bool]]:
        bound, lsb, cmin, cmax = self._bound, self._lsb, self._cmin, self._cmax
        codes: list[int] = []
        flags: list[bool] = []
        for x in values:
            if x != x:  # NaN
                codes.append(0)
                flags.append(True)
                continue
            code = round(min(bound, max(-bound, x)) / lsb)
            flags.append(code < cmin or code > cmax)
            codes.append(min(cmax, max(cmin, code)))
        return codes, flags


DAC12_VALUES: Final[ValueQuantizer] = ValueQuantizer(DAC12)
""":data:`DAC12`'s quantization of plain floats (the controller's per-tick D/A)."""


_TPDO1_WORDS: Final = struct.Struct("<4h")


def decode_analog_inputs_16_values(data: bytes | bytearray) -> tuple[int, int, int, int]:
    """:func:`decode_analog_inputs_16` as a tuple of plain ints (no array)."""
    _check_len(data, 8, "TPDO1")
    w0, w1, w2, w3 = _TPDO1_WORDS.unpack(data)
    return w0, w1, w2, w3


_RPDO1_WORDS: Final = struct.Struct("<2h")


def encode_analog_outputs_values(w0: int, w1: int) -> bytes:
    """:func:`encode_analog_outputs` of two plain ints (left-justified INT16 words)."""
    return _pack(_RPDO1_WORDS, "RPDO1", w0, w1)
