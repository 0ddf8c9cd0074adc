"""The plant I/O node's object dictionary: one table, two uses.

:func:`object_table` is the single description of every object the node
serves (CiA 301 communication objects, the manufacturer-specific settings
and the CiA 401 analog I/O). The running node builds its
:class:`ObjectDictionary` from it, and :func:`render_eds` writes the CiA 306
EDS shipped as ``protocol/ralf_io.eds`` from the same table, so the file a
master loads always describes what the node answers. Regenerate the EDS after
changing the table::

    /work/venv/bin/python -m plant_emulator.object_dictionary > protocol/ralf_io.eds

(a test compares the shipped file with :func:`render_eds`).

The dictionary here is passive storage with type, access and range checks;
the node attaches write hooks (validation and side effects) and getters
(live values such as diagnostic counters). SDO access errors are raised as
:class:`SdoAbort` carrying the CiA 301 abort code.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, Union

from protocol.can_map import (
    EMCY_BASE,
    OD_ANALOG_INPUT_16,
    OD_ANALOG_INPUT_32,
    OD_ANALOG_OUTPUT_16,
    RPDO1_BASE,
    SYNC_COB_ID,
    TPDO1_BASE,
    TPDO2_BASE,
    TPDO3_BASE,
    WORD16_VOLTS_PER_LSB,
    WORD32_VOLTS_PER_LSB,
)

if TYPE_CHECKING:  # pragma: no cover - typing only (node.py imports this module)
    from plant_emulator.node import NodeConfig

Value = Union[int, float, str]


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


class Access(str, enum.Enum):
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
    """engineering value = raw * factor (written as the EDS ``Factor`` key, which the canopen package reads)"""
    description: str = ""

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


# --- the table -------------------------------------------------------------------

DEVICE_TYPE_401: Final[int] = 0x000C0191
"""0x1000: CiA 401 profile (0x0191) with analog inputs (bit 18) and analog outputs (bit 19)."""

PDO_NOT_VALID: Final[int] = 1 << 31
PDO_NO_RTR: Final[int] = 1 << 30
TRANSMISSION_SYNC: Final[int] = 1
"""TPDOs: synchronous, every SYNC."""
TRANSMISSION_EVENT: Final[int] = 255
"""RPDO1: asynchronous (event driven, manufacturer specific): applied on receipt."""

# manufacturer-specific objects
OD_SAMPLE_PERIOD: Final[int] = 0x2000
OD_ADC_RESOLUTION: Final[int] = 0x2001
OD_VALVE_LIMIT: Final[int] = 0x2002
OD_WATCHDOG_PERIODS: Final[int] = 0x2003
OD_DIAGNOSTICS: Final[int] = 0x2010

ADC_RESOLUTIONS: Final[tuple[int, ...]] = (12, 16, 20)

DIAGNOSTIC_NAMES: Final[tuple[str, ...]] = (
    "SYNC received",
    "SYNC missed",
    "Watchdog trips",
    "Clipped outputs",
    "Malformed frames",
    "SDO aborts",
)
"""0x2010 sub 1.. (UNSIGNED32, wrap at 2**32)."""


def _var(index: int, name: str, dtype: DataType, access: Access, default: Value, **kw: object) -> ObjectDef:
    return ObjectDef(index, name, ObjectKind.VAR, (Entry(index, 0, name, dtype, access, default, **kw),))  # type: ignore[arg-type]


def _sub0(index: int, value: int, name: str = "Highest sub-index supported", access: Access = Access.CONST) -> Entry:
    return Entry(index, 0, name, DataType.UNSIGNED8, access, value)


def _tpdo_comm(index: int, n: int, cob_id: int, valid: bool) -> ObjectDef:
    flags = PDO_NO_RTR | (0 if valid else PDO_NOT_VALID)
    return ObjectDef(
        index,
        f"TPDO{n} communication parameter",
        ObjectKind.RECORD,
        (
            _sub0(index, 5),
            Entry(index, 1, "COB-ID used by TPDO", DataType.UNSIGNED32, Access.RO, flags + cob_id, node_relative=True,
                  description="bit 31 set: PDO not valid; bit 30 set: no RTR"),
            Entry(index, 2, "Transmission type", DataType.UNSIGNED8, Access.RO, TRANSMISSION_SYNC,
                  description="1: synchronous, sent on every SYNC"),
            Entry(index, 3, "Inhibit time", DataType.UNSIGNED16, Access.RO, 0, unit="100us"),
            Entry(index, 5, "Event timer", DataType.UNSIGNED16, Access.RO, 0, unit="ms"),
        ),
    )


def _mapping(index: int, name: str, mapped: Iterable[int]) -> ObjectDef:
    mapped = tuple(mapped)
    entries = [_sub0(index, len(mapped), "Number of mapped objects", Access.RO)]
    entries += [
        Entry(index, i, f"Mapped object {i}", DataType.UNSIGNED32, Access.RO, m) for i, m in enumerate(mapped, start=1)
    ]
    return ObjectDef(index, name, ObjectKind.RECORD, tuple(entries))


def _map_word(index: int, sub: int, bits: int) -> int:
    return (index << 16) | (sub << 8) | bits


def _array(index: int, name: str, sub0_name: str, item: str, n: int, dtype: DataType, access: Access,
           pdo: bool = False, unit: str = "", factor: float | None = None, description: str = "") -> ObjectDef:
    entries = [_sub0(index, n, sub0_name)]
    entries += [
        Entry(index, i, f"{item} {i}", dtype, access, 0, pdo_mapping=pdo, unit=unit, factor=factor,
              description=description)
        for i in range(1, n + 1)
    ]
    return ObjectDef(index, name, ObjectKind.ARRAY, tuple(entries))


def object_table(cfg: NodeConfig | None = None) -> tuple[ObjectDef, ...]:
    """Every object of the node, with the defaults of ``cfg`` (the EDS uses
    the :class:`~plant_emulator.node.NodeConfig` defaults)."""
    if cfg is None:
        from plant_emulator.node import NodeConfig

        cfg = NodeConfig()
    wide = cfg.adc_bits > 16
    return (
        _var(0x1000, "Device type", DataType.UNSIGNED32, Access.RO, DEVICE_TYPE_401,
             description="CiA 401 I/O module with analog inputs and outputs"),
        _var(0x1001, "Error register", DataType.UNSIGNED8, Access.RO, 0,
             description="bit 0 generic, 1 current, 2 voltage, 4 communication, 7 manufacturer"),
        ObjectDef(
            0x1003,
            "Pre-defined error field",
            ObjectKind.ARRAY,
            (Entry(0x1003, 0, "Number of errors", DataType.UNSIGNED8, Access.RW, 0,
                   description="write 0 to clear the history"),)
            + tuple(
                Entry(0x1003, i, f"Standard error field {i}", DataType.UNSIGNED32, Access.RO, 0,
                      description="newest first: EMCY code in bits 0-15, vendor bytes 0-1 in bits 16-31")
                for i in range(1, 9)
            ),
        ),
        _var(0x1005, "COB-ID SYNC", DataType.UNSIGNED32, Access.RO, SYNC_COB_ID),
        _var(0x1008, "Manufacturer device name", DataType.VISIBLE_STRING, Access.CONST, cfg.device_name),
        _var(0x100A, "Manufacturer software version", DataType.VISIBLE_STRING, Access.CONST, cfg.software_version),
        _var(0x1014, "COB-ID EMCY", DataType.UNSIGNED32, Access.RO, EMCY_BASE, node_relative=True),
        _var(0x1017, "Producer heartbeat time", DataType.UNSIGNED16, Access.RW, cfg.heartbeat_ms, unit="ms",
             description="0 disables the heartbeat"),
        ObjectDef(
            0x1018,
            "Identity object",
            ObjectKind.RECORD,
            (
                _sub0(0x1018, 4),
                Entry(0x1018, 1, "Vendor-ID", DataType.UNSIGNED32, Access.RO, cfg.vendor_id),
                Entry(0x1018, 2, "Product code", DataType.UNSIGNED32, Access.RO, cfg.product_code),
                Entry(0x1018, 3, "Revision number", DataType.UNSIGNED32, Access.RO, cfg.revision),
                Entry(0x1018, 4, "Serial number", DataType.UNSIGNED32, Access.RO, cfg.serial_number),
            ),
        ),
        _var(0x1019, "Synchronous counter overflow value", DataType.UNSIGNED8, Access.RW, cfg.sync_counter_overflow,
             high=240, description="240: SYNC carries a counter 1..240; 0: SYNC without counter"),
        ObjectDef(
            0x1400,
            "RPDO1 communication parameter",
            ObjectKind.RECORD,
            (
                _sub0(0x1400, 2),
                Entry(0x1400, 1, "COB-ID used by RPDO", DataType.UNSIGNED32, Access.RO, PDO_NO_RTR + RPDO1_BASE,
                      node_relative=True),
                Entry(0x1400, 2, "Transmission type", DataType.UNSIGNED8, Access.RO, TRANSMISSION_EVENT,
                      description="255: asynchronous, outputs applied on receipt"),
            ),
        ),
        _mapping(0x1600, "RPDO1 mapping parameter",
                 (_map_word(OD_ANALOG_OUTPUT_16, s, 16) for s in (1, 2))),
        _tpdo_comm(0x1800, 1, TPDO1_BASE, valid=True),
        _tpdo_comm(0x1801, 2, TPDO2_BASE, valid=wide),
        _tpdo_comm(0x1802, 3, TPDO3_BASE, valid=wide),
        _mapping(0x1A00, "TPDO1 mapping parameter", (_map_word(OD_ANALOG_INPUT_16, s, 16) for s in (1, 2, 3, 4))),
        _mapping(0x1A01, "TPDO2 mapping parameter", (_map_word(OD_ANALOG_INPUT_32, s, 32) for s in (1, 2))),
        _mapping(0x1A02, "TPDO3 mapping parameter", (_map_word(OD_ANALOG_INPUT_32, s, 32) for s in (3, 4))),
        _var(OD_SAMPLE_PERIOD, "Sample period", DataType.UNSIGNED32, Access.RW, cfg.sample_period_us,
             low=100, high=1_000_000, unit="us", description="nominal SYNC period; the watchdog counts in these"),
        _var(OD_ADC_RESOLUTION, "ADC resolution", DataType.UNSIGNED8, Access.RW, cfg.adc_bits, low=12, high=20,
             unit="bit", description="12, 16 or 20; above 16 bits TPDO2/TPDO3 carry 0x6402 as well"),
        _var(OD_VALVE_LIMIT, "Valve voltage limit", DataType.REAL32, Access.RW, cfg.valve_limit_v, unit="V",
             description="analog outputs are clipped to +-limit (0 < limit <= 10)"),
        _var(OD_WATCHDOG_PERIODS, "SYNC watchdog periods", DataType.UNSIGNED16, Access.RW, cfg.watchdog_periods,
             description="valves to zero after this many sample periods without SYNC; 0 disables"),
        ObjectDef(
            OD_DIAGNOSTICS,
            "Diagnostic counters",
            ObjectKind.ARRAY,
            (_sub0(OD_DIAGNOSTICS, len(DIAGNOSTIC_NAMES)),)
            + tuple(
                Entry(OD_DIAGNOSTICS, i, name, DataType.UNSIGNED32, Access.RO, 0)
                for i, name in enumerate(DIAGNOSTIC_NAMES, start=1)
            ),
        ),
        _array(OD_ANALOG_INPUT_16, "Read analog input 16-bit", "Number of analog inputs", "Analog input", 4,
               DataType.INTEGER16, Access.RO, pdo=True, unit="V", factor=WORD16_VOLTS_PER_LSB,
               description="left-justified converter value"),
        _array(OD_ANALOG_INPUT_32, "Read analog input 32-bit", "Number of analog inputs", "Analog input", 4,
               DataType.INTEGER32, Access.RO, pdo=True, unit="V", factor=WORD32_VOLTS_PER_LSB,
               description="left-justified converter value"),
        _array(OD_ANALOG_OUTPUT_16, "Write analog output 16-bit", "Number of analog outputs", "Analog output", 2,
               DataType.INTEGER16, Access.RWW, pdo=True, unit="V", factor=WORD16_VOLTS_PER_LSB,
               description="left-justified D/A value; an SDO write applies it like RPDO1"),
    )


# --- runtime dictionary ------------------------------------------------------------

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

    def get(self, index: int, sub: int = 0) -> Value:
        g = self._getters.get((index, sub))
        if g is not None:
            return g()
        return self._values[(index, sub)]

    def set(self, index: int, sub: int, value: Value) -> None:
        assert (index, sub) in self._entries, (index, sub)
        self._values[(index, sub)] = value

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


# --- EDS (CiA 306) -------------------------------------------------------------------

EDS_FILE_INFO: Final[dict[str, str]] = {
    "FileName": "ralf_io.eds",
    "FileVersion": "1",
    "FileRevision": "0",
    "EDSVersion": "4.0",
    "Description": "RALF-HIL plant: CiA 401 analog I/O node (4 A/D inputs, 2 D/A valve outputs)",
    "CreationTime": "12:00PM",
    "CreationDate": "11-23-2026",
    "CreatedBy": "ralf-hil plant_emulator.object_dictionary",
    "ModificationTime": "12:00PM",
    "ModificationDate": "11-23-2026",
    "ModifiedBy": "ralf-hil plant_emulator.object_dictionary",
}

_MANDATORY: Final[frozenset[int]] = frozenset({0x1000, 0x1001, 0x1018})


def _eds_value(e: Entry, value: Value) -> str:
    if e.dtype is DataType.VISIBLE_STRING:
        return str(value)
    if e.dtype is DataType.REAL32:
        return repr(float(value))
    assert isinstance(value, int)
    if e.node_relative:
        return f"$NODEID+0x{value:X}"
    if e.dtype in (DataType.UNSIGNED32, DataType.UNSIGNED16) and value > 0xFF:
        return f"0x{value:0{2 * (e.dtype.size or 4)}X}"
    return str(value)


def _eds_entry(e: Entry, cfg_default: Value) -> list[str]:
    lines = [
        f"ParameterName={e.name}",
        f"ObjectType=0x{ObjectKind.VAR:X}",
        f"DataType=0x{e.dtype:04X}",
        f"AccessType={e.access.value}",
        f"DefaultValue={_eds_value(e, cfg_default)}",
        f"PDOMapping={int(e.pdo_mapping)}",
    ]
    if e.low is not None:
        lines.append(f"LowLimit={e.low}")
    if e.high is not None:
        lines.append(f"HighLimit={e.high}")
    if e.factor is not None:
        lines.append(f"Factor={e.factor!r}")
    if e.unit:
        lines.append(f"Unit={e.unit}")
    if e.description:
        lines.append(f"Description={e.description}")
    return lines


def render_eds(table: Iterable[ObjectDef] | None = None) -> str:
    """The CiA 306 EDS text for ``table`` (default: :func:`object_table` with
    the default configuration); deterministic, so the shipped file can be
    compared with it."""
    from plant_emulator.node import NodeConfig

    cfg = NodeConfig()
    objs = sorted(table if table is not None else object_table(cfg), key=lambda o: o.index)
    out: list[str] = []

    def section(name: str, lines: Iterable[str]) -> None:
        out.append(f"[{name}]")
        out.extend(lines)
        out.append("")

    section("FileInfo", (f"{k}={v}" for k, v in EDS_FILE_INFO.items()))
    n_rx = sum(1 for o in objs if 0x1400 <= o.index <= 0x15FF)
    n_tx = sum(1 for o in objs if 0x1800 <= o.index <= 0x19FF)
    section(
        "DeviceInfo",
        [
            "VendorName=ralf-hil",
            f"VendorNumber=0x{cfg.vendor_id:08X}",
            "ProductName=RALF plant analog I/O",
            f"ProductNumber=0x{cfg.product_code:08X}",
            f"RevisionNumber=0x{cfg.revision:08X}",
            "OrderCode=ralf-hil-plant-io",
        ]
        + [f"BaudRate_{r}={int(r in (125, 250, 500, 1000))}" for r in (10, 20, 50, 125, 250, 500, 800, 1000)]
        + [
            "SimpleBootUpMaster=0",
            "SimpleBootUpSlave=1",
            "Granularity=0",
            "DynamicChannelsSupported=0",
            "GroupMessaging=0",
            f"NrOfRXPDO={n_rx}",
            f"NrOfTXPDO={n_tx}",
            "LSS_Supported=0",
        ],
    )
    section("DummyUsage", (f"Dummy000{i}=0" for i in range(1, 8)))
    comments = [
        "Generated from plant_emulator/object_dictionary.py (object_table); do not edit by hand.",
        "Analog values are CiA 401 left-justified: volts = INT16 * 10/32768 = INT32 * 10/2**31.",
        "TPDO1 (0x6401) is sent on every SYNC; TPDO2/TPDO3 (0x6402) only when 0x2001 > 16 bits.",
        "RPDO1 (0x6411) is asynchronous: outputs are applied on receipt.",
    ]
    section("Comments", [f"Lines={len(comments)}"] + [f"Line{i}={c}" for i, c in enumerate(comments, start=1)])

    groups: dict[str, list[int]] = {"MandatoryObjects": [], "OptionalObjects": [], "ManufacturerObjects": []}
    for o in objs:
        if o.index in _MANDATORY:
            groups["MandatoryObjects"].append(o.index)
        elif 0x2000 <= o.index <= 0x5FFF:
            groups["ManufacturerObjects"].append(o.index)
        else:
            groups["OptionalObjects"].append(o.index)
    by_index = {o.index: o for o in objs}
    for group, indices in groups.items():
        section(group, [f"SupportedObjects={len(indices)}"] + [f"{i}=0x{x:04X}" for i, x in enumerate(indices, start=1)])
        for index in indices:
            o = by_index[index]
            if o.kind is ObjectKind.VAR:
                e = o.entries[0]
                section(f"{index:04X}", _eds_entry(e, e.default))
                continue
            section(
                f"{index:04X}",
                [f"ParameterName={o.name}", f"ObjectType=0x{o.kind:X}", f"SubNumber={len(o.entries)}"],
            )
            for e in o.entries:
                section(f"{index:04X}sub{e.sub:X}", _eds_entry(e, e.default))
    return "\n".join(out).rstrip("\n") + "\n"


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render_eds())
