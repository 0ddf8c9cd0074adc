"""The CiA 306 EDS of the node, written from its object table, and its units file.

Regenerate the shipped files after changing the table::

    python -m plant_emulator.canopen_node --write protocol

(``protocol/ralf_io.eds`` and ``protocol/ralf_io.units.json``; a test
compares both with :func:`render_eds` and :func:`render_units`, and runs
Lely's ``dcfchk`` on the EDS).

CiA 306 has no key for an entry's unit, scale factor or description, so the
EDS holds only standard keys (Lely's ``dcfchk`` flags any other) and says
those things in comment lines (``;``), which every EDS reader skips. The
same facts travel, machine-readable, in the units file next to it (JSON,
one record per EDS section: ``unit``, ``factor``, ``description``);
:func:`apply_units` puts them on a ``canopen`` object dictionary, so
``Variable.phys`` reads volts as it did when the EDS carried the package's
own ``Factor`` key. REAL32 defaults are written as the IEEE-754 bit pattern
in hex (``10.0`` -> ``0x41200000``), as CiA 306 writes numbers; no value or
comment holds ``=`` or ``;`` (INI readers split or cut lines there).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any, Final

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
UNITS_FORMAT: Final[str] = "ralf-hil EDS units 1"
UNITS_FILE: Final[str] = "ralf_io.units.json"
"""The units file's name, next to the EDS in the ``protocol`` package."""


def real32_bits(value: float) -> str:
    """A REAL32 as CiA 306 writes it: the IEEE-754 single bit pattern in hex (10.0 -> ``0x41200000``)."""
    (bits,) = struct.unpack(">I", struct.pack(">f", float(value)))
    return f"0x{bits:08X}"


def _eds_value(e: Entry, value: Value) -> str:
    if e.dtype is DataType.VISIBLE_STRING:
        return str(value)
    if e.dtype is DataType.REAL32:
        return real32_bits(float(value))
    assert isinstance(value, int)
    if e.node_relative:
        return f"$NODEID+0x{value:X}"
    if e.dtype in (DataType.UNSIGNED32, DataType.UNSIGNED16) and value > 0xFF:
        return f"0x{value:0{2 * (e.dtype.size or 4)}X}"
    return str(value)


def _comment(text: str, value: bool = False) -> str:
    """A comment line (``;text``), or with ``value`` the text of a ``[Comments]`` LineN value."""
    if "=" in text or "\n" in text or (value and ";" in text):
        raise ValueError(f"EDS comment text must not hold '='{', ;' if value else ''} or a line break: {text!r}")
    return text if value else f";{text}"


def _section_name(e: Entry, var: bool) -> str:
    return f"{e.index:04X}" if var else f"{e.index:04X}sub{e.sub:X}"


def _eds_entry(e: Entry, cfg_default: Value) -> list[str]:
    lines = []
    if e.description:
        lines.append(_comment(e.description))
    if e.unit or e.factor is not None:
        lines.append(_comment(f"Unit {e.unit or '-'}" + (f", {e.factor!r} per raw unit" if e.factor is not None else "")))
    lines += [
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
    if e.obj_flags:
        lines.append(f"ObjFlags=0x{e.obj_flags:X}")
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
        "Generated from plant_emulator/canopen_node/objects.py (object_table), not edited by hand.",
        "Units, scale factors and descriptions: ralf_io.units.json (and the comment lines of each section).",
        "Analog values are CiA 401 left-justified: volts are INT16 x 10/32768 or INT32 x 10/2**31.",
        "TPDO1 (0x6401) is sent on every SYNC. TPDO2/TPDO3 (0x6402) only above 16 bits of 0x2001.",
        "RPDO1 (0x6411) is asynchronous: outputs are applied on receipt.",
        "0x6411 sub 1-2 (rww) refuse SDO writes outside OPERATIONAL and while the SYNC watchdog",
        "holds the valves: abort 0x08000022. ObjFlags 0x1 keeps a DCF download from writing them.",
    ]
    comments = [_comment(c, value=True) for c in comments]
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
                section(_section_name(e, var=True), _eds_entry(e, e.default))
                continue
            section(
                f"{index:04X}",
                [f"ParameterName={o.name}", f"ObjectType=0x{o.kind:X}", f"SubNumber={len(o.entries)}"],
            )
            for e in o.entries:
                section(_section_name(e, var=False), _eds_entry(e, e.default))
    return "\n".join(out).rstrip("\n") + "\n"


@dataclass(frozen=True)
class EntryUnits:
    """What CiA 306 cannot say about an entry: its unit, scale and meaning."""

    unit: str = ""
    factor: float | None = None
    """engineering value = raw * factor"""
    description: str = ""


def render_units(table: Iterable[ObjectDef] | None = None) -> str:
    """The units file (JSON) for ``table`` (default: :func:`object_table`):
    ``{"format": ..., "eds": ..., "entries": {"<EDS section>": {"unit", "factor", "description"}}}``,
    entries without any of the three left out; deterministic."""
    objs = sorted(table if table is not None else object_table(NodeConfig()), key=lambda o: o.index)
    entries: dict[str, dict[str, Any]] = {}
    for o in objs:
        for e in o.entries:
            if e.unit or e.factor is not None or e.description:
                entries[_section_name(e, var=o.kind is ObjectKind.VAR)] = {"unit": e.unit, "factor": e.factor, "description": e.description}
    doc = {"format": UNITS_FORMAT, "eds": EDS_FILE_INFO["FileName"], "entries": entries}
    return json.dumps(doc, indent=1) + "\n"


def _section_key(section: str) -> tuple[int, int | None]:
    """``"6401sub1"`` -> (0x6401, 1); ``"2002"`` -> (0x2002, None)."""
    head, _, sub = section.lower().partition("sub")
    return int(head, 16), (int(sub, 16) if sub else None)


def load_units(path: str | Path | None = None) -> dict[tuple[int, int], EntryUnits]:
    """The units file (default: the shipped ``protocol/ralf_io.units.json``) by
    (index, sub-index); a VAR's entry is sub-index 0. A file that is not one
    raises ValueError naming it."""
    text = Path(path).read_text() if path is not None else files("protocol").joinpath(UNITS_FILE).read_text()
    try:
        doc = json.loads(text)
        if doc.get("format") != UNITS_FORMAT:
            raise ValueError(f"format is {doc.get('format')!r}, not {UNITS_FORMAT!r}")
        out: dict[tuple[int, int], EntryUnits] = {}
        for section, rec in doc["entries"].items():
            index, sub = _section_key(section)
            factor = rec.get("factor")
            out[(index, sub or 0)] = EntryUnits(str(rec.get("unit", "")), None if factor is None else float(factor), str(rec.get("description", "")))
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise ValueError(f"{path or UNITS_FILE}: not an EDS units file: {exc}") from None
    return out


def apply_units(od: Any, units: Mapping[tuple[int, int], EntryUnits] | None = None) -> int:
    """Put the units file's ``factor``, ``unit`` and ``description`` on the
    variables of a ``canopen`` object dictionary loaded from the EDS (what the
    package's non-standard ``Factor``/``Unit``/``Description`` keys would
    have set): ``Variable.phys`` then reads engineering values. Returns how
    many variables were given them."""
    n = 0
    for (index, sub), u in (units if units is not None else load_units()).items():
        var = od.get_variable(index, sub)
        if var is None:
            continue
        if u.factor is not None:
            var.factor = u.factor
        var.unit = u.unit
        var.description = u.description
        n += 1
    return n
