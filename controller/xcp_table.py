"""The one table of what the controller serves over XCP (docs/xcp.md).

Every measurement and calibration parameter, with its ASAM type, unit,
physical limits and linear conversion (``physical = factor * raw +
offset``). The slave's memory map (:func:`controller_layout`) and the A2L
(:func:`controller_a2l`; ``python -m controller.xcp_table``) are both built
from :data:`XCP_TABLE`, so they cannot drift apart.

``source`` names where the loop takes a measurement's raw value: a column
of the run record (:data:`controller.service.RECORD_COLUMNS`), or one of
:data:`SERVICE_SOURCES` the service keeps. A calibration parameter's raw
value is the one the control law holds (the PI gains in V/rad, which the
A2L shows in the thesis's mV/rad; the OATF's first stage; the dither's
amplitude) or the input monitors' limits in effect (their settings'
bounds: :class:`protocol.setting_groups.InputMonitors`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from protocol.can_map import WORD16_VOLTS_PER_LSB
from service_kit.xcp.a2l import a2l_text, event_cycle
from service_kit.xcp.memory import MemoryLayout, Variable
from service_kit.xcp.slave import EventChannel

__all__ = ["A2L_MODULE", "SERVICE_SOURCES", "XCP_TABLE", "XcpEntry", "controller_a2l", "controller_layout", "table_markdown", "xcp_events"]

A2L_MODULE: Final = "RALF_CONTROLLER"
"""The A2L MODULE's name; GET_ID 0 answers it."""
BASE_ADDRESS: Final = 0x1000
SERVICE_SOURCES: Final = frozenset({"tet_prev_s", "deadline_misses", "overruns"})
"""Measurements the service keeps outside the run record."""
CALIBRATIONS: Final = frozenset(
    {
        "kp1",
        "kp2",
        "ki1",
        "ki2",
        "oatf_frequency_hz",
        "oatf_zeta",
        "dither_amplitude_v",
        "input_extension_lo_in",
        "input_extension_hi_in",
        "input_stuck_samples",
        "input_extension_rate_v_s",
        "input_deflection_rate_v_s",
        "input_disagree_in",
    }
)
"""The parameters a master may write (each has its apply step in :mod:`controller.xcp_link`)."""


@dataclass(frozen=True)
class XcpEntry:
    variable: Variable
    source: str
    """A run-record column, a :data:`SERVICE_SOURCES` name, or (calibration) the parameter itself."""


def _m(name: str, unit: str, lower: float, upper: float, description: str, datatype: str = "FLOAT64_IEEE", factor: float = 1.0, source: str = "") -> XcpEntry:
    return XcpEntry(Variable(name, datatype, unit, lower, upper, "measurement", factor, 0.0, description), source or name)


def _c(name: str, unit: str, lower: float, upper: float, description: str, factor: float = 1.0, datatype: str = "FLOAT64_IEEE") -> XcpEntry:
    return XcpEntry(Variable(name, datatype, unit, lower, upper, "calibration", factor, 0.0, description), name)


