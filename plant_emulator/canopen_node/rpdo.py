"""RPDO1 (CiA 401 analog outputs 0x6411 sub 1-2): the controller's valve commands to the plant,
applied on receipt, clipped to the valve limit 0x2002, and a second RPDO producer told from the count
per SYNC period (docs/canopen.md, "Behaviour on the bus": RPDO1)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.live_config import LiveConfig, LiveConfigReader, dac_bounds
from plant_emulator.canopen_node.nmt import NmtSlave
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode, Value
from plant_emulator.canopen_node.sync import CONFLICT_CLEAR_PERIODS
from plant_emulator.canopen_node.transmit import NodeLog, log
from plant_emulator.canopen_node.watchdog import Watchdog
from protocol.can_map import (
    DAC12,
    FULL_SCALE_V,
    N_ANALOG_OUTPUTS,
    OD_ANALOG_OUTPUT_16,
    OD_RPDO1_COMM,
    OD_RPDO_EVENT_TIMER_SUB,
    OD_VALVE_LIMIT,
    EmcyCode,
    NmtState,
)

OUT16_KEYS: Final = tuple((OD_ANALOG_OUTPUT_16, sub) for sub in range(1, N_ANALOG_OUTPUTS + 1))
ZERO_VOLTS: Final[tuple[float, float]] = (0.0, 0.0)
_OPERATIONAL: Final = NmtState.OPERATIONAL
_OUTPUT_CLIPPED: Final = int(EmcyCode.OUTPUT_CLIPPED)
_PDO_LENGTH: Final = int(EmcyCode.PDO_LENGTH)
_RPDO_CONFLICT: Final = int(EmcyCode.RPDO_CONFLICT)
_DAC_LSB: Final = DAC12.lsb_v
_DAC_SHIFT: Final = DAC12.shift(16)
"""DAC12's constants, read once (its properties compute them on every access)."""
_RPDO1: Final = struct.Struct("<2h")
"""RPDO1 payload: two left-justified INT16 words (as protocol.can_map.decode_analog_outputs, length already checked)."""


