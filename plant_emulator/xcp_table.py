"""The one table of what the plant serves over XCP (docs/xcp.md, "The plant's slave").

Same :class:`~service_kit.xcp.memory.Variable` type as the controller's
table (:mod:`controller.xcp_table`): the slave's memory map
(:func:`plant_layout`) and the A2L (:func:`plant_a2l`; ``python -m
plant_emulator.xcp_table``) are both built from :data:`XCP_TABLE`.

Measurements are the plant's state after each SYNC's step, read from the
model's :meth:`~plant_emulator.plant_model.PlantModel.truth_summary` (the
ground truth the test port publishes: joint angles, link deflections, tip,
the first two modal frequencies and damping ratios, payload), the valve
voltages the model integrates with and the A/D codes of that SYNC's TPDO1.
The one calibration parameter is the payload (attached or released at the
next SYNC, as a scenario's payload command): the only plant parameter that
changes at run time without a restart of the model.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from service_kit.xcp.a2l import a2l_text, event_cycle
from service_kit.xcp.memory import MemoryLayout, Variable
from service_kit.xcp.slave import EventChannel

__all__ = ["A2L_MODULE", "XCP_TABLE", "PlantXcpEntry", "plant_a2l", "plant_layout", "table_markdown", "xcp_events"]

A2L_MODULE: Final = "RALF_PLANT"
BASE_ADDRESS: Final = 0x2000


@dataclass(frozen=True)
class PlantXcpEntry:
    variable: Variable
    source: str
    """``truth`` (the model's truth summary), ``valves``, ``adc`` (the SYNC's A/D codes), ``counters``, or the parameter."""


def _m(name: str, unit: str, lower: float, upper: float, description: str, source: str, datatype: str = "FLOAT64_IEEE") -> PlantXcpEntry:
    return PlantXcpEntry(Variable(name, datatype, unit, lower, upper, "measurement", 1.0, 0.0, description), source)


_ANGLE = 3.2
_INCHES = 100.0
_CODE = 1 << 20
XCP_TABLE: Final[tuple[PlantXcpEntry, ...]] = (
    _m("syncs", "", 0, 4294967295, "SYNCs the plant has taken", "counters", "ULONG"),
    _m("t_s", "s", 0, 1e7, "the model's simulated time after this SYNC's step", "truth"),
    _m("theta1_rad", "rad", -_ANGLE, _ANGLE, "joint 1 angle", "truth"),
    _m("theta2_rad", "rad", -_ANGLE, _ANGLE, "joint 2 angle", "truth"),
    _m("defl1_in", "in", -_INCHES, _INCHES, "link 1 tip deflection", "truth"),
    _m("defl2_in", "in", -_INCHES, _INCHES, "link 2 tip deflection", "truth"),
    _m("tip_x_in", "in", -1000, 1000, "arm tip, x", "truth"),
    _m("tip_y_in", "in", -1000, 1000, "arm tip, y", "truth"),
    _m("f1_hz", "Hz", 0, 1000, "first modal frequency at this pose (NaN: the model has none)", "truth"),
    _m("f2_hz", "Hz", 0, 1000, "second modal frequency (NaN: none)", "truth"),
    _m("zeta1", "", 0, 1, "first modal damping ratio (NaN: none)", "truth"),
    _m("zeta2", "", 0, 1, "second modal damping ratio (NaN: none)", "truth"),
    _m("u1_applied_v", "V", -10, 10, "valve 1 voltage the model integrates with (NaN: the model does not say)", "valves"),
    _m("u2_applied_v", "V", -10, 10, "valve 2 voltage the model integrates with (NaN: the model does not say)", "valves"),
    _m("ai1_code", "LSB", -_CODE, _CODE, "A/D code, channel 1, this SYNC's TPDO1 (at the converter's resolution)", "adc", "SLONG"),
    _m("ai2_code", "LSB", -_CODE, _CODE, "A/D code, channel 2", "adc", "SLONG"),
    _m("ai3_code", "LSB", -_CODE, _CODE, "A/D code, channel 3", "adc", "SLONG"),
    _m("ai4_code", "LSB", -_CODE, _CODE, "A/D code, channel 4", "adc", "SLONG"),
    _m("hard_stops", "", 0, 4294967295, "arrivals at a hard stop since the start", "counters", "ULONG"),
    _m("payload_attached", "", 0, 1, "1: the payload is at the tip", "truth", "UBYTE"),
    PlantXcpEntry(Variable("payload", "UBYTE", "", 0, 1, "calibration", 1.0, 0.0, "1: attach the payload at the next SYNC, 0: release it"), "payload"),
)


def plant_layout() -> MemoryLayout:
    return MemoryLayout([e.variable for e in XCP_TABLE], BASE_ADDRESS)


def xcp_events(sample_period_s: float) -> tuple[EventChannel, ...]:
    """Event 0: the plant's sample (each SYNC it answers)."""
    cycle, unit = event_cycle(sample_period_s)
    return (EventChannel("sync", cycle, unit, 0),)


def plant_a2l(sample_period_s: float = 0.005, udp_port: int = 0, tcp_port: int = 0, host: str = "127.0.0.1", can_ids: tuple[int, int] | None = None) -> str:
    return a2l_text(
        plant_layout(),
        A2L_MODULE,
        "RALF plant emulator: the arm's state and the payload",
        xcp_events(sample_period_s),
        udp_port=udp_port,
        tcp_port=tcp_port,
        host=host,
        can_ids=can_ids,
    )


def table_markdown() -> str:
    """The table as docs/xcp.md shows it (``python -m plant_emulator.xcp_table --markdown``)."""
    lines = ["| name | kind | address | ASAM type | unit | limits (physical) | meaning |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for v in plant_layout().variables:
        lines.append(f"| `{v.name}` | {v.kind} | 0x{v.address:X} | {v.datatype} | {v.unit or '-'} | {v.lower:.10g} .. {v.upper:.10g} | {v.description} |")
    return "\n".join(lines)


def port_number(text: str) -> int:
    port = int(text)
    if not 0 <= port <= 65535:
        raise ValueError(text)
    return port


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m plant_emulator.xcp_table [-o FILE] [--udp-port N] [--tcp-port N] [--markdown]``."""
    parser = argparse.ArgumentParser(prog="python -m plant_emulator.xcp_table", description="Write the plant's A2L (docs/xcp.md).")
    parser.add_argument("-o", "--output", help="the A2L file (default: standard output)")
    parser.add_argument("--sample-rate-hz", type=float, default=200.0)
    parser.add_argument("--udp-port", type=port_number, default=0, metavar="PORT")
    parser.add_argument("--tcp-port", type=port_number, default=0, metavar="PORT")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--markdown", action="store_true", help="print the table as docs/xcp.md shows it instead")
    args = parser.parse_args(argv)
    if args.markdown:
        print(table_markdown())
        return 0
    if not args.sample_rate_hz > 0:
        parser.error("--sample-rate-hz must be positive")
    text = plant_a2l(1.0 / args.sample_rate_hz, args.udp_port, args.tcp_port, args.host)
    if args.output:
        try:
            Path(args.output).write_text(text, encoding="utf-8")
        except OSError as exc:
            print(f"python -m plant_emulator.xcp_table: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
            return 1
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
