"""What the node needs from the plant, and the objects it passes on to it.

The plant service implements :class:`NodeApplication`; the node calls it on
each SYNC (sample), on each RPDO1 (valve voltages) and when the watchdog
trips or releases. :class:`ApplicationObjects` serves the two objects whose
writes the application must accept: 0x2000 (sample period) and 0x2001 (A/D
resolution)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
import numpy.typing as npt

from plant_emulator.canopen_node.live_config import LiveConfigReader
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode, Value
from plant_emulator.canopen_node.transmit import NodeLog, log
from protocol.can_map import ADC_RESOLUTIONS, OD_ADC_RESOLUTION, OD_SAMPLE_PERIOD


class NodeApplication(Protocol):
    """What the node needs from the plant (implemented by the plant service)."""

    def on_sync(self, counter: int) -> tuple[Sequence[int] | npt.NDArray[np.int64], Sequence[bool] | npt.NDArray[np.bool_]]:
        """Advance the plant to this SYNC and sample it: (codes at the current
        ADC resolution, saturated flags), four each: int64 and bool arrays, or
        lists of ints and bools (the plant's own, taken as they are).
        ``counter`` is the SYNC counter (1..240), or 0 for SYNCs without counter."""
        ...

    def on_outputs(self, volts: npt.NDArray[np.float64]) -> None:
        """New valve voltages (2,), after D/A quantization and clipping."""
        ...

    def on_watchdog(self, tripped: bool) -> None:
        """SYNC lost (True: drive the valves to zero and hold) or back (False)."""
        ...


class ConfigurableApplication(NodeApplication, Protocol):
    """Optional hooks, looked up with ``getattr``: an application without
    ``on_adc_bits`` refuses resolution changes by SDO (abort 0x08000020);
    one without ``on_sample_period`` just has the value stored. Either may
    raise to refuse a value (abort 0x08000020, the old value stays)."""

    def on_adc_bits(self, bits: int) -> None:
        """Switch the A/D to ``bits`` (12, 16, 20): later ``on_sync`` codes use it."""
        ...

    def on_sample_period(self, period_s: float) -> None: ...


class ApplicationObjects:
    """SDO writes of 0x2000 and 0x2001, passed to the application's optional hooks
    (:class:`ConfigurableApplication`); a hook that raises refuses the value."""

    def __init__(self, od: ObjectDictionary, app: object, config: LiveConfigReader, update_tpdo_valid: Callable[[int], None], log: NodeLog) -> None:
        self.app = app
        self.config = config
        self.update_tpdo_valid = update_tpdo_valid
        self.node_id = log.node_id
        od.on_write(OD_SAMPLE_PERIOD, 0, self._write_sample_period)
        od.on_write(OD_ADC_RESOLUTION, 0, self._write_adc_resolution)

    def _write_sample_period(self, value: Value) -> None:
        hook = getattr(self.app, "on_sample_period", None)
        if hook is not None:
            try:
                hook(int(value) * 1e-6)
            except Exception as e:  # noqa: BLE001 - the app refuses: abort, keep the old value
                raise SdoAbort(SdoAbortCode.CANNOT_STORE, f"application refused the sample period: {e}") from e

    def _write_adc_resolution(self, value: Value) -> None:
        if value not in ADC_RESOLUTIONS:
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, f"ADC resolution must be one of {ADC_RESOLUTIONS}")
        bits = int(value)
        if bits == self.config().adc_bits:
            return
        hook = getattr(self.app, "on_adc_bits", None)
        if hook is None:
            raise SdoAbort(SdoAbortCode.CANNOT_STORE, "the application cannot change the ADC resolution")
        try:
            hook(bits)
        except Exception as e:  # noqa: BLE001
            raise SdoAbort(SdoAbortCode.CANNOT_STORE, f"application refused {bits} bits: {e}") from e
        self.update_tpdo_valid(bits)
        log.info("node %d: ADC resolution %d bits", self.node_id, bits)
