"""The bus of :func:`service_kit.can_wire.arbitration.simulate`, one frame at a time.

:func:`~service_kit.can_wire.arbitration.simulate` needs every frame up
front; a co-simulation learns its frames as it goes (a node answers a frame
when it arrives). :class:`OnlineBus` takes frames as they are queued and
decides the next transmission when asked, by the same rule without errors:
the bus starts at ``max(bus free, earliest queued frame)``; of the frames
queued by then the lowest ``(arbitration_key, queued_ns, submission order)``
wins (each node's own best first, then the best of those: the same frame);
it occupies the bus for its exact bits, intermission included.

The caller's promise: before :meth:`OnlineBus.commit` every frame that
will ever be queued at or before :meth:`OnlineBus.next_start` has been
submitted (a node's answer to a frame is queued when that frame's last bit
is gone, which is before the bus is free again). Given all frames in
submission order equal to :func:`simulate`'s input order, the transmissions
are :func:`simulate`'s (tested), the submission index standing for the input
index.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from service_kit.can_wire.arbitration import INTERMISSION_BITS, Transmission
from service_kit.can_wire.bits import FrameBits
from service_kit.can_wire.timing import bit_time_ns


@dataclass(frozen=True)
class _Queued:
    key: tuple[int, ...]
    queued_ns: int
    seq: int
    node: str
    frame: FrameBits
    tag: Any


@dataclass(frozen=True)
class Sent:
    """One transmission and what its sender attached to the frame."""

    transmission: Transmission
    frame: FrameBits
    tag: Any


@dataclass
class OnlineBus:
    """An error-free CAN bus fed frame by frame (module docstring)."""

    bitrate: int
    bus_free_ns: int = 0
    _pending: list[_Queued] = field(default_factory=list)
    _seq: int = 0

    def __post_init__(self) -> None:
        self._bit = bit_time_ns(self.bitrate)

    def submit(self, node: str, queued_ns: int, frame: FrameBits, tag: Any = None) -> int:
        """Queue ``frame`` of ``node`` at ``queued_ns``; returns its submission index."""
        seq = self._seq
        self._seq += 1
        self._pending.append(_Queued(frame.arbitration_key, queued_ns, seq, node, frame, tag))
        return seq

    @property
    def pending(self) -> int:
        return len(self._pending)

    def next_start(self) -> int | None:
        """When the next transmission starts, from the frames known (None: none pending)."""
        if not self._pending:
            return None
        return max(self.bus_free_ns, min(q.queued_ns for q in self._pending))

    def commit(self) -> Sent:
        """Puts the next frame on the bus (the caller's promise: module docstring)."""
        start = self.next_start()
        if start is None:
            raise ValueError("no frame pending")
        winner = min((q for q in self._pending if q.queued_ns <= start), key=lambda q: (q.key, q.queued_ns, q.seq))
        self._pending.remove(winner)
        end = start + winner.frame.n_bits * self._bit
        self.bus_free_ns = end
        tx = Transmission(
            index=winner.seq,
            node=winner.node,
            arbitration_id=winner.frame.arbitration_id,
            queued_ns=winner.queued_ns,
            start_ns=start,
            last_bit_ns=end - INTERMISSION_BITS * self._bit,
            end_ns=end,
            attempts=1,
        )
        return Sent(tx, winner.frame, winner.tag)
