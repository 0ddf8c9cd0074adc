"""Compatibility names: the CANopen node now lives in :mod:`plant_emulator.canopen_node`."""

from plant_emulator.canopen_node import (
    CanopenNode,
    NodeConfig,
    NodeCounters,
    node_can_filters,
    run_node,
)

__all__ = ["CanopenNode", "NodeConfig", "NodeCounters", "node_can_filters", "run_node"]
