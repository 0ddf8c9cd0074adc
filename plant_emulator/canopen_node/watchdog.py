"""The SYNC watchdog and RPDO1 deadline monitoring: valves to zero when the master goes quiet
(docs/canopen.md, "Behaviour on the bus": Watchdog)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.live_config import LiveConfig
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode, Value
from plant_emulator.canopen_node.transmit import NodeLog, log
from protocol.can_map import OD_WATCHDOG_PERIODS, EmcyCode

_SYNC_TIMEOUT: Final = int(EmcyCode.SYNC_TIMEOUT)
_RPDO_TIMEOUT: Final = int(EmcyCode.RPDO_TIMEOUT)
_OUTPUT_CLIPPED: Final = int(EmcyCode.OUTPUT_CLIPPED)


class Watchdog:
    """Trips on a silent SYNC or RPDO1 stream while OPERATIONAL; released by the stream that stopped."""

    def __init__(
        self,
        od: ObjectDictionary,
        on_watchdog: Callable[[bool], None],
        zero_outputs: Callable[[], None],
        emcy: EmcyProducer,
        counters: NodeCounters,
        log: NodeLog,
    ) -> None:
        self.on_watchdog = on_watchdog
        self.zero_outputs = zero_outputs
        self.emcy = emcy
        self.counters = counters
        self.log = log
        self.sync_last: float | None = None
        """Last SYNC in OPERATIONAL (None: not armed)."""
        self.rpdo_last: float | None = None
        """Last RPDO1 applied in OPERATIONAL: the second input (armed by the first RPDO1)."""
        self.tripped = False
        self.cause = "sync"
        """What tripped it: ``sync`` or ``rpdo``."""
        self.code = 0
        """The EMCY code of the current trip (SYNC_TIMEOUT or RPDO_TIMEOUT), 0 when none."""
        od.on_write(OD_WATCHDOG_PERIODS, 0, self._write_periods)

    def deadlines(self, conf: LiveConfig) -> tuple[float, float]:
        """(SYNC watchdog, RPDO1 deadline) while armed, inf where not."""
        sync_timeout, rpdo_timeout = conf.watchdog_timeout_s, conf.rpdo_timeout_s
        sync_last, rpdo_last = self.sync_last, self.rpdo_last
        sync_due = sync_last + sync_timeout if sync_last is not None and sync_timeout > 0 else math.inf
        rpdo_due = rpdo_last + rpdo_timeout if rpdo_last is not None and rpdo_timeout > 0 else math.inf
        return sync_due, rpdo_due

    def check(self, now: float, conf: LiveConfig, sync_counter: int | None) -> float:
        """In OPERATIONAL and not tripped: trip when a deadline passed; returns the next deadline (inf: none)."""
        sync_due, rpdo_due = self.deadlines(conf)
        if now >= sync_due or now >= rpdo_due:
            self._trip(now, sync_due, sync_counter)  # held from now on: no deadline until it recovers
            return math.inf
        return sync_due if sync_due < rpdo_due else rpdo_due

    def _trip(self, now: float, sync_due: float, sync_counter: int | None) -> None:
        # SYNC silent, or SYNC still coming but RPDO1 stopped: someone else's
        # SYNC stream must not keep the valves open for a controller that froze.
        self.cause = "sync" if now >= sync_due else "rpdo"
        self.tripped = True
        self.counters.watchdog_trips += 1
        node_id = self.log.node_id
        if self.cause == "sync":
            assert self.sync_last is not None
            log.warning("node %d: no SYNC for %.1f ms: watchdog tripped, valves held at zero", node_id, (now - self.sync_last) * 1e3)
        else:
            self.counters.rpdo_timeouts += 1
            assert self.rpdo_last is not None
            log.warning("node %d: SYNC present but no RPDO1 for %.1f ms: watchdog tripped, valves held at zero", node_id, (now - self.rpdo_last) * 1e3)
        self.zero_outputs()
        self.log.call_app("on_watchdog", self.on_watchdog, True)
        cause = 0 if self.cause == "sync" else 1
        self.code = _SYNC_TIMEOUT if cause == 0 else _RPDO_TIMEOUT
        self.emcy.set_fault(self.code, True, bytes([sync_counter or 0, cause]))
        self.emcy.set_fault(_OUTPUT_CLIPPED, False)

    def recover(self, now: float) -> None:
        """The stream that stopped is back: release the valves to the next RPDO1."""
        self.tripped = False
        self.counters.watchdog_recoveries += 1
        log.info("node %d: %s back, watchdog released", self.log.node_id, "SYNC" if self.cause == "sync" else "RPDO1")
        self.sync_last = now
        self.rpdo_last = now if self.rpdo_last is not None else None
        self.log.call_app("on_watchdog", self.on_watchdog, False)
        self.clear_trip_fault()

    def release(self) -> bool:
        """Leaving OPERATIONAL ends a trip (the application is told); returns whether there was one."""
        if not self.tripped:
            return False
        self.tripped = False
        self.log.call_app("on_watchdog", self.on_watchdog, False)
        return True

    def clear_trip_fault(self) -> None:
        if self.code:
            self.emcy.set_fault(self.code, False)
            self.code = 0

    def disarm(self) -> None:
        """Not armed again until the next SYNC and RPDO1 in OPERATIONAL."""
        self.sync_last = None
        self.rpdo_last = None

    def _write_periods(self, value: Value) -> None:
        if int(value) == 0:
            self.counters.watchdog_disable_refused += 1
            log.warning("node %d: SDO write 0x2003 = 0 (watchdog off) refused; only the node's configuration disables it", self.log.node_id)
            raise SdoAbort(SdoAbortCode.CANNOT_STORE_DEVICE_STATE, "the SYNC watchdog cannot be disabled over the bus (use a longer time)")
