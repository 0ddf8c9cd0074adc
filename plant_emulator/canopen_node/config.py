"""The node's power-on configuration (what NMT RESET_NODE returns to).

The plant service maps its settings onto :class:`NodeConfig`; every field is
also an object of the dictionary (see :mod:`plant_emulator.canopen_node.objects`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from protocol.can_map import (
    ADC_RESOLUTIONS,
    DEFAULT_NODE_ID,
    FULL_SCALE_V,
    SYNC_COUNTER_OVERFLOW,
)
from protocol.errors import ConfigError


@dataclass(frozen=True)
class NodeConfig:
    """Power-on values of the node (RESET_NODE returns to these).

    Every field is also an object in the dictionary
    (:func:`plant_emulator.canopen_node.objects.object_table`).
    """

    node_id: int = DEFAULT_NODE_ID
    """CANopen node id 1..127."""
    heartbeat_ms: int = 100
    """0x1017 producer heartbeat time (ms); 0 disables."""
    sample_period_s: float = 0.005
    """0x2000 nominal SYNC period (stored in µs there), 200 Hz as on the rig; the watchdog's unit."""
    adc_bits: int = 12
    """0x2001 A/D resolution: 12, 16 or 20 bits; the application must start at this resolution."""
    valve_limit_v: float = FULL_SCALE_V
    """0x2002 analog outputs are clipped to ± this (0 < limit <= 10 V)."""
    watchdog_periods: int = 5
    """0x2003 SYNC watchdog, in sample periods; 0 disables."""
    sync_counter_overflow: int = SYNC_COUNTER_OVERFLOW
    """0x1019: 240 (SYNC with counter) or 0 (SYNC without counter)."""
    device_name: str = "RALF plant analog I/O (AVME 9325 A/D + AVME 947X D/A emulation)"
    """0x1008."""
    software_version: str = "ralf-hil 0.1.0"
    """0x100A."""
    vendor_id: int = 0x52414C46
    """0x1018 sub 1 ('RALF'; not a CiA-assigned id: this is an emulation)."""
    product_code: int = 0x00009325
    """0x1018 sub 2."""
    revision: int = 0x00010000
    """0x1018 sub 3 (major 1, minor 0)."""
    serial_number: int = 1996
    """0x1018 sub 4."""

    def __post_init__(self) -> None:
        problems = []
        if not 1 <= self.node_id <= 127:
            problems.append(f"node_id must be 1..127, got {self.node_id}")
        if not 0 <= self.heartbeat_ms <= 0xFFFF:
            problems.append(f"heartbeat_ms must be 0..65535, got {self.heartbeat_ms}")
        if not (math.isfinite(self.sample_period_s) and 100 <= round(self.sample_period_s * 1e6) <= 1_000_000):
            problems.append(f"sample_period_s must be 100 µs..1 s, got {self.sample_period_s}")
        if self.adc_bits not in ADC_RESOLUTIONS:
            problems.append(f"adc_bits must be one of {ADC_RESOLUTIONS}, got {self.adc_bits}")
        if not (math.isfinite(self.valve_limit_v) and 0 < self.valve_limit_v <= FULL_SCALE_V):
            problems.append(f"valve_limit_v must be in (0, {FULL_SCALE_V}], got {self.valve_limit_v}")
        if not 0 <= self.watchdog_periods <= 0xFFFF:
            problems.append(f"watchdog_periods must be 0..65535, got {self.watchdog_periods}")
        if self.sync_counter_overflow not in (0, SYNC_COUNTER_OVERFLOW):
            problems.append(f"sync_counter_overflow must be 0 or {SYNC_COUNTER_OVERFLOW}")
        for name in ("vendor_id", "product_code", "revision", "serial_number"):
            if not 0 <= getattr(self, name) <= 0xFFFFFFFF:
                problems.append(f"{name} must fit UNSIGNED32")
        for name in ("device_name", "software_version"):
            if not getattr(self, name).isascii() or ";" in getattr(self, name):
                problems.append(f"{name} must be ASCII without ';' (it goes into the EDS)")
        if problems:
            raise ConfigError("invalid NodeConfig: " + "; ".join(problems))

    @property
    def sample_period_us(self) -> int:
        """As object 0x2000 holds it."""
        return round(self.sample_period_s * 1e6)
