"""This node's object table: the single description of every object it serves
(CiA 301 communication objects, the manufacturer-specific settings and the
CiA 401 analog I/O).

The running node builds its :class:`~plant_emulator.canopen_node.od.ObjectDictionary`
from :func:`object_table`, and :mod:`plant_emulator.canopen_node.eds` writes the
shipped ``protocol/ralf_io.eds`` from the same table, so the file a master
loads always describes what the node answers.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

from plant_emulator.canopen_node.config import NodeConfig
from plant_emulator.canopen_node.od import (
    Access,
    DataType,
    Entry,
    ObjectDef,
    ObjectKind,
    Value,
)
from protocol.can_map import (
    ADC_RESOLUTIONS,
    EMCY_BASE,
    OD_ADC_RESOLUTION,
    OD_ANALOG_INPUT_16,
    OD_ANALOG_INPUT_32,
    OD_ANALOG_OUTPUT_16,
    OD_DIAGNOSTICS,
    OD_SAMPLE_PERIOD,
    OD_VALVE_LIMIT,
    OD_WATCHDOG_PERIODS,
    RPDO1_BASE,
    SYNC_COB_ID,
    TPDO1_BASE,
    TPDO2_BASE,
    TPDO3_BASE,
    WORD16_VOLTS_PER_LSB,
    WORD32_VOLTS_PER_LSB,
)

__all__ = ["ADC_RESOLUTIONS", "object_table"]


DEVICE_TYPE_401: Final[int] = 0x000C0191
"""0x1000: CiA 401 profile (0x0191) with analog inputs (bit 18) and analog outputs (bit 19)."""

PDO_NOT_VALID: Final[int] = 1 << 31
PDO_NO_RTR: Final[int] = 1 << 30
OBJ_FLAG_REFUSE_WRITE_ON_DOWNLOAD: Final[int] = 0x1
"""CiA 306 ObjFlags bit 0: a configuration manager must not write the entry while it downloads
a DCF (it does so in PRE-OPERATIONAL, where the outputs 0x6411 refuse writes)."""
TRANSMISSION_SYNC: Final[int] = 1
"""TPDOs: synchronous, every SYNC."""
TRANSMISSION_EVENT: Final[int] = 255
"""RPDO1: asynchronous (event driven, manufacturer specific): applied on receipt."""

DIAGNOSTIC_NAMES: Final[tuple[str, ...]] = (
    "SYNC received",
    "SYNC missed",
    "Watchdog trips",
    "Clipped outputs",
    "Malformed frames",
    "SDO aborts",
    "Impersonated frames",
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
            Entry(
                index,
                1,
                "COB-ID used by TPDO",
                DataType.UNSIGNED32,
                Access.RO,
                flags + cob_id,
                node_relative=True,
                description="bit 31 set: PDO not valid; bit 30 set: no RTR",
            ),
            Entry(index, 2, "Transmission type", DataType.UNSIGNED8, Access.RO, TRANSMISSION_SYNC, description="1: synchronous, sent on every SYNC"),
            Entry(index, 3, "Inhibit time", DataType.UNSIGNED16, Access.RO, 0, unit="100us"),
            Entry(index, 5, "Event timer", DataType.UNSIGNED16, Access.RO, 0, unit="ms"),
        ),
    )


def _mapping(index: int, name: str, mapped: Iterable[int]) -> ObjectDef:
    mapped = tuple(mapped)
    entries = [_sub0(index, len(mapped), "Number of mapped objects", Access.RO)]
    entries += [Entry(index, i, f"Mapped object {i}", DataType.UNSIGNED32, Access.RO, m) for i, m in enumerate(mapped, start=1)]
    return ObjectDef(index, name, ObjectKind.RECORD, tuple(entries))


def _map_word(index: int, sub: int, bits: int) -> int:
    return (index << 16) | (sub << 8) | bits


def _array(
    index: int,
    name: str,
    sub0_name: str,
    item: str,
    n: int,
    dtype: DataType,
    access: Access,
    pdo: bool = False,
    unit: str = "",
    factor: float | None = None,
    description: str = "",
    obj_flags: int = 0,
) -> ObjectDef:
    entries = [_sub0(index, n, sub0_name)]
    entries += [
        Entry(index, i, f"{item} {i}", dtype, access, 0, pdo_mapping=pdo, unit=unit, factor=factor, description=description, obj_flags=obj_flags)
        for i in range(1, n + 1)
    ]
    return ObjectDef(index, name, ObjectKind.ARRAY, tuple(entries))


def _device_objects(cfg: NodeConfig) -> tuple[ObjectDef, ...]:
    """0x1000-0x1019: device type, error register and history, identity, heartbeat, SYNC."""
    return (
        _var(0x1000, "Device type", DataType.UNSIGNED32, Access.RO, DEVICE_TYPE_401, description="CiA 401 I/O module with analog inputs and outputs"),
        _var(0x1001, "Error register", DataType.UNSIGNED8, Access.RO, 0, description="bit 0 generic, 1 current, 2 voltage, 4 communication, 7 manufacturer"),
        ObjectDef(
            0x1003,
            "Pre-defined error field",
            ObjectKind.ARRAY,
            (Entry(0x1003, 0, "Number of errors", DataType.UNSIGNED8, Access.RW, 0, description="write 0 to clear the history"),)
            + tuple(
                Entry(
                    0x1003,
                    i,
                    f"Standard error field {i}",
                    DataType.UNSIGNED32,
                    Access.RO,
                    0,
                    description="newest first: EMCY code in bits 0-15, vendor bytes 0-1 in bits 16-31",
                )
                for i in range(1, 9)
            ),
        ),
        _var(0x1005, "COB-ID SYNC", DataType.UNSIGNED32, Access.RO, SYNC_COB_ID),
        _var(0x1008, "Manufacturer device name", DataType.VISIBLE_STRING, Access.CONST, cfg.device_name),
        _var(0x100A, "Manufacturer software version", DataType.VISIBLE_STRING, Access.CONST, cfg.software_version),
        _var(0x1014, "COB-ID EMCY", DataType.UNSIGNED32, Access.RO, EMCY_BASE, node_relative=True),
        _var(0x1017, "Producer heartbeat time", DataType.UNSIGNED16, Access.RW, cfg.heartbeat_ms, unit="ms", description="0 disables the heartbeat"),
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
        _var(
            0x1019,
            "Synchronous counter overflow value",
            DataType.UNSIGNED8,
            Access.RW,
            cfg.sync_counter_overflow,
            high=240,
            description="240: SYNC with a counter 1..240 and SYNC without counter both accepted; 0: only SYNC without counter",
        ),
    )


def _pdo_objects(cfg: NodeConfig) -> tuple[ObjectDef, ...]:
    """0x1400-0x1A02: RPDO1 and TPDO1-3 communication and mapping (TPDO2/3 valid above 16 bits)."""
    wide = cfg.adc_bits > 16
    return (
        ObjectDef(
            0x1400,
            "RPDO1 communication parameter",
            ObjectKind.RECORD,
            (
                _sub0(0x1400, 5),
                Entry(0x1400, 1, "COB-ID used by RPDO", DataType.UNSIGNED32, Access.RO, PDO_NO_RTR + RPDO1_BASE, node_relative=True),
                Entry(
                    0x1400,
                    2,
                    "Transmission type",
                    DataType.UNSIGNED8,
                    Access.RO,
                    TRANSMISSION_EVENT,
                    description="255: asynchronous, outputs applied on receipt",
                ),
                Entry(
                    0x1400,
                    5,
                    "Event timer",
                    DataType.UNSIGNED16,
                    Access.RW,
                    0,
                    unit="ms",
                    description="RPDO1 deadline monitoring: valves to zero when no RPDO1 for this long after the "
                    "first (0 off); written only outside OPERATIONAL",
                ),
            ),
        ),
        _mapping(0x1600, "RPDO1 mapping parameter", (_map_word(OD_ANALOG_OUTPUT_16, s, 16) for s in (1, 2))),
        _tpdo_comm(0x1800, 1, TPDO1_BASE, valid=True),
        _tpdo_comm(0x1801, 2, TPDO2_BASE, valid=wide),
        _tpdo_comm(0x1802, 3, TPDO3_BASE, valid=wide),
        _mapping(0x1A00, "TPDO1 mapping parameter", (_map_word(OD_ANALOG_INPUT_16, s, 16) for s in (1, 2, 3, 4))),
        _mapping(0x1A01, "TPDO2 mapping parameter", (_map_word(OD_ANALOG_INPUT_32, s, 32) for s in (1, 2))),
        _mapping(0x1A02, "TPDO3 mapping parameter", (_map_word(OD_ANALOG_INPUT_32, s, 32) for s in (3, 4))),
    )


def _manufacturer_objects(cfg: NodeConfig) -> tuple[ObjectDef, ...]:
    """0x2000-0x2010: sample period, A/D resolution, valve limit, watchdog, diagnostics."""
    return (
        _var(
            OD_SAMPLE_PERIOD,
            "Sample period",
            DataType.UNSIGNED32,
            Access.RW,
            cfg.sample_period_us,
            low=100,
            high=1_000_000,
            unit="us",
            description="nominal SYNC period; the watchdog counts in these",
        ),
        _var(
            OD_ADC_RESOLUTION,
            "ADC resolution",
            DataType.UNSIGNED8,
            Access.RW,
            cfg.adc_bits,
            low=12,
            high=20,
            unit="bit",
            description="12, 16 or 20; above 16 bits TPDO2/TPDO3 carry 0x6402 as well",
        ),
        _var(
            OD_VALVE_LIMIT,
            "Valve voltage limit",
            DataType.REAL32,
            Access.RW,
            cfg.valve_limit_v,
            unit="V",
            description="analog outputs are clipped to +-limit (above 0, at most 10 V)",
        ),
        _var(
            OD_WATCHDOG_PERIODS,
            "SYNC watchdog periods",
            DataType.UNSIGNED16,
            Access.RW,
            cfg.watchdog_periods,
            description="valves to zero after this many sample periods without SYNC (or RPDO1 once one came); 0 (off) is refused by SDO",
        ),
        ObjectDef(
            OD_DIAGNOSTICS,
            "Diagnostic counters",
            ObjectKind.ARRAY,
            (_sub0(OD_DIAGNOSTICS, len(DIAGNOSTIC_NAMES)),)
            + tuple(Entry(OD_DIAGNOSTICS, i, name, DataType.UNSIGNED32, Access.RO, 0) for i, name in enumerate(DIAGNOSTIC_NAMES, start=1)),
        ),
    )


def _profile_objects() -> tuple[ObjectDef, ...]:
    """0x6401, 0x6402, 0x6411: CiA 401 analog inputs and outputs."""
    return (
        _array(
            OD_ANALOG_INPUT_16,
            "Read analog input 16-bit",
            "Number of analog inputs",
            "Analog input",
            4,
            DataType.INTEGER16,
            Access.RO,
            pdo=True,
            unit="V",
            factor=WORD16_VOLTS_PER_LSB,
            description="left-justified converter value",
        ),
        _array(
            OD_ANALOG_INPUT_32,
            "Read analog input 32-bit",
            "Number of analog inputs",
            "Analog input",
            4,
            DataType.INTEGER32,
            Access.RO,
            pdo=True,
            unit="V",
            factor=WORD32_VOLTS_PER_LSB,
            description="left-justified converter value",
        ),
        _array(
            OD_ANALOG_OUTPUT_16,
            "Write analog output 16-bit",
            "Number of analog outputs",
            "Analog output",
            2,
            DataType.INTEGER16,
            Access.RWW,
            pdo=True,
            unit="V",
            factor=WORD16_VOLTS_PER_LSB,
            description="left-justified D/A value; an SDO write applies it like RPDO1, but only in OPERATIONAL with SYNC present (else abort 0x08000022)",
            obj_flags=OBJ_FLAG_REFUSE_WRITE_ON_DOWNLOAD,
        ),
    )


def object_table(cfg: NodeConfig | None = None) -> tuple[ObjectDef, ...]:
    """Every object of the node, with the defaults of ``cfg`` (the EDS uses
    the :class:`~plant_emulator.canopen_node.config.NodeConfig` defaults)."""
    if cfg is None:
        cfg = NodeConfig()
    return _device_objects(cfg) + _pdo_objects(cfg) + _manufacturer_objects(cfg) + _profile_objects()
