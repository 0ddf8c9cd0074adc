"""Object dictionary storage and types (CiA 301 data types, CiA 306 access
types): passive storage with type, access and range checks.

The node attaches write hooks (validation and side effects) and getters
(live values such as diagnostic counters); SDO access errors are raised as
:class:`SdoAbort` carrying the CiA 301 abort code. Which objects exist is
:mod:`plant_emulator.canopen_node.objects`; the EDS is written by
:mod:`plant_emulator.canopen_node.eds`.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Final

Value = int | float | str


class DataType(enum.IntEnum):
    """CiA 301 static data types (the codes used in the EDS)."""

    BOOLEAN = 0x01
    INTEGER8 = 0x02
    INTEGER16 = 0x03
    INTEGER32 = 0x04
    UNSIGNED8 = 0x05
    UNSIGNED16 = 0x06
    UNSIGNED32 = 0x07
    REAL32 = 0x08
    VISIBLE_STRING = 0x09

    @property
    def size(self) -> int | None:
        """Encoded size in bytes (``None`` for strings)."""
        fmt = _FORMATS.get(self)
        return None if fmt is None else fmt.size

    @property
    def is_integer(self) -> bool:
        return self not in (DataType.REAL32, DataType.VISIBLE_STRING)

    @property
    def int_range(self) -> tuple[int, int]:
        return _INT_RANGES[self]


_FORMATS: Final[dict[DataType, struct.Struct]] = {
    DataType.BOOLEAN: struct.Struct("<B"),
    DataType.INTEGER8: struct.Struct("<b"),
    DataType.INTEGER16: struct.Struct("<h"),
    DataType.INTEGER32: struct.Struct("<i"),
    DataType.UNSIGNED8: struct.Struct("<B"),
    DataType.UNSIGNED16: struct.Struct("<H"),
    DataType.UNSIGNED32: struct.Struct("<I"),
    DataType.REAL32: struct.Struct("<f"),
}
_INT_RANGES: Final[dict[DataType, tuple[int, int]]] = {
    DataType.BOOLEAN: (0, 1),
    DataType.INTEGER8: (-(1 << 7), (1 << 7) - 1),
    DataType.INTEGER16: (-(1 << 15), (1 << 15) - 1),
    DataType.INTEGER32: (-(1 << 31), (1 << 31) - 1),
    DataType.UNSIGNED8: (0, 0xFF),
    DataType.UNSIGNED16: (0, 0xFFFF),
    DataType.UNSIGNED32: (0, 0xFFFFFFFF),
}


class Access(str, enum.Enum):  # noqa: UP042 -- str(member) and f"{member}" must stay as they are in the EDS writer
    """CiA 306 access types."""

    RO = "ro"
    WO = "wo"
    RW = "rw"
    RWR = "rwr"
    """read/write, mappable to a TPDO"""
    RWW = "rww"
    """read/write, mappable to an RPDO"""
    CONST = "const"

    @property
    def readable(self) -> bool:
        return self is not Access.WO

    @property
    def writable(self) -> bool:
        return self in (Access.WO, Access.RW, Access.RWR, Access.RWW)


class ObjectKind(enum.IntEnum):
    """CiA 306 ObjectType."""

    VAR = 0x7
    ARRAY = 0x8
    RECORD = 0x9


class SdoAbortCode(enum.IntEnum):
    """CiA 301 SDO abort codes used by the server."""

    TOGGLE_NOT_ALTERNATED = 0x05030000
    SDO_TIMEOUT = 0x05040000
    INVALID_COMMAND = 0x05040001
    OUT_OF_MEMORY = 0x05040005
    UNSUPPORTED_ACCESS = 0x06010000
    READ_WRITE_ONLY = 0x06010001
    WRITE_READ_ONLY = 0x06010002
    OBJECT_DOES_NOT_EXIST = 0x06020000
    LENGTH_MISMATCH = 0x06070010
    LENGTH_TOO_HIGH = 0x06070012
    LENGTH_TOO_LOW = 0x06070013
    SUBINDEX_DOES_NOT_EXIST = 0x06090011
    INVALID_VALUE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    GENERAL_ERROR = 0x08000000
    CANNOT_STORE = 0x08000020
    CANNOT_STORE_LOCAL_CONTROL = 0x08000021
    CANNOT_STORE_DEVICE_STATE = 0x08000022


class SdoAbort(Exception):
    """An SDO access that the server refuses, with its CiA 301 abort code."""

    def __init__(self, code: SdoAbortCode | int, reason: str = "") -> None:
        self.code = int(code)
        self.reason = reason
        try:
            name = SdoAbortCode(code).name
        except ValueError:
            name = "?"
        super().__init__(f"SDO abort 0x{self.code:08X} ({name}){': ' + reason if reason else ''}")


@dataclass(frozen=True)
class Entry:
    """One sub-object (a VAR is an object with the single sub-index 0)."""

    index: int
    sub: int
    name: str
    dtype: DataType
    access: Access
    default: Value
    pdo_mapping: bool = False
    low: int | None = None
    high: int | None = None
    node_relative: bool = False
    """The default is ``$NODEID + default`` (COB-IDs of the pre-defined connection set)."""
    unit: str = ""
    factor: float | None = None
    """engineering value = raw * factor (with ``unit`` and ``description`` in the EDS's units file, not in
    the EDS: CiA 306 has no key for them; see :mod:`plant_emulator.canopen_node.eds`)"""
    description: str = ""
    obj_flags: int = 0
    """CiA 306 ``ObjFlags``: bit 0 "refuse write on download" (a configuration
    manager writing a DCF, in PRE-OPERATIONAL, must leave the entry alone)."""

    def default_for(self, node_id: int) -> Value:
        if self.node_relative:
            assert isinstance(self.default, int)
            return self.default + node_id
        return self.default

    # --- encoding ------------------------------------------------------------

    def encode(self, value: Value) -> bytes:
        if self.dtype is DataType.VISIBLE_STRING:
            return str(value).encode("ascii", errors="replace")
        fmt = _FORMATS[self.dtype]
        if self.dtype is DataType.REAL32:
            return fmt.pack(float(value))
        return fmt.pack(int(value))

    def decode(self, data: bytes) -> Value:
        """Value from SDO download data; length errors raise :class:`SdoAbort`."""
        if self.dtype is DataType.VISIBLE_STRING:
            try:
                return data.decode("ascii")
            except UnicodeDecodeError:
                raise SdoAbort(SdoAbortCode.INVALID_VALUE, "string is not ASCII") from None
        fmt = _FORMATS[self.dtype]
        if len(data) > fmt.size:
            raise SdoAbort(SdoAbortCode.LENGTH_TOO_HIGH, f"{self.dtype.name} takes {fmt.size} bytes, got {len(data)}")
        if len(data) < fmt.size:
            raise SdoAbort(SdoAbortCode.LENGTH_TOO_LOW, f"{self.dtype.name} takes {fmt.size} bytes, got {len(data)}")
        (value,) = fmt.unpack(data)
        if self.dtype is DataType.REAL32:
            return float(value)
        return int(value)

    def check_range(self, value: Value) -> None:
        if self.dtype is DataType.BOOLEAN and value not in (0, 1):
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, "BOOLEAN must be 0 or 1")
        if self.low is not None and isinstance(value, (int, float)) and value < self.low:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_LOW, f"{self.name}: {value} < {self.low}")
        if self.high is not None and isinstance(value, (int, float)) and value > self.high:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH, f"{self.name}: {value} > {self.high}")


@dataclass(frozen=True)
class ObjectDef:
    """An object (index) and its sub-objects."""

    index: int
    name: str
    kind: ObjectKind
    entries: tuple[Entry, ...]

    def __post_init__(self) -> None:
        if self.kind is ObjectKind.VAR:
            assert len(self.entries) == 1 and self.entries[0].sub == 0
        for e in self.entries:
            assert e.index == self.index


WriteHook = Callable[[Value], None]
Getter = Callable[[], Value]


@dataclass
class ObjectDictionary:
    """Values of the table's entries, with SDO-level access checks.

    ``read``/``write`` are the SDO view (access rights, encoded bytes,
    hooks); ``get``/``set`` are the node's own view (no checks, no hooks).
    """

    objects: dict[int, ObjectDef]
    node_id: int
    _entries: dict[tuple[int, int], Entry] = field(default_factory=dict)
    _values: dict[tuple[int, int], Value] = field(default_factory=dict)
    _hooks: dict[tuple[int, int], WriteHook] = field(default_factory=dict)
    _getters: dict[tuple[int, int], Getter] = field(default_factory=dict)
    generation: int = 0
    """Bumped by every change that may alter a stored value or how it is
    served, except ``set`` on the ``quiet`` indices: lets the node cache
    configuration it reads every tick."""
    quiet: frozenset[int] = frozenset()
    """Indices whose ``set`` leaves ``generation`` alone (process data written every tick)."""

    @classmethod
    def from_table(cls, table: Iterable[ObjectDef], node_id: int) -> ObjectDictionary:
        od = cls({o.index: o for o in table}, node_id)
        for obj in od.objects.values():
            for e in obj.entries:
                od._entries[(e.index, e.sub)] = e
        od.restore_defaults()
        return od

    def restore_defaults(self, indices: range | None = None) -> None:
        """Reset stored values (of the indices in ``indices``, default all) to the table."""
        self.generation += 1
        for key, e in self._entries.items():
            if indices is None or e.index in indices:
                self._values[key] = e.default_for(self.node_id)

    def __iter__(self) -> Iterator[Entry]:
        return iter(self._entries.values())

    def __contains__(self, key: tuple[int, int]) -> bool:
        return key in self._entries

    def entry(self, index: int, sub: int) -> Entry:
        e = self._entries.get((index, sub))
        if e is None:
            if index in self.objects:
                raise SdoAbort(SdoAbortCode.SUBINDEX_DOES_NOT_EXIST, f"0x{index:04X} has no sub-index {sub}")
            raise SdoAbort(SdoAbortCode.OBJECT_DOES_NOT_EXIST, f"no object 0x{index:04X}")
        return e

    def on_write(self, index: int, sub: int, hook: WriteHook) -> None:
        """``hook(value)`` runs after the type/range checks of an SDO write and
        before the value is stored; it may raise :class:`SdoAbort` to refuse."""
        assert (index, sub) in self._entries, (index, sub)
        self._hooks[(index, sub)] = hook

    def getter(self, index: int, sub: int, fn: Getter) -> None:
        """Serve a live value instead of the stored one."""
        assert (index, sub) in self._entries, (index, sub)
        self._getters[(index, sub)] = fn
        self.generation += 1

    def get(self, index: int, sub: int = 0) -> Value:
        g = self._getters.get((index, sub))
        if g is not None:
            return g()
        return self._values[(index, sub)]

    def set(self, index: int, sub: int, value: Value) -> None:
        assert (index, sub) in self._entries, (index, sub)
        self._values[(index, sub)] = value
        if index not in self.quiet:
            self.generation += 1

    # --- SDO view --------------------------------------------------------------

    def read(self, index: int, sub: int) -> bytes:
        e = self.entry(index, sub)
        if not e.access.readable:
            raise SdoAbort(SdoAbortCode.READ_WRITE_ONLY)
        value = self.get(index, sub)
        if e.dtype.is_integer:
            lo, hi = e.dtype.int_range
            value = int(value)
            if not lo <= value <= hi:  # counters wrap like the real 32-bit ones
                value = value % (1 << (8 * (e.dtype.size or 4)))
                if e.dtype in (DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32) and value > hi:
                    value -= 1 << (8 * (e.dtype.size or 4))
        return e.encode(value)

    def check_writable(self, index: int, sub: int) -> Entry:
        e = self.entry(index, sub)
        if not e.access.writable:
            raise SdoAbort(SdoAbortCode.WRITE_READ_ONLY, f"0x{index:04X}:{sub} is {e.access.value}")
        return e

    def write(self, index: int, sub: int, data: bytes) -> None:
        e = self.check_writable(index, sub)
        value = e.decode(bytes(data))
        if isinstance(value, float) and not math.isfinite(value):
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, "not a finite number")
        e.check_range(value)
        hook = self._hooks.get((index, sub))
        if hook is not None:
            hook(value)
        self._values[(index, sub)] = value
        self.generation += 1
