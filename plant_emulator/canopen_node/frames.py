"""The frames the node produces, before they become python-can messages.

A :class:`Frame` is a standard (11-bit) CAN data frame: COB-ID, payload
bytes, the time it was produced. It reads like a :class:`can.Message` for
what a CANopen master looks at (``arbitration_id``, ``data``, ``dlc``,
``timestamp`` and the ``is_*`` flags, all false), so a receiver in the
same process (the co-simulation's direct wire) takes it as it is, while
the bus runner turns it into a message with :meth:`Frame.to_message`.
The payload is whatever the codecs of :mod:`protocol.can_map` packed."""

from __future__ import annotations

import can


class Frame:
    """One standard CAN data frame produced by the node."""

    __slots__ = ("arbitration_id", "data", "timestamp")

    is_extended_id = False
    is_remote_frame = False
    is_error_frame = False
    is_fd = False

    def __init__(self, arbitration_id: int, data: bytes, timestamp: float) -> None:
        self.arbitration_id = arbitration_id
        self.data = data
        self.timestamp = timestamp

    @property
    def dlc(self) -> int:
        return len(self.data)

    def to_message(self) -> can.Message:
        """The same frame as a python-can message (for a bus)."""
        return can.Message(arbitration_id=self.arbitration_id, data=self.data, is_extended_id=False, timestamp=self.timestamp)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Frame):
            return NotImplemented
        return (self.arbitration_id, self.data, self.timestamp) == (other.arbitration_id, other.data, other.timestamp)

    __hash__ = None  # type: ignore[assignment]  # mutable, like can.Message

    def __repr__(self) -> str:
        return f"Frame(arbitration_id=0x{self.arbitration_id:03X}, data={self.data.hex(' ')!r}, timestamp={self.timestamp!r})"
