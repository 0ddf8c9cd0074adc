"""The slave's memory: typed variables at fixed addresses, laid out from a table.

Each :class:`Variable` has an ASAM data type (the A2L's names: ``UBYTE`` ..
``FLOAT64_IEEE``), a unit, physical limits and a linear conversion
``physical = factor * raw + offset`` (the A2L's ``COEFFS_LINEAR``). The
measurements come first from ``base``, then the calibration parameters,
each aligned to its size, so one :class:`struct.Struct` packs the whole
image (:meth:`MemoryLayout.pack`) from the values in table order.

Access rules (what the slave answers, :mod:`service_kit.xcp.slave`):

* a read (UPLOAD, SHORT_UPLOAD, a DAQ entry) must lie inside the image;
  outside it is ``ERR_ACCESS_DENIED``;
* a write (DOWNLOAD, SHORT_DOWNLOAD) that touches a measurement is
  ``ERR_WRITE_PROTECTED``; one that covers a calibration parameter only in
  part, or touches no variable, is ``ERR_ACCESS_DENIED``; a value outside
  the parameter's physical limits (or not finite) is ``ERR_OUT_OF_RANGE``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Final, Literal

from service_kit.xcp.packets import Err

__all__ = ["ASAM_TYPES", "MemoryLayout", "Variable", "Write", "WriteRefused"]

ASAM_TYPES: Final[dict[str, tuple[str, str]]] = {
    "UBYTE": ("B", "U8"),
    "SBYTE": ("b", "I8"),
    "UWORD": ("H", "U16"),
    "SWORD": ("h", "I16"),
    "ULONG": ("I", "U32"),
    "SLONG": ("i", "I32"),
    "A_UINT64": ("Q", "U64"),
    "A_INT64": ("q", "I64"),
    "FLOAT32_IEEE": ("f", "F32"),
    "FLOAT64_IEEE": ("d", "F64"),
}
"""ASAM data type -> (its :mod:`struct` code, little-endian; pyxcp's DAQ type name)."""


@dataclass(frozen=True)
class Variable:
    """One measurement or calibration parameter of the map."""

    name: str
    datatype: str
    """An ASAM data type (:data:`ASAM_TYPES`)."""
    unit: str
    lower: float
    """Physical lower limit."""
    upper: float
    """Physical upper limit."""
    kind: Literal["measurement", "calibration"] = "measurement"
    factor: float = 1.0
    """``physical = factor * raw + offset``."""
    offset: float = 0.0
    description: str = ""
    address: int = 0
    """Assigned by :class:`MemoryLayout`."""

    @property
    def size(self) -> int:
        return struct.calcsize("<" + ASAM_TYPES[self.datatype][0])

    @property
    def code(self) -> str:
        return ASAM_TYPES[self.datatype][0]

    @property
    def is_float(self) -> bool:
        return self.datatype.startswith("FLOAT")

    def to_physical(self, raw: float) -> float:
        return self.factor * raw + self.offset if (self.factor != 1.0 or self.offset != 0.0) else float(raw)


@dataclass(frozen=True)
class Write:
    """One parameter a write sets: its raw value as written and the physical value it stands for."""

    variable: Variable
    raw: float | int
    physical: float


class WriteRefused(Exception):
    """A write the map does not take, with the XCP error code to answer."""

    def __init__(self, code: Err, reason: str) -> None:
        super().__init__(reason)
        self.code = code


def _align(address: int, size: int) -> int:
    return (address + size - 1) // size * size


class MemoryLayout:
    """The variables at their addresses, and the checks of reads and writes."""

    def __init__(self, variables: Sequence[Variable], base: int = 0x1000) -> None:
        names = [v.name for v in variables]
        if len(set(names)) != len(names):
            raise ValueError("variable names must be unique")
        for v in variables:
            if v.datatype not in ASAM_TYPES:
                raise ValueError(f"{v.name}: unknown ASAM data type {v.datatype!r}")
            if not v.lower <= v.upper or v.factor == 0.0:
                raise ValueError(f"{v.name}: limits {v.lower}..{v.upper} or factor {v.factor} invalid")
        ordered = [v for v in variables if v.kind == "measurement"] + [v for v in variables if v.kind == "calibration"]
        placed: list[Variable] = []
        address, fmt = base, "<"
        for v in ordered:
            start = _align(address, v.size)
            if start > address:
                fmt += f"{start - address}x"
            placed.append(replace(v, address=start))
            fmt += v.code
            address = start + v.size
        self.base = base
        self.variables: tuple[Variable, ...] = tuple(placed)
        """Measurements, then calibration parameters, in table order, with their addresses."""
        self.by_name = {v.name: v for v in self.variables}
        self.end = address
        self.size = address - base
        self.image_struct = struct.Struct(fmt)
        """Packs the raw values of :attr:`variables`, in order, into the whole image."""
        self.measurements = tuple(v for v in self.variables if v.kind == "measurement")
        self.calibrations = tuple(v for v in self.variables if v.kind == "calibration")

    def pack(self, raw_values: Sequence[float | int]) -> bytes:
        """The image of ``raw_values`` (one per variable, in :attr:`variables`' order)."""
        return self.image_struct.pack(*raw_values)

    def readable(self, address: int, n: int) -> bool:
        return n >= 0 and self.base <= address and address + n <= self.end

    def check_write(self, address: int, data: bytes) -> list[Write]:
        """The calibration parameters a write of ``data`` at ``address`` sets, with
        their new values; raises :class:`WriteRefused`."""
        end = address + len(data)
        if not data or address < self.base or end > self.end:
            raise WriteRefused(Err.ERR_ACCESS_DENIED, f"write of {len(data)} bytes at 0x{address:X} is outside the map")
        touched = [v for v in self.variables if v.address < end and address < v.address + v.size]
        if not touched:
            raise WriteRefused(Err.ERR_ACCESS_DENIED, f"write at 0x{address:X} touches no variable")
        for v in touched:
            if v.kind != "calibration":
                raise WriteRefused(Err.ERR_WRITE_PROTECTED, f"{v.name} is a measurement")
            if v.address < address or v.address + v.size > end:
                raise WriteRefused(Err.ERR_ACCESS_DENIED, f"write covers {v.name} only in part")
        changes: list[Write] = []
        for v in touched:
            (raw,) = struct.unpack_from("<" + v.code, data, v.address - address)
            physical = v.to_physical(raw)
            if not (math.isfinite(physical) and v.lower <= physical <= v.upper):
                raise WriteRefused(Err.ERR_OUT_OF_RANGE, f"{v.name} = {physical!r} outside {v.lower}..{v.upper} {v.unit}")
            changes.append(Write(v, raw, physical))
        return changes
