"""The node's configuration as this link left it, kept while the run is on.

The objects the link configures or relies on (the heartbeat period 0x1017,
the SYNC counter overflow 0x1019, RPDO1's event timer 0x1400 sub 5, the
sample period 0x2000, the watchdog 0x2003): when another master writes one
of them (:class:`controller.bus_watch.ForeignMasters` sees the request),
the link's value goes back at once by an expedited download, without waiting
for the answer, so a policy that goes on runs with the node as configured
(``comm_restores``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from controller.bus_watch import ConflictLog
from controller.plant_link_counters import PlantLinkCounters
from controller.sdo_client import download_request
from protocol.can_map import OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, OD_SAMPLE_PERIOD, OD_WATCHDOG_PERIODS

SDO_SIZES: Final[dict[tuple[int, int], int]] = {
    (0x1017, 0): 2,
    (0x1019, 0): 1,
    (OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB): 2,
    (OD_SAMPLE_PERIOD, 0): 4,
    (OD_WATCHDOG_PERIODS, 0): 2,
}
"""The guarded objects (index, sub) with their sizes in bytes."""


class ConfigGuard:
    """Writes this link's values back after another master's write, while ``running()``."""

    def __init__(self, send_sdo: Callable[[bytes], None], running: Callable[[], bool], log: ConflictLog, counters: PlantLinkCounters) -> None:
        self._send_sdo = send_sdo
        self._running = running
        self._log = log
        self._counters = counters
        self.values: dict[tuple[int, int], int] = {}
        """The guarded objects' values as the link configured or found them at start."""

    def restore(self, index: int, sub: int) -> None:
        """Another master wrote 0x``index``:``sub``: while running, this link's value goes back at once."""
        value = self.values.get((index, sub))
        if value is None or not self._running():
            return
        self._send_sdo(download_request(index, sub, value, SDO_SIZES[(index, sub)]))
        self._counters.comm_restores += 1
        self._log.log_limited(f"restore:{index:04X}", "wrote 0x%04X:%d = %d back after another master changed it", index, sub, value)
