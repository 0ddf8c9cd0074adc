"""The plant's CANopen (CiA 301 / CiA 401) slave, in the parts a CANopen stack has.

Modules, each importing only those above it (docs/canopen.md, "Code layout"):
storage and configuration (:mod:`.config`, :mod:`.od`, :mod:`.objects`,
:mod:`.eds`, :mod:`.sdo_server`, :mod:`.counters`, :mod:`.live_config`), the
protocol's parts (:mod:`.emcy`, :mod:`.nmt`, :mod:`.sync`, :mod:`.watchdog`,
:mod:`.tpdo`, :mod:`.rpdo`, :mod:`.impersonation`, :mod:`.application`,
:mod:`.lifecycle`), :class:`CanopenNode` assembling them around the object
dictionary (:mod:`.node`: pure, frames and times in, frames out) and
:func:`run_node`, the I/O loop on a python-can bus (:mod:`.runner`).

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
