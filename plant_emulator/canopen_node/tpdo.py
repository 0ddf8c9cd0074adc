"""TPDO1-3 (CiA 401 analog inputs 0x6401/0x6402): on each SYNC in OPERATIONAL, the plant's A/D
codes onto the bus (docs/canopen.md, "Behaviour on the bus": TPDO1-3)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.live_config import LiveConfigReader
from plant_emulator.canopen_node.objects import PDO_NO_RTR, PDO_NOT_VALID
from plant_emulator.canopen_node.od import ObjectDictionary, Value
from plant_emulator.canopen_node.transmit import NodeLog, Outbox
from protocol.can_map import (
    N_ANALOG_INPUTS,
    OD_ANALOG_INPUT_16,
    OD_ANALOG_INPUT_32,
    TPDO2_BASE,
    TPDO3_BASE,
    EmcyCode,
    encode_analog_inputs_16,
    encode_analog_inputs_32,
)

IN16_KEYS: Final = tuple((OD_ANALOG_INPUT_16, sub) for sub in range(1, N_ANALOG_INPUTS + 1))
IN32_KEYS: Final = tuple((OD_ANALOG_INPUT_32, sub) for sub in range(1, N_ANALOG_INPUTS + 1))
_INPUT_SATURATED: Final = int(EmcyCode.INPUT_SATURATED)


def sample_lists(result: Any) -> tuple[list[int], list[bool]]:
    """``on_sync``'s (codes, saturated flags) as four plain ints and four bools;
    raises ValueError (or TypeError) on anything else."""
    raw_codes, raw_sat = result
    if (
        type(raw_codes) is list
        and type(raw_sat) is list
        and len(raw_codes) == N_ANALOG_INPUTS
        and len(raw_sat) == N_ANALOG_INPUTS
        and type(raw_codes[0]) is int
        and type(raw_codes[1]) is int
        and type(raw_codes[2]) is int
        and type(raw_codes[3]) is int
        and type(raw_sat[0]) is bool
        and type(raw_sat[1]) is bool
        and type(raw_sat[2]) is bool
        and type(raw_sat[3]) is bool
    ):
        return raw_codes, raw_sat  # the plant's own A/D output: four plain ints and bools already
    if (
        type(raw_codes) is np.ndarray
        and raw_codes.dtype == np.int64
        and raw_codes.shape == (N_ANALOG_INPUTS,)
        and type(raw_sat) is np.ndarray
        and raw_sat.dtype == np.bool_
        and raw_sat.shape == (N_ANALOG_INPUTS,)
    ):
        return raw_codes.tolist(), raw_sat.tolist()
    arr = np.asarray(raw_codes)
    sat_arr = np.asarray(raw_sat, dtype=bool).reshape(N_ANALOG_INPUTS)
    if arr.shape != (N_ANALOG_INPUTS,):
        raise ValueError(f"codes must have shape (4,), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr.astype(np.float64))):
            raise ValueError("codes must be finite")
        arr = np.rint(arr.astype(np.float64))
    return arr.astype(np.int64).tolist(), sat_arr.tolist()


class TpdoProducer:
    """The analog inputs 0x6401/0x6402 and the TPDOs that carry them."""

    def __init__(
        self,
        od: ObjectDictionary,
        config: LiveConfigReader,
        on_sync: Callable[[int], Any],
        ids: dict[str, int],
        outbox: Outbox,
        emcy: EmcyProducer,
        counters: NodeCounters,
        log: NodeLog,
    ) -> None:
        self.od = od
        self.config = config
        self.on_sync = on_sync
        self.node_id = log.node_id
        self.tpdo_ids = ids["tpdo1"], ids["tpdo2"], ids["tpdo3"]
        self.outbox = outbox
        self.emcy = emcy
        self.counters = counters
        self.log = log
        # The process data lives in these lists, which the dictionary serves
        # through getters: written on every sample, read only by SDO uploads.
        self._defaults = {key: od.get(*key) for key in IN16_KEYS + IN32_KEYS}
        self.in16: list[int] = []
        self.in32: list[int] = []
        self.reset_process_data()
        for i in range(N_ANALOG_INPUTS):
            od.getter(OD_ANALOG_INPUT_16, i + 1, self._getter(16, i))
            od.getter(OD_ANALOG_INPUT_32, i + 1, self._getter(32, i))

    def _getter(self, width: int, i: int) -> Callable[[], Value]:
        def get() -> Value:
            value: int = (self.in16 if width == 16 else self.in32)[i]
            return value

        return get

    def reset_process_data(self) -> None:
        """0x6401/0x6402 back to their configured values (NMT RESET_NODE)."""
        self.in16 = [int(self._defaults[k]) for k in IN16_KEYS]
        self.in32 = [int(self._defaults[k]) for k in IN32_KEYS]

    def update_valid(self, bits: int) -> None:
        """TPDO2/3's COB-IDs (0x1801/0x1802 sub 1) valid above 16 bits only."""
        valid = bits > 16
        for index, base in ((0x1801, TPDO2_BASE), (0x1802, TPDO3_BASE)):
            self.od.set(index, 1, PDO_NO_RTR | (0 if valid else PDO_NOT_VALID) | (base + self.node_id))

    def sample(self, counter: int) -> None:
        """One SYNC's sample: the application's codes onto TPDO1 (and TPDO2/3 above 16 bits)."""
        try:
            result = self.on_sync(counter)
        except Exception:  # noqa: BLE001 - the app's bug must not take the bus down
            self.log.app_failed("on_sync")
            return
        if result is None:
            return
        try:
            codes, saturated = sample_lists(result)
        except Exception as e:  # noqa: BLE001 - a bad sample costs one TPDO, not the node
            self.counters.app_errors += 1
            self.log.once("app:on_sync_result", "node %d: on_sync returned unusable data: %s", self.node_id, e)
            return
        self._transmit(codes, self.config().adc_bits)
        self.counters.samples += 1
        s0, s1, s2, s3 = saturated
        if s0 or s1 or s2 or s3:
            self.counters.saturated_samples += int(s0) + int(s1) + int(s2) + int(s3)
            self.emcy.set_fault(_INPUT_SATURATED, True, bytes([int(s0) | int(s1) << 1 | int(s2) << 2 | int(s3) << 3]))
        elif _INPUT_SATURATED in self.emcy.faults:
            self.emcy.set_fault(_INPUT_SATURATED, False)

    def _transmit(self, codes: Sequence[int], bits: int) -> None:
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        c0, c1, c2, c3 = codes
        if not (lo <= c0 <= hi and lo <= c1 <= hi and lo <= c2 <= hi and lo <= c3 <= hi):
            self.counters.app_codes_clipped += 1
            self.log.once("app:codes", "node %d: on_sync codes %s outside %d-bit range, clipped", self.node_id, np.array(codes, dtype=np.int64), bits)
            c0, c1, c2, c3 = (min(hi, max(lo, c)) for c in codes)
        if bits <= 16:
            s16 = 16 - bits
            words16 = [c0 << s16, c1 << s16, c2 << s16, c3 << s16]
        else:
            s16 = bits - 16
            words16 = [c0 >> s16, c1 >> s16, c2 >> s16, c3 >> s16]
        s32 = 32 - bits
        self.in16 = words16
        self.in32 = words32 = [c0 << s32, c1 << s32, c2 << s32, c3 << s32]
        tpdo1_id, tpdo2_id, tpdo3_id = self.tpdo_ids
        outbox = self.outbox
        outbox.emit(tpdo1_id, encode_analog_inputs_16(words16), "tpdo1")
        if bits > 16:
            tpdo2, tpdo3 = encode_analog_inputs_32(words32)
            outbox.emit(tpdo2_id, tpdo2, "tpdo2")
            outbox.emit(tpdo3_id, tpdo3, "tpdo3")