class RpdoConsumer:
    """The analog outputs: RPDO1 and SDO writes of 0x6411 to the valves."""

    def __init__(
        self,
        od: ObjectDictionary,
        config: LiveConfigReader,
        app: Any,
        nmt: NmtSlave,
        emcy: EmcyProducer,
        counters: NodeCounters,
        log: NodeLog,
    ) -> None:
        self.config = config
        self.app = app
        self.nmt = nmt
        self.emcy = emcy
        self.counters = counters
        self.log = log
        self.watchdog: Watchdog
        """Set by the node once built (it zeroes these outputs when it trips)."""
        self._on_output_values: Callable[[float, float], None] | None = getattr(app, "on_output_values", None)
        """The application's optional float form of ``on_outputs`` (two plain floats, no array per RPDO)."""
        self._defaults = {key: od.get(*key) for key in OUT16_KEYS}
        self.out16: list[int] = []
        self.reset_process_data()
        self.volts = ZERO_VOLTS
        """Valve voltages as last given to the application."""
        self.in_period = 0
        """RPDO1s applied since the last SYNC."""
        self._conflict_clean = 0
        for sub in range(1, N_ANALOG_OUTPUTS + 1):
            od.getter(OD_ANALOG_OUTPUT_16, sub, self._getter(sub - 1))
            od.on_write(OD_ANALOG_OUTPUT_16, sub, self._writer(sub))
        od.on_write(OD_VALVE_LIMIT, 0, self._write_valve_limit)
        od.on_write(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, self._write_event_timer)

    def _getter(self, i: int) -> Callable[[], Value]:
        def get() -> Value:
            return self.out16[i]

        return get

    def reset_process_data(self) -> None:
        """0x6411 back to its configured values (NMT RESET_NODE)."""
        self.out16 = [int(self._defaults[k]) for k in OUT16_KEYS]

    def receive(self, cob_id: int, data: bytes, now: float) -> None:
        self.counters.rx["rpdo"] += 1
        if self.nmt.state is not _OPERATIONAL:
            self.log.malformed("rpdo_not_operational", cob_id, data, f"RPDO in {self.nmt.state.name}, PDOs need NMT START")
            return
        if len(data) != 4:
            self.log.malformed("rpdo_dlc", cob_id, data, f"RPDO1 takes 4 bytes, got {len(data)}")
            self.emcy.set_fault(_PDO_LENGTH, True, bytes([len(data) & 0xFF]))
            return
        if _PDO_LENGTH in self.emcy.faults:
            self.emcy.set_fault(_PDO_LENGTH, False)
        watchdog = self.watchdog
        if watchdog.tripped:
            self.counters.outputs_held += 1
            if watchdog.cause == "rpdo":
                watchdog.recover(now)  # the controller is back; this frame is held, the next one applies
            return
        watchdog.rpdo_last = now
        self.in_period += 1  # held frames (tripped) are not counted
        w0, w1 = _RPDO1.unpack(data)
        conf = self.config()
        self.apply_words(w0, w1, conf.dac_code_lo, conf.dac_code_hi)

    def apply_words(self, w0: int, w1: int, lo: int, hi: int) -> None:
        """Two 0x6411 words to the valves: D/A codes (the 4 padding bits
        dropped), clipped to the D/A codes ``lo``..``hi`` the valve limit allows."""
        self.out16 = [w0, w1]
        lsb = _DAC_LSB
        # Plain ints: the code's int -> float conversion and the product by one LSB are
        # the same IEEE operations numpy does on the int64 array.
        c0, c1 = w0 >> _DAC_SHIFT, w1 >> _DAC_SHIFT
        clip0, clip1 = c0 < lo or c0 > hi, c1 < lo or c1 > hi
        # min(hi, max(lo, c)) written out (ints: the same values)
        v0 = float(lo if c0 < lo else (hi if c0 > hi else c0)) * lsb
        v1 = float(lo if c1 < lo else (hi if c1 > hi else c1)) * lsb
        self.volts = (v0, v1)
        self.counters.outputs_applied += 1
        try:
            values = self._on_output_values
            if values is not None:
                values(v0, v1)
            else:
                self.app.on_outputs(np.array((v0, v1), dtype=np.float64))
        except Exception:  # noqa: BLE001 - as NodeLog.call_app
            self.log.app_failed("on_outputs")
        if clip0 or clip1:
            self.counters.clipped_outputs += 1
            self.emcy.set_fault(_OUTPUT_CLIPPED, True, bytes([int(clip0) | (int(clip1) << 1)]))
        elif _OUTPUT_CLIPPED in self.emcy.faults:
            self.emcy.set_fault(_OUTPUT_CLIPPED, False)

    def zero(self) -> None:
        """The words and volts to zero (the application is told by the caller)."""
        self.out16 = [0, 0]
        self.volts = ZERO_VOLTS

    def end_period(self, missed: int, conf: LiveConfig) -> None:
        """At each SYNC, while RPDO1 is declared cyclic (0x1400 sub 5 > 0): more
        RPDO1s in the period just ended than SYNCs in it (1 + the SYNCs the
        counter says were lost) means a second producer: EMCY RPDO_CONFLICT
        until CONFLICT_CLEAR_PERIODS clean periods."""
        n, self.in_period = self.in_period, 0
        if conf.rpdo_timeout_s <= 0:
            return  # RPDO1 not declared cyclic: event-driven masters may send several per period
        if n > 1 + missed:
            self.counters.rpdo_conflicts += 1
            self._conflict_clean = 0
            if _RPDO_CONFLICT not in self.emcy.faults:
                log.warning("node %d: %d RPDO1 in one SYNC period: a second RPDO producer on the bus?", self.log.node_id, n)
            self.emcy.set_fault(_RPDO_CONFLICT, True, bytes([min(n, 255)]))
        elif _RPDO_CONFLICT in self.emcy.faults:
            self._conflict_clean += 1
            if self._conflict_clean >= CONFLICT_CLEAR_PERIODS:
                self.emcy.set_fault(_RPDO_CONFLICT, False)

    def _words(self) -> npt.NDArray[np.int64]:
        return np.array(self.out16, dtype=np.int64)

    def _writer(self, sub: int) -> Callable[[Value], None]:
        def write(value: Value) -> None:
            if self.nmt.state is not _OPERATIONAL or self.watchdog.tripped:
                raise SdoAbort(
                    SdoAbortCode.CANNOT_STORE_DEVICE_STATE,
                    "outputs are written only in OPERATIONAL with SYNC present",
                )
            words = self._words()
            words[sub - 1] = int(value)
            conf = self.config()
            self.apply_words(int(words[0]), int(words[1]), conf.dac_code_lo, conf.dac_code_hi)

        return write

    def _write_valve_limit(self, value: Value) -> None:
        v = float(value)
        if v <= 0:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_LOW, "the valve voltage limit must be positive")
        if v > FULL_SCALE_V:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH, f"the D/A spans ±{FULL_SCALE_V} V")
        if self.nmt.state is _OPERATIONAL and not self.watchdog.tripped:
            words = self._words()
            wanted = DAC12.to_volts(DAC12.from_left_justified(words))
            if np.any(np.abs(wanted) > v) or _OUTPUT_CLIPPED in self.emcy.faults:
                self.apply_words(int(words[0]), int(words[1]), *dac_bounds(v))  # re-clip (or release) what the valves get now

    def _write_event_timer(self, value: Value) -> None:
        if self.nmt.state is _OPERATIONAL:
            raise SdoAbort(SdoAbortCode.CANNOT_STORE_DEVICE_STATE, "the RPDO1 event timer is set in PRE-OPERATIONAL (before NMT START)")