_ANGLE = 3.2
_INCHES = 100.0
XCP_TABLE: Final[tuple[XcpEntry, ...]] = (
    _m("tick", "", 0, 4294967295, "the loop's tick counter", "ULONG"),
    _m("t_s", "s", 0, 1e7, "the tick's simulated time"),
    _m("phi_ref1", "rad", -_ANGLE, _ANGLE, "joint 1 set-point"),
    _m("phi_ref2", "rad", -_ANGLE, _ANGLE, "joint 2 set-point"),
    _m("phi_shaped1", "rad", -_ANGLE, _ANGLE, "joint 1 set-point after the OATF (outer)"),
    _m("phi_shaped2", "rad", -_ANGLE, _ANGLE, "joint 2 set-point after the OATF (outer)"),
    _m("phi1", "rad", -_ANGLE, _ANGLE, "joint 1 angle"),
    _m("phi2", "rad", -_ANGLE, _ANGLE, "joint 2 angle"),
    _m("ext1_in", "in", -_INCHES, _INCHES, "cylinder 1 extension [A.8]"),
    _m("ext2_in", "in", -_INCHES, _INCHES, "cylinder 2 extension [A.8]"),
    _m("defl1_in", "in", -_INCHES, _INCHES, "link 1 deflection"),
    _m("defl2_in", "in", -_INCHES, _INCHES, "link 2 deflection"),
    _m("ai1_word", "V", -10, 10, "A/D word, channel 1 (raw INT16; physical: volts)", "SWORD", WORD16_VOLTS_PER_LSB),
    _m("ai2_word", "V", -10, 10, "A/D word, channel 2 (raw INT16; physical: volts)", "SWORD", WORD16_VOLTS_PER_LSB),
    _m("ai3_word", "V", -10, 10, "A/D word, channel 3 (raw INT16; physical: volts)", "SWORD", WORD16_VOLTS_PER_LSB),
    _m("ai4_word", "V", -10, 10, "A/D word, channel 4 (raw INT16; physical: volts)", "SWORD", WORD16_VOLTS_PER_LSB),
    _m("u1_v", "V", -10, 10, "valve 1 voltage after the D/A"),
    _m("u2_v", "V", -10, 10, "valve 2 voltage after the D/A"),
    _m("pi1_v", "V", -10, 10, "joint 1 PI output"),
    _m("pi2_v", "V", -10, 10, "joint 2 PI output"),
    _m("oatf_hz", "Hz", 0, 100, "the OATF's design frequency (NaN: off)"),
    _m("f_id_hz", "Hz", 0, 100, "first identified frequency (NaN: none yet)"),
    _m("f_id2_hz", "Hz", 0, 100, "second identified frequency (NaN: none)"),
    _m("zeta_id", "", 0, 1, "first identified damping ratio"),
    _m("id_confidence", "", 0, 1, "the identification's confidence"),
    _m("irq_applied", "", 0, 1, "1: a DSP interrupt changed the OATF at this tick"),
    _m("stale", "", 0, 1, "1: the identified parameters are stale"),
    _m("tet_prev_s", "s", 0, 10, "the previous tick's task execution time (wall clock)"),
    _m("deadline_misses", "", 0, 4294967295, "DSP batches whose interrupt missed its deadline", "ULONG"),
    _m("overruns", "", 0, 4294967295, "ticks that overran their period (real time)", "ULONG"),
    _c("kp1", "mV/rad", 0, 1e6, "joint 1 proportional gain (raw: V/rad)", 1000.0),
    _c("kp2", "mV/rad", 0, 1e6, "joint 2 proportional gain (raw: V/rad)", 1000.0),
    _c("ki1", "mV/rad", 0, 1e6, "joint 1 integral gain, on the windowed sum of e*Ts (raw: V/rad)", 1000.0),
    _c("ki2", "mV/rad", 0, 1e6, "joint 2 integral gain, on the windowed sum of e*Ts (raw: V/rad)", 1000.0),
    _c("oatf_frequency_hz", "Hz", 0.5, 50, "the OATF first stage's design frequency [3-33] (runs with an OATF only)"),
    _c("oatf_zeta", "", 0, 0.95, "the OATF first stage's design damping ratio (runs with an OATF only)"),
    _c("dither_amplitude_v", "V", 0, 2.0, "the dither's RMS per valve; 0 mutes it (runs with a dither only)"),
    _c("input_extension_lo_in", "in", -100, 100, "input_range: the extensions' low end, below the high end (runs with input monitors only)"),
    _c("input_extension_hi_in", "in", -100, 100, "input_range: the extensions' high end, above the low end (runs with input monitors only)"),
    _c("input_stuck_samples", "", 2, 100000, "input_stuck: moving ticks with an unchanged code before it fires (runs with input monitors only)", 1.0, "ULONG"),
    _c("input_extension_rate_v_s", "V/s", 0.1, 1e6, "input_rate: the rate limit of AI1, AI2 (runs with input monitors only)"),
    _c("input_deflection_rate_v_s", "V/s", 0.1, 1e6, "input_rate: the rate limit of AI3, AI4 (runs with input monitors only)"),
    _c("input_disagree_in", "in", 0.001, 10, "input_disagree: the largest |measured - implied| deflection (runs with input monitors only)"),
)


