"""The EMCY producer (CiA 301): active faults, the error register 0x1001 and the error history 0x1003
(docs/canopen.md, "Behaviour on the bus": EMCY)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode, Value
from plant_emulator.canopen_node.transmit import Outbox
from protocol.can_map import EmcyCode, encode_emcy

OD_ERROR_REGISTER: Final[int] = 0x1001
OD_ERROR_HISTORY: Final[int] = 0x1003
HISTORY_DEPTH: Final[int] = 8
"""Entries of 0x1003 (sub 1 the newest)."""


def error_register_bits(code: int) -> int:
    """CiA 301 error register (0x1001) bits for an active EMCY code, besides
    the generic bit 0: current (bit 1), voltage (2), temperature (3),
    communication (4), manufacturer specific (7)."""
    if code >> 8 == 0xFF:
        return 0x80
    return {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}.get(code >> 12, 0x00)


class EmcyProducer:
    """Raises and clears faults; ``may_send()`` says whether the NMT state lets EMCYs out."""

    def __init__(self, od: ObjectDictionary, outbox: Outbox, counters: NodeCounters, cob_id: int, may_send: Callable[[], bool]) -> None:
        self.od = od
        self.outbox = outbox
        self.counters = counters
        self.cob_id = cob_id
        self.may_send = may_send
        self.faults: dict[int, bytes] = {}
        """Active fault codes and the vendor bytes they were raised with."""
        self.history: list[int] = []
        od.getter(OD_ERROR_REGISTER, 0, lambda: self.error_register)
        od.on_write(OD_ERROR_HISTORY, 0, self._write_history)

    @property
    def error_register(self) -> int:
        reg = 0
        for code in self.faults:
            reg |= 0x01 | error_register_bits(code)
        return reg

    def set_fault(self, code: int, active: bool, vendor: bytes = b"") -> None:
        """EMCY on entry, the reset EMCY on exit; nothing when the fault is already so."""
        code = int(code)
        if active:
            if code in self.faults:
                return
            self.faults[code] = vendor
            self.record(code, vendor)
            self.send(code, vendor)
        else:
            if code not in self.faults:
                return
            del self.faults[code]
            self.send(EmcyCode.NO_ERROR, code.to_bytes(2, "little"))

    def record(self, code: int, vendor: bytes) -> None:
        """Push ``code`` (its first two vendor bytes as additional information) onto 0x1003."""
        info = int.from_bytes(vendor[:2].ljust(2, b"\x00"), "little")
        self.history.insert(0, code | (info << 16))
        del self.history[HISTORY_DEPTH:]
        for sub in range(1, HISTORY_DEPTH + 1):
            self.od.set(OD_ERROR_HISTORY, sub, self.history[sub - 1] if sub <= len(self.history) else 0)
        self.od.set(OD_ERROR_HISTORY, 0, len(self.history))

    def send(self, code: int, vendor: bytes) -> None:
        if not self.may_send():
            self.counters.emcy_suppressed += 1
            return
        self.outbox.emit(self.cob_id, encode_emcy(code, self.error_register, vendor[:5]), "emcy")

    def reset(self) -> None:
        """NMT reset: no faults, an empty history (the dictionary is restored by the caller)."""
        self.faults.clear()
        self.history.clear()

    def _write_history(self, value: Value) -> None:
        if value != 0:
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, "only 0 may be written (clears the history)")
        self.history.clear()
        for sub in range(1, HISTORY_DEPTH + 1):
            self.od.set(OD_ERROR_HISTORY, sub, 0)
