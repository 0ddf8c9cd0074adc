"""The configuration the node reads on every frame, as one named snapshot.

The object dictionary holds the values (0x1017, 0x1019, 0x1400 sub 5,
0x2000-0x2003); :class:`LiveConfigReader` converts them to the units the
node works in and keeps the snapshot until the dictionary changes (its
``generation``), so a tick reads attributes, not dictionary entries."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from plant_emulator.canopen_node.od import ObjectDictionary
from protocol.can_map import (
    DAC12,
    OD_ADC_RESOLUTION,
    OD_RPDO1_COMM,
    OD_RPDO_EVENT_TIMER_SUB,
    OD_SAMPLE_PERIOD,
    OD_VALVE_LIMIT,
    OD_WATCHDOG_PERIODS,
)

OD_HEARTBEAT_TIME: Final[int] = 0x1017
OD_SYNC_OVERFLOW: Final[int] = 0x1019


def dac_bounds(limit_v: float) -> tuple[int, int]:
    """The lowest and highest D/A code a valve voltage limit allows."""
    limit_code = int(math.floor(limit_v / DAC12.lsb_v + 1e-9))
    return max(-limit_code, DAC12.code_min), min(limit_code, DAC12.code_max)


@dataclass(frozen=True, slots=True)
class LiveConfig:
    """The node's configuration as the dictionary holds it now."""

    adc_bits: int
    """0x2001: A/D resolution of the TPDO codes."""
    valve_limit_v: float
    """0x2002: the valves get at most ± this."""
    sample_period_s: float
    """0x2000 (µs there): the nominal SYNC period, the watchdog's unit."""
    heartbeat_period_s: float
    """0x1017 (ms there): 0 = no heartbeat."""
    rpdo_timeout_s: float
    """0x1400 sub 5 (ms there), the RPDO1 event timer: 0 = RPDO1 not monitored (event driven)."""
    watchdog_timeout_s: float
    """0x2003 periods of 0x2000: 0 = the SYNC watchdog is off."""
    sync_overflow: int
    """0x1019: 240 (SYNC with or without counter) or 0 (only without)."""
    dac_code_lo: int
    """The lowest D/A code the valve limit allows."""
    dac_code_hi: int
    """The highest D/A code the valve limit allows."""

    @classmethod
    def from_od(cls, od: ObjectDictionary) -> LiveConfig:
        period = int(od.get(OD_SAMPLE_PERIOD)) * 1e-6
        limit = float(od.get(OD_VALVE_LIMIT))
        code_lo, code_hi = dac_bounds(limit)
        return cls(
            adc_bits=int(od.get(OD_ADC_RESOLUTION)),
            valve_limit_v=limit,
            sample_period_s=period,
            heartbeat_period_s=int(od.get(OD_HEARTBEAT_TIME)) * 1e-3,
            rpdo_timeout_s=int(od.get(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB)) * 1e-3,
            watchdog_timeout_s=int(od.get(OD_WATCHDOG_PERIODS)) * period,
            sync_overflow=int(od.get(OD_SYNC_OVERFLOW)),
            dac_code_lo=code_lo,
            dac_code_hi=code_hi,
        )


class LiveConfigReader:
    """``reader()`` is the current :class:`LiveConfig`, read again only after the dictionary changed."""

    __slots__ = ("_conf", "_generation", "_od")

    def __init__(self, od: ObjectDictionary) -> None:
        self._od = od
        self._generation = od.generation
        self._conf = LiveConfig.from_od(od)

    def __call__(self) -> LiveConfig:
        od = self._od
        if od.generation != self._generation:
            self._conf = LiveConfig.from_od(od)
            self._generation = od.generation
        return self._conf