def controller_layout() -> MemoryLayout:
    """The memory map of :data:`XCP_TABLE` from :data:`BASE_ADDRESS`."""
    return MemoryLayout([e.variable for e in XCP_TABLE], BASE_ADDRESS)


def xcp_events(sample_period_s: float) -> tuple[EventChannel, ...]:
    """Event 0: the tick (every sample period); event 1: the DSP interrupt (sporadic)."""
    cycle, unit = event_cycle(sample_period_s)
    return (EventChannel("tick", cycle, unit, 0), EventChannel("dsp_interrupt", 0, 0, 1))


def controller_a2l(
    sample_period_s: float = 0.005, udp_port: int = 0, tcp_port: int = 0, host: str = "127.0.0.1", can_ids: tuple[int, int] | None = None
) -> str:
    """The controller's A2L."""
    return a2l_text(
        controller_layout(),
        A2L_MODULE,
        "RALF controller (emulated MVME CPU): measurements and calibration",
        xcp_events(sample_period_s),
        udp_port=udp_port,
        tcp_port=tcp_port,
        host=host,
        can_ids=can_ids,
    )


def port_number(text: str) -> int:
    port = int(text)
    if not 0 <= port <= 65535:
        raise ValueError(text)
    return port


def table_markdown() -> str:
    """The table as docs/xcp.md shows it (``python -m controller.xcp_table --markdown``; a test checks the page)."""
    lines = [
        "| name | kind | address | ASAM type | unit | limits (physical) | conversion | from |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    sources = {e.variable.name: e.source for e in XCP_TABLE}
    for v in controller_layout().variables:
        conversion = "identity" if (v.factor, v.offset) == (1.0, 0.0) else f"{v.factor:.9g} × raw + {v.offset:g}"
        calibration = "input monitors" if v.name.startswith("input_") else "control law"
        source = calibration if v.kind == "calibration" else ("service" if sources[v.name] in SERVICE_SOURCES else "run record")
        lines.append(
            f"| `{v.name}` | {v.kind} | 0x{v.address:X} | {v.datatype} | {v.unit or '-'} | {v.lower:.10g} .. {v.upper:.10g} | {conversion} | {source} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m controller.xcp_table [-o FILE] [--udp-port N] [--tcp-port N]``: write the A2L."""
    parser = argparse.ArgumentParser(prog="python -m controller.xcp_table", description="Write the controller's A2L (docs/xcp.md).")
    parser.add_argument("-o", "--output", help="the A2L file (default: standard output)")
    parser.add_argument("--sample-rate-hz", type=float, default=200.0)
    parser.add_argument("--udp-port", type=port_number, default=0, metavar="PORT", help="the XCP_ON_UDP_IP port (0: none)")
    parser.add_argument("--tcp-port", type=port_number, default=0, metavar="PORT", help="the XCP_ON_TCP_IP port (0: none)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--markdown", action="store_true", help="print the table as docs/xcp.md shows it instead")
    args = parser.parse_args(argv)
    if args.markdown:
        print(table_markdown())
        return 0
    if not args.sample_rate_hz > 0:
        parser.error("--sample-rate-hz must be positive")
    text = controller_a2l(1.0 / args.sample_rate_hz, args.udp_port, args.tcp_port, args.host)
    if args.output:
        try:
            Path(args.output).write_text(text, encoding="utf-8")
        except OSError as exc:
            print(f"python -m controller.xcp_table: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
            return 1
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
