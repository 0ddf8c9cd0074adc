"""Expedited SDO transfers to the plant node (CiA 301), as the controller's
link configures it at start: a request out, the node's answer to that
object awaited (an answer for another object, e.g. to someone else's
request, is skipped); an abort or no answer is a
:class:`controller.plant_errors.PlantFault` naming the object."""

from __future__ import annotations

from collections.abc import Callable

from controller.plant_errors import PlantFault


def download_request(index: int, subindex: int, value: int, size: int) -> bytes:
    """An expedited download (write) of a ``size``-byte unsigned value."""
    command = 0x23 | ((4 - size) << 2)
    return bytes([command, index & 0xFF, index >> 8, subindex]) + int(value).to_bytes(size, "little").ljust(4, b"\x00")


class SdoClient:
    """SDO requests through ``send``; answers put in :attr:`response` by the link's receive path."""

    def __init__(self, send: Callable[[bytes], None], poll: Callable[[float], None], now: Callable[[], float]) -> None:
        self._send, self._poll, self._now = send, poll, now
        self.response: bytes | None = None
        """The node's latest SDO answer (set by the link as frames arrive)."""

    def _transfer(self, request: bytes, what: str, timeout: float) -> bytes:
        """Send an expedited SDO request and return the node's answer to it."""
        self.response = None
        self._send(request)
        deadline = self._now() + timeout
        while True:
            reply = self.response
            if reply is not None and reply[1:4] == request[1:4]:
                break
            self.response = None
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"no SDO answer from the plant node {what}")
            self._poll(min(remaining, 0.05))
        if reply[0] == 0x80:
            code = int.from_bytes(reply[4:8], "little")
            raise PlantFault(f"the plant node refused {what} (SDO abort 0x{code:08X})")
        return reply

    def write(self, index: int, subindex: int, value: int, size: int = 4, timeout: float = 1.0) -> None:
        """Expedited SDO download of a ``size``-byte unsigned value."""
        reply = self._transfer(download_request(index, subindex, value, size), f"writing 0x{index:04X}:{subindex} = {value}", timeout)
        if reply[0] != 0x60:
            raise PlantFault(f"unexpected SDO answer {reply.hex()} writing 0x{index:04X}:{subindex}")

    def read(self, index: int, subindex: int, timeout: float = 1.0) -> int:
        """Expedited SDO upload of an unsigned value (up to 4 bytes)."""
        what = f"reading 0x{index:04X}:{subindex}"
        reply = self._transfer(bytes([0x40, index & 0xFF, index >> 8, subindex, 0, 0, 0, 0]), what, timeout)
        if reply[0] & 0xE2 != 0x42:
            raise PlantFault(f"unexpected SDO answer {reply.hex()} {what}")
        n = 4 - ((reply[0] >> 2) & 0x3) if reply[0] & 0x01 else 4
        return int.from_bytes(reply[4 : 4 + n], "little")
