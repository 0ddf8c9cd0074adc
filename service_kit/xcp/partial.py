"""Writes that arrive in parts: a calibration parameter wider than one command.

On CAN a command is at most 8 bytes (MAX_CTO), so a DOWNLOAD carries at most
6 data bytes and a FLOAT64 parameter takes two writes. :class:`PartialWrites`
holds a parameter's first bytes until its last arrive (docs/xcp.md, "XCP on
CAN"):

* a write that starts at a calibration parameter's first byte and ends
  inside it (or ends inside the parameter after whole ones) is held, not
  applied: the map keeps the old value, read-backs show it;
* the next write at the address right after the held bytes continues it;
  once the parameter is complete it is checked against its limits as a
  whole (:meth:`MemoryLayout.check_write`: ERR_OUT_OF_RANGE,
  ERR_WRITE_PROTECTED, ...) and applied like any other write;
* a write at any other address drops the held bytes (counted as
  ``partial_writes_dropped``) and is taken on its own; so does the end of the
  session (DISCONNECT, a lost connection);
* a write that starts inside a parameter with nothing held for it is
  refused ``ERR_ACCESS_DENIED``, as on Ethernet.

Pure: no I/O, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass

from service_kit.xcp.memory import MemoryLayout, Variable, WriteRefused
from service_kit.xcp.packets import Err

__all__ = ["PartialWrites", "Split"]


@dataclass(frozen=True)
class Split:
    """A write cut into what can be checked now and what must wait."""

    address: int
    """Where :attr:`whole` starts."""
    whole: bytes
    """Whole parameters, to check and apply now (may be empty)."""
    held: bytes
    """A parameter's first bytes, held after :attr:`whole` (may be empty)."""


class PartialWrites:
    """The bytes held for one parameter between two writes."""

    def __init__(self, layout: MemoryLayout) -> None:
        self.layout = layout
        self.variable: Variable | None = None
        self.held = b""
        self.dropped = 0
        """Held parts dropped: a write elsewhere, or the session's end, before the parameter was complete."""

    def drop(self) -> None:
        if self.variable is not None:
            self.dropped += 1
        self.variable, self.held = None, b""

    def split(self, address: int, data: bytes) -> Split:
        """Join ``data`` at ``address`` to the held bytes it continues; return what is
        whole and what is held. Raises :class:`WriteRefused` for a tail that cannot be a
        parameter's first bytes (the held part is dropped first, counted)."""
        v = self.variable
        if v is not None and address == v.address + len(self.held):
            address, data = v.address, self.held + data
            self.variable, self.held = None, b""  # continued, not dropped
        self.drop()
        end = address + len(data)
        last = next((x for x in self.layout.variables if x.address < end < x.address + x.size), None)
        if last is None:  # ends on a boundary (or outside every variable): nothing to hold
            return Split(address, data, b"")
        if last.kind != "calibration":
            raise WriteRefused(Err.ERR_WRITE_PROTECTED, f"{last.name} is a measurement")
        if last.address < address:  # starts inside the parameter it ends in: no first bytes
            raise WriteRefused(Err.ERR_ACCESS_DENIED, f"write covers {last.name} only in part")
        cut = last.address - address
        whole, held = data[:cut], data[cut:]
        if whole:
            self.layout.check_write(address, whole)  # refused whole parameters: nothing held
        self.variable, self.held = last, held
        return Split(address, whole, held)
