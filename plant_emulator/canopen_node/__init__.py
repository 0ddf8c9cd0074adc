"""The plant's CANopen (CiA 301 / CiA 401) slave, in the parts a CANopen stack has.

Modules, each importing only those above it:

* :mod:`~plant_emulator.canopen_node.config`: :class:`NodeConfig`, the power-on values;
* :mod:`~plant_emulator.canopen_node.od`: object dictionary storage and types (data
  and access types, :class:`SdoAbort`);
* :mod:`~plant_emulator.canopen_node.objects`: this node's object table;
* :mod:`~plant_emulator.canopen_node.eds`: the CiA 306 EDS writer (``python -m
  plant_emulator.canopen_node > protocol/ralf_io.eds`` regenerates the shipped file);
* :mod:`~plant_emulator.canopen_node.sdo_server`: the SDO server;
* :mod:`~plant_emulator.canopen_node.counters`: what the node counts;
* :mod:`~plant_emulator.canopen_node.node`: :class:`CanopenNode`, the NMT / SYNC /
  PDO / EMCY / heartbeat state machine (pure: frames and times in, frames out);
* :mod:`~plant_emulator.canopen_node.runner`: :func:`run_node`, the I/O loop on a
  python-can bus.

The OD indices both sides of the bus use live in :mod:`protocol.can_map`.
"""

from plant_emulator.canopen_node.config import NodeConfig
from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.eds import render_eds
from plant_emulator.canopen_node.node import (
    CanopenNode,
    ConfigurableApplication,
    NodeApplication,
    error_register_bits,
    node_can_filters,
)
from plant_emulator.canopen_node.objects import object_table
from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode
from plant_emulator.canopen_node.runner import run_node
from plant_emulator.canopen_node.sdo_server import SdoServer

__all__ = [
    "CanopenNode",
    "ConfigurableApplication",
    "NodeApplication",
    "NodeConfig",
    "NodeCounters",
    "ObjectDictionary",
    "SdoAbort",
    "SdoAbortCode",
    "SdoServer",
    "error_register_bits",
    "node_can_filters",
    "object_table",
    "render_eds",
    "run_node",
]
