"""Fault confinement of one CAN node: its error counters and error state.

The rules are those of the CAN 2.0 specification part B, section 8
("Fault confinement", rules 1-12), carried unchanged into ISO 11898-1's
fault confinement clause:

1. A receiver that detects an error adds 1 to its receive error counter
   (REC), unless the error was a bit error while sending an active error
   flag or an overload flag.
2. A receiver that sees a dominant bit as the first bit after sending an
   error flag adds 8 to its REC.
3. A transmitter that sends an error flag adds 8 to its transmit error
   counter (TEC). Exception 1: an error-passive transmitter that detects an
   ACK error (no dominant ACK) and sees no dominant bit while sending its
   passive error flag leaves its TEC alone. Exception 2: a stuff error
   during arbitration on a recessive stuff bit that was monitored dominant.
4. A transmitter that sees a bit error while sending an active error flag
   or an overload flag adds 8 to its TEC.
5. Likewise a receiver, to its REC.
6. After the 14th consecutive dominant bit following an active error flag
   or overload flag, or the 8th after a passive error flag, and after each
   further 8 consecutive dominant bits, every transmitter adds 8 to its TEC
   and every receiver 8 to its REC.
7. After a successful transmission (ACK received and no error until EOF
   ends) the TEC goes down by 1 unless it is 0.
8. After a successful reception (no error up to the ACK slot and the ACK bit
   sent) the REC goes down by 1 if it was 1..127; above 127 it is set to a
   value between 119 and 127 (:attr:`FaultConfinement.rec_after_passive_success`).
9. A node is error passive when its TEC or REC is 128 or more.
10. A node is bus off when its TEC is 256 or more.
11. An error-passive node becomes error active again when both counters are
    127 or less.
12. A bus-off node becomes error active, both counters 0, after it has
    monitored 128 occurrences of 11 consecutive recessive bits on the bus.

:class:`FaultConfinement` applies rules 1-3 and 7-12 through one method per
event; the bus model (:mod:`service_kit.can_wire.arbitration`) calls them.
Rules 3 exception 2 and 4-6 (errors inside error flags, dominant bits after
them) need a bit-level model of the error frames of every node, which the
bus model does not have: not modelled.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

PASSIVE_LIMIT = 128
"""Rule 9: TEC or REC at or above it is error passive."""
BUS_OFF_LIMIT = 256
"""Rule 10: TEC at or above it is bus off."""
RECOVERY_SEQUENCES = 128
"""Rule 12: occurrences of :data:`RECOVERY_RUN` recessive bits a bus-off node waits for."""
RECOVERY_RUN = 11
ERROR_FLAG_BITS = 6
"""An active error flag: 6 dominant bits; a passive one: 6 recessive bits."""
ERROR_ECHO_MAX = 6
"""Other nodes' flags, started up to 6 bits later, superpose: 0..6 more dominant bits."""
ERROR_DELIMITER_BITS = 8
SUSPEND_BITS = 8
"""An error-passive transmitter waits 8 more bits after the intermission before it may start again (suspend transmission)."""


class ErrorState(Enum):
    ACTIVE = "error-active"
    PASSIVE = "error-passive"
    BUS_OFF = "bus-off"


@dataclass
class FaultConfinement:
    """One node's counters (module docstring for the rules)."""

    tec: int = 0
    rec: int = 0
    rec_after_passive_success: int = 127
    """Rule 8: the value 119..127 an REC above 127 takes after a successful reception."""
    bus_off: bool = False
    recovery_sequences: int = 0
    """Rule 12: occurrences of 11 recessive bits seen since going bus off."""
    _recessive_run: int = field(default=0, repr=False)

    def __post_init__(self) -> None:
        if not 119 <= self.rec_after_passive_success <= 127:
            raise ValueError(f"rec_after_passive_success must be 119..127, got {self.rec_after_passive_success}")

    @property
    def state(self) -> ErrorState:
        """Rules 9-11."""
        if self.bus_off:
            return ErrorState.BUS_OFF
        if self.tec >= PASSIVE_LIMIT or self.rec >= PASSIVE_LIMIT:
            return ErrorState.PASSIVE
        return ErrorState.ACTIVE

    def transmit_error(self, *, ack_error: bool = False, dominant_during_passive_flag: bool = False) -> None:
        """Rule 3 (and exception 1), then rule 10."""
        if self.bus_off:
            return
        if ack_error and self.state is ErrorState.PASSIVE and not dominant_during_passive_flag:
            return
        self.tec += 8
        if self.tec >= BUS_OFF_LIMIT:
            self.bus_off = True
            self.recovery_sequences = 0
            self._recessive_run = 0

    def transmit_success(self) -> None:
        """Rule 7."""
        if not self.bus_off and self.tec > 0:
            self.tec -= 1

    def receive_error(self, *, dominant_after_flag: bool = False) -> None:
        """Rule 1 (+1), or rule 2 (+8) when the first bit after the node's own error flag was dominant."""
        if not self.bus_off:
            self.rec += 8 if dominant_after_flag else 1

    def receive_success(self) -> None:
        """Rule 8."""
        if self.bus_off:
            return
        if 1 <= self.rec <= 127:
            self.rec -= 1
        elif self.rec > 127:
            self.rec = self.rec_after_passive_success

    def monitor(self, bits: Sequence[int]) -> int | None:
        """Rule 12 while bus off: the bits the node sees on the bus, in order.
        Returns the number of bits after which the node recovered (error
        active, counters 0), or None if it is still bus off (or was not)."""
        if not self.bus_off:
            return None
        for i, bit in enumerate(bits):
            if bit:
                self._recessive_run += 1
                if self._recessive_run == RECOVERY_RUN:
                    self._recessive_run = 0
                    self.recovery_sequences += 1
                    if self.recovery_sequences >= RECOVERY_SEQUENCES:
                        self._recover()
                        return i + 1
            else:
                self._recessive_run = 0
        return None

    def monitor_idle(self, n_bits: int) -> int | None:
        """:meth:`monitor` of ``n_bits`` recessive bits (an idle bus), without building them."""
        if not self.bus_off or n_bits <= 0:
            return None
        needed = (RECOVERY_SEQUENCES - self.recovery_sequences) * RECOVERY_RUN - self._recessive_run
        if n_bits >= needed:
            self._recover()
            return needed
        total = self._recessive_run + n_bits
        self.recovery_sequences += total // RECOVERY_RUN
        self._recessive_run = total % RECOVERY_RUN
        return None

    def idle_bits_to_recover(self) -> int | None:
        """Bits of idle bus this bus-off node still needs to recover (None if it is not bus off)."""
        if not self.bus_off:
            return None
        return (RECOVERY_SEQUENCES - self.recovery_sequences) * RECOVERY_RUN - self._recessive_run

    def _recover(self) -> None:
        self.bus_off = False
        self.tec = 0
        self.rec = 0
        self.recovery_sequences = 0
        self._recessive_run = 0
