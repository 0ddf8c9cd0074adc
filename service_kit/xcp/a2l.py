"""The A2L (ASAM MCD-2 MC) that describes a :class:`MemoryLayout`: one
MEASUREMENT per measurement, one CHARACTERISTIC (VALUE) per calibration
parameter, each with its own COMPU_METHOD (``LINEAR``, ``COEFFS_LINEAR
factor offset``: physical = factor * raw + offset), and the XCP IF_DATA
(protocol layer, DAQ events, the Ethernet and CAN transports). Written from the
same layout the slave serves, so the two cannot disagree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from service_kit.xcp.can import CAN_MAX_CTO, CAN_MAX_DTO
from service_kit.xcp.memory import MemoryLayout, Variable
from service_kit.xcp.slave import MAX_CTO, MAX_DAQ, MAX_DTO, MAX_ODT_ENTRY_SIZE, EventChannel

__all__ = ["a2l_text", "event_cycle"]


CAN_BAUDRATE: Final = 500000
"""The A2L's nominal bit rate on CAN (the rig's buses are emulated: python-can virtual or udp_multicast)."""


def event_cycle(sample_period_s: float) -> tuple[int, int]:
    """``(cycle, XCP time unit)`` of a periodic event: the coarsest unit in which the
    period is a whole number below 256 (``(0, 0)``: none, the event is then sporadic)."""
    for unit, seconds in ((6, 1e-3), (5, 1e-4), (4, 1e-5), (3, 1e-6)):
        cycle = sample_period_s / seconds
        if abs(cycle - round(cycle)) < 1e-9 * max(1.0, cycle) and 1 <= round(cycle) <= 255:
            return int(round(cycle)), unit
    return 0, 0


def _q(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _number(x: float) -> str:
    return repr(float(x)) if x != int(x) or abs(x) >= 1e15 else str(int(x))


def _compu_method(v: Variable) -> str:
    fmt = '"%12.6"' if v.is_float or v.factor != 1.0 else '"%12.0"'
    return (
        f"    /begin COMPU_METHOD CM_{v.name} {_q(v.description or v.name)}\n"
        f"      LINEAR {fmt} {_q(v.unit)}\n"
        f"      COEFFS_LINEAR {_number(v.factor)} {_number(v.offset)}\n"
        f"    /end COMPU_METHOD\n"
    )


def _measurement(v: Variable) -> str:
    return (
        f"    /begin MEASUREMENT {v.name} {_q(v.description)}\n"
        f"      {v.datatype} CM_{v.name} 0 0 {_number(v.lower)} {_number(v.upper)}\n"
        f"      ECU_ADDRESS 0x{v.address:X}\n"
        f"    /end MEASUREMENT\n"
    )


def _characteristic(v: Variable) -> str:
    return (
        f"    /begin CHARACTERISTIC {v.name} {_q(v.description)}\n"
        f"      VALUE 0x{v.address:X} RL_{v.datatype} 0 CM_{v.name} {_number(v.lower)} {_number(v.upper)}\n"
        f"    /end CHARACTERISTIC\n"
    )


def _if_data(events: Sequence[EventChannel], udp_port: int, tcp_port: int, host: str, can_ids: tuple[int, int] | None) -> str:
    lines = [
        "    /begin IF_DATA XCP",
        "      /begin PROTOCOL_LAYER 0x0104 1000 2000 0 0 0 0 0",
        f"        {MAX_CTO} {MAX_DTO} BYTE_ORDER_MSB_LAST ADDRESS_GRANULARITY_BYTE",
        "        OPTIONAL_CMD GET_COMM_MODE_INFO OPTIONAL_CMD GET_ID OPTIONAL_CMD SET_MTA OPTIONAL_CMD UPLOAD",
        "        OPTIONAL_CMD SHORT_UPLOAD OPTIONAL_CMD DOWNLOAD OPTIONAL_CMD SHORT_DOWNLOAD OPTIONAL_CMD GET_DAQ_CLOCK",
        "        OPTIONAL_CMD GET_DAQ_PROCESSOR_INFO OPTIONAL_CMD GET_DAQ_RESOLUTION_INFO OPTIONAL_CMD GET_DAQ_EVENT_INFO",
        "        OPTIONAL_CMD FREE_DAQ OPTIONAL_CMD ALLOC_DAQ OPTIONAL_CMD ALLOC_ODT OPTIONAL_CMD ALLOC_ODT_ENTRY",
        "      /end PROTOCOL_LAYER",
        f"      /begin DAQ DYNAMIC {MAX_DAQ} {len(events)} 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE IDENTIFICATION_FIELD_TYPE_ABSOLUTE",
        f"        GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE {MAX_ODT_ENTRY_SIZE} NO_OVERLOAD_INDICATION",
        "        /begin TIMESTAMP_SUPPORTED 1 SIZE_DWORD UNIT_1US /end TIMESTAMP_SUPPORTED",
    ]
    for i, e in enumerate(events):
        lines.append(f"        /begin EVENT {_q(e.name)} {_q(e.name[:8])} {i} DAQ 255 {e.cycle} {e.unit} {e.priority} /end EVENT")
    lines.append("      /end DAQ")
    if udp_port:
        lines.append(f"      /begin XCP_ON_UDP_IP 0x0104 {udp_port} ADDRESS {_q(host)} /end XCP_ON_UDP_IP")
    if tcp_port:
        lines.append(f"      /begin XCP_ON_TCP_IP 0x0104 {tcp_port} ADDRESS {_q(host)} /end XCP_ON_TCP_IP")
    if can_ids is not None:  # its own protocol layer: a classic CAN frame holds 8 bytes
        lines += [
            f"      /begin XCP_ON_CAN 0x0104 CAN_ID_MASTER 0x{can_ids[0]:X} CAN_ID_SLAVE 0x{can_ids[1]:X} BAUDRATE {CAN_BAUDRATE} SAMPLE_POINT 0x4B",
            "        /begin PROTOCOL_LAYER 0x0104 1000 2000 0 0 0 0 0",
            f"          {CAN_MAX_CTO} {CAN_MAX_DTO} BYTE_ORDER_MSB_LAST ADDRESS_GRANULARITY_BYTE",
            "        /end PROTOCOL_LAYER",
            "      /end XCP_ON_CAN",
        ]
    lines.append("    /end IF_DATA")
    return "\n".join(lines) + "\n"


def a2l_text(
    layout: MemoryLayout,
    module: str,
    description: str,
    events: Sequence[EventChannel],
    *,
    udp_port: int = 0,
    tcp_port: int = 0,
    host: str = "127.0.0.1",
    can_ids: tuple[int, int] | None = None,
) -> str:
    """The A2L of ``layout`` as MODULE ``module`` (byte order INTEL: ``MSB_LAST``)."""
    types = sorted({v.datatype for v in layout.calibrations})
    parts = [
        "ASAP2_VERSION 1 71\n",
        f"/begin PROJECT {module} {_q(description)}\n",
        '  /begin HEADER "" VERSION "1.0" /end HEADER\n',
        f"  /begin MODULE {module} {_q(description)}\n",
        '    /begin MOD_COMMON "" BYTE_ORDER MSB_LAST ALIGNMENT_BYTE 1 /end MOD_COMMON\n',
        '    /begin MOD_PAR ""\n',
        f'      /begin MEMORY_SEGMENT Map "" DATA RAM INTERN 0x{layout.base:X} 0x{layout.size:X} -1 -1 -1 -1 -1 /end MEMORY_SEGMENT\n',
        "    /end MOD_PAR\n",
        _if_data(events, udp_port, tcp_port, host, can_ids),
    ]
    parts += [f"    /begin RECORD_LAYOUT RL_{t} FNC_VALUES 1 {t} ROW_DIR DIRECT /end RECORD_LAYOUT\n" for t in types]
    for v in layout.variables:
        parts.append(_compu_method(v))
        parts.append(_measurement(v) if v.kind == "measurement" else _characteristic(v))
    parts += ["  /end MODULE\n", "/end PROJECT\n"]
    return "".join(parts)
