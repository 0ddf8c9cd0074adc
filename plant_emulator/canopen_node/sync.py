"""SYNC consumer (CiA 301): the SYNC counter, its gaps, and a second SYNC producer told from the counter
(docs/canopen.md, "Behaviour on the bus": SYNC)."""

from __future__ import annotations

from typing import Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode, Value
from plant_emulator.canopen_node.transmit import NodeLog, log
from protocol.can_map import SYNC_COUNTER_OVERFLOW, EmcyCode

CONFLICT_CLEAR_PERIODS: Final[int] = 10
"""Clean SYNC periods after which a SYNC or RPDO conflict EMCY is reset."""
_SYNC_CONFLICT: Final = int(EmcyCode.SYNC_CONFLICT)


class SyncConsumer:
    """Checks each SYNC's counter; ``last_counter`` is the last one (0: without counter, None: none yet)."""

    def __init__(self, od: ObjectDictionary, emcy: EmcyProducer, counters: NodeCounters, log: NodeLog) -> None:
        self.emcy = emcy
        self.counters = counters
        self.log = log
        self.last_counter: int | None = None
        self._clean = 0
        od.on_write(0x1019, 0, self._write_overflow)

    def receive(self, cob_id: int, data: bytes, overflow: int) -> tuple[int, int] | None:
        """(counter, SYNCs the counter says were lost) of a SYNC frame, None when malformed (counted)."""
        missed = 0
        conflict = ""
        if not data:
            counter = 0  # SYNC without counter: accepted whatever 0x1019 says (CiA 301 allows both)
            if self.last_counter:
                conflict = "a SYNC without counter among SYNCs with counter"
        else:
            if overflow == 0:
                self.log.malformed("sync_dlc", cob_id, data, "0x1019 = 0: SYNC without counter expected (DLC 0)")
                return None
            if len(data) != 1:
                self.log.malformed("sync_dlc", cob_id, data, f"SYNC with counter takes 1 byte, got {len(data)}")
                return None
            counter = data[0]
            if not 1 <= counter <= overflow:
                self.log.malformed("sync_counter", cob_id, data, f"SYNC counter {counter} outside 1..{overflow}")
                return None
            prev = self.last_counter
            if not (
                prev and counter == prev % SYNC_COUNTER_OVERFLOW + 1 and overflow >= 2
            ):  # the next counter (every tick's case): _follow finds nothing lost, no conflict
                conflict, missed = self._follow(counter, overflow)
        self.last_counter = counter
        self.counters.sync_received += 1
        if conflict or _SYNC_CONFLICT in self.emcy.faults:
            self._check_conflict(conflict)
        return counter, missed

    def _follow(self, counter: int, overflow: int) -> tuple[str, int]:
        """(what one producer cannot send, or "", SYNCs lost) from the previous counter to ``counter``."""
        prev = self.last_counter
        if prev == 0:
            return "a SYNC with counter among SYNCs without counter", 0
        if prev is None:
            return "", 0
        if counter == prev:
            self.counters.sync_repeats += 1
            return f"SYNC counter {counter} repeated", 0
        gap = (counter - prev - 1) % SYNC_COUNTER_OVERFLOW  # sync_gap(prev, counter), counter != prev: inline
        if gap >= overflow // 2:
            return f"SYNC counter went back from {prev} to {counter}", 0
        if gap:
            self.counters.sync_gaps += 1
            self.counters.syncs_missed += gap
            log.debug("node %d: SYNC gap %d -> %d (%d missed)", self.log.node_id, prev, counter, gap)
        return "", gap

    def _check_conflict(self, conflict: str) -> None:
        """EMCY SYNC_CONFLICT until CONFLICT_CLEAR_PERIODS clean SYNCs."""
        if conflict:
            self.counters.sync_conflicts += 1
            self._clean = 0
            if _SYNC_CONFLICT not in self.emcy.faults:
                log.warning("node %d: %s: a second SYNC producer on the bus?", self.log.node_id, conflict)
            self.emcy.set_fault(_SYNC_CONFLICT, True, bytes([self.last_counter or 0]))
        elif _SYNC_CONFLICT in self.emcy.faults:
            self._clean += 1
            if self._clean >= CONFLICT_CLEAR_PERIODS:
                self.emcy.set_fault(_SYNC_CONFLICT, False)

    def _write_overflow(self, value: Value) -> None:
        if value not in (0, SYNC_COUNTER_OVERFLOW):
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, f"0x1019 must be 0 or {SYNC_COUNTER_OVERFLOW}")
        self.last_counter = None
