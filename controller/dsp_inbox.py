"""The DSP's messages at the controller's edge: decoded, paired and queued.

The port's sink runs in the port's thread (zenoh's, for the zenoh port):
each message is size-capped, decoded and checked there, then queued in a
bounded inbox (service_kit/inbox.py) that the loop drains between ticks.
The first block flag after the run-start reset pairs the controller with
its DSP board (the session id the flag carries as its attachment); flags
and interrupts of any other board, and interrupts of batches never sent,
are refused before they can take a place in the inbox (a flood must not
crowd out the real one).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from protocol.command_fields import COMMAND_KEYS, refused_fields
from protocol.messages import BlockFlag, ConfigChange, Interrupt, decode
from service_kit.inbox import LIMITS, MAX_BYTES, REFUSED, Inbox, Item

log = logging.getLogger(__name__)

INBOX_CAPACITY = 256
"""Messages the inbox holds between two drains."""


class DspInbox:
    """Decodes and pairs at the edge; :meth:`drain` hands the loop what came."""

    def __init__(self, was_sent: Callable[[int], bool], synchronous: bool) -> None:
        self.events = Inbox("controller", capacity=INBOX_CAPACITY, limits=LIMITS)
        self._was_sent = was_sent
        """Whether a batch of that number went out (and is not answered yet)."""
        self._synchronous = synchronous
        self.waiting = False
        """The port's sink queued something since the loop last drained the inbox."""
        self.reset_sent = False
        """The run-start reset went out: the next flag pairs the controller with its board."""
        self.paired_board: bytes | None = None
        """The DSP board (session id) this controller takes flags and interrupts from."""
        self._decoders: dict[str, Callable[..., Any]] = {
            "flag": self._decode_flag,
            "interrupt": self._decode_interrupt,
            "command": lambda b: self._decode_command("command", b),
            "test_command": lambda b: self._decode_command("test_command", b),
        }

    def on_port_event(self, kind: str, payload: Any, arrival: float, attachment: Any = None) -> None:
        """The port's sink, called in its thread: size-capped, decoded and checked here, then queued."""
        if kind == "alive":
            self.events.put("alive", payload == b"1", arrival)
            self.waiting = True
            return
        decoder = self._decoders.get(kind)
        if decoder is None:
            return
        if kind in ("flag", "interrupt"):
            self.events.offer(kind, payload, decoder, MAX_BYTES[kind], attachment=attachment, use_attachment=True, arrival=arrival)
        else:
            self.events.offer(kind, payload, decoder, MAX_BYTES[kind], arrival=arrival)
        self.waiting = True  # after the item: the loop clears this before it drains

    def _decode_flag(self, payload: bytes, board: bytes | None) -> BlockFlag | object | None:
        """The first flag after the run-start reset pairs the controller with
        its board; flags of any other board are refused."""
        flag = decode(BlockFlag, payload)
        if not self.reset_sent:
            return None  # the board announcing itself before the run-start reset: expected, nothing to pair with yet (counted as handled)
        if self.paired_board is None and board:
            self.paired_board = board
            log.info("paired with DSP board %s", board.decode(errors="replace"))
        return flag if board is not None and board == self.paired_board else REFUSED

    def _decode_command(self, kind: str, payload: bytes) -> ConfigChange | object:
        """A command that sets a field its key does not take (protocol/command_fields.py) is refused whole."""
        change = decode(ConfigChange, payload)
        refused = refused_fields(kind, change)
        if refused:
            self.events.log.warning(f"refused:{kind}", "refused a %s setting %s: not taken on %s", kind, ", ".join(sorted(refused)), COMMAND_KEYS[kind])
            return REFUSED
        return change

    def _decode_interrupt(self, payload: bytes, board: bytes | None) -> Interrupt | object:
        """An interrupt from another board than the paired one, or for no batch we sent, is refused."""
        irq = decode(Interrupt, payload)
        if board is None or board != self.paired_board:
            return REFUSED
        return irq if self._was_sent(irq.batch_seq) else REFUSED

    def drain(self, take: Callable[[str, Any, float], None]) -> None:
        """Hand each queued message to ``take`` (at most one inbox's capacity per call)."""
        # Nothing queued on almost every tick: the flag (set by the port's sink after
        # each item, cleared here before draining) spares asking the queue's lock.
        if self.waiting:
            self.waiting = False
            events = self.events
            if len(events):
                for kind, message, arrival in events.drain(limit=events.capacity):
                    take(kind, message, arrival)
                if len(events):
                    self.waiting = True  # more than one drain's limit: the next tick takes the rest

    def next_event(self, timeout: float) -> Item | None:
        """The next message (decoded), waiting up to ``timeout`` wall seconds
        (not at all when the port answers synchronously)."""
        if self._synchronous:
            return self.events.get_nowait()
        return self.events.get(timeout=timeout)
