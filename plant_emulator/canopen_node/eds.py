"""The CiA 306 EDS of the node, written from its object table.

Regenerate the shipped file after changing the table::

    python -m plant_emulator.canopen_node > protocol/ralf_io.eds

(a test compares the shipped file with :func:`render_eds`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

from plant_emulator.canopen_node.config import NodeConfig
from plant_emulator.canopen_node.objects import object_table
from plant_emulator.canopen_node.od import DataType, Entry, ObjectDef, ObjectKind, Value

EDS_FILE_INFO: Final[dict[str, str]] = {
    "FileName": "ralf_io.eds",
    "FileVersion": "1",
    "FileRevision": "0",
    "EDSVersion": "4.0",
    "Description": "RALF-HIL plant: CiA 401 analog I/O node (4 A/D inputs, 2 D/A valve outputs)",
    "CreationTime": "12:00PM",
    "CreationDate": "11-23-2026",
    "CreatedBy": "ralf-hil plant_emulator.canopen_node",
    "ModificationTime": "12:00PM",
    "ModificationDate": "11-23-2026",
    "ModifiedBy": "ralf-hil plant_emulator.canopen_node",
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
        "Generated from plant_emulator/canopen_node/objects.py (object_table); do not edit by hand.",
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
