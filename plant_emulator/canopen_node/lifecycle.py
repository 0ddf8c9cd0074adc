"""What boot-up, the NMT state changes and the two resets do to the node's parts
(docs/canopen.md, "Behaviour on the bus": NMT)."""

from __future__ import annotations

from typing import Any, Final

import numpy as np

from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.impersonation import CollisionMonitor
from plant_emulator.canopen_node.live_config import LiveConfigReader
from plant_emulator.canopen_node.nmt import NmtSlave
from plant_emulator.canopen_node.od import ObjectDictionary
from plant_emulator.canopen_node.rpdo import RpdoConsumer
from plant_emulator.canopen_node.sdo_server import SdoServer
from plant_emulator.canopen_node.sync import SyncConsumer
from plant_emulator.canopen_node.tpdo import TpdoProducer
from plant_emulator.canopen_node.transmit import NodeLog, log
from plant_emulator.canopen_node.watchdog import Watchdog
from protocol.can_map import N_ANALOG_OUTPUTS, OD_SAMPLE_PERIOD, EmcyCode, NmtCommand, NmtState

_ZERO_OUTPUTS: Final = np.zeros(N_ANALOG_OUTPUTS)
_COMMUNICATION_OBJECTS: Final = range(0x1000, 0x2000)


class Lifecycle:
    """Carries out NMT commands on the parts of one node."""

    def __init__(
        self,
        app: Any,
        od: ObjectDictionary,
        config: LiveConfigReader,
        nmt: NmtSlave,
        sdo: SdoServer,
        sync: SyncConsumer,
        watchdog: Watchdog,
        rpdo: RpdoConsumer,
        tpdo: TpdoProducer,
        emcy: EmcyProducer,
        collisions: CollisionMonitor,
        log: NodeLog,
    ) -> None:
        self.app = app
        self.od = od
        self.config = config
        self.nmt = nmt
        self.sdo = sdo
        self.sync = sync
        self.watchdog = watchdog
        self.rpdo = rpdo
        self.tpdo = tpdo
        self.emcy = emcy
        self.collisions = collisions
        self.log = log

    def command(self, command: NmtCommand) -> None:
        if command is NmtCommand.START:
            self.enter(NmtState.OPERATIONAL)
        elif command is NmtCommand.STOP:
            self.enter(NmtState.STOPPED)
        elif command is NmtCommand.ENTER_PRE_OPERATIONAL:
            self.enter(NmtState.PRE_OPERATIONAL)
        elif command is NmtCommand.RESET_NODE:
            self.reset(application=True)
        elif command is NmtCommand.RESET_COMMUNICATION:
            self.reset(application=False)

    def boot(self) -> None:
        self.sdo.reset()
        self.nmt.send_boot_up()
        self.sync.last_counter = None
        self.watchdog.disarm()
        self.rpdo.in_period = 0
        log.info("node %d: boot-up, PRE-OPERATIONAL", self.log.node_id)

    def enter(self, new: NmtState) -> None:
        old = self.nmt.state
        if new is old:
            return
        self.nmt.state = new
        log.info("node %d: NMT %s -> %s", self.log.node_id, old.name, new.name)
        if old is NmtState.OPERATIONAL:
            self.watchdog.disarm()
            if self.watchdog.release():
                self.watchdog.clear_trip_fault()
            self._zero_outputs()
            self.emcy.set_fault(EmcyCode.OUTPUT_CLIPPED, False)
        if new is NmtState.OPERATIONAL:
            self.watchdog.disarm()  # armed by the first SYNC and the first RPDO
            self.sync.last_counter = None  # a new master may count differently
            self.rpdo.in_period = 0

    def _zero_outputs(self) -> None:
        self.rpdo.zero()
        self.log.call_app("on_outputs", self.app.on_outputs, _ZERO_OUTPUTS.copy())

    def reset(self, application: bool) -> None:
        old_bits, old_period = self.config().adc_bits, int(self.od.get(OD_SAMPLE_PERIOD))
        was_operational = self.nmt.state is NmtState.OPERATIONAL
        self.nmt.state = NmtState.BOOT_UP  # no EMCY from the tear-down: the boot-up says it all
        if was_operational or self.watchdog.tripped or any(self.rpdo.volts):
            self.watchdog.release()
            self._zero_outputs()
        self.emcy.reset()
        self.watchdog.code = 0
        self.collisions.last = None
        self.od.restore_defaults(None if application else _COMMUNICATION_OBJECTS)
        if application:  # the process data too (served from the parts' lists)
            self.tpdo.reset_process_data()
            self.rpdo.reset_process_data()
            self._tell_app(old_bits, old_period)
        self.tpdo.update_valid(self.config().adc_bits)
        log.info("node %d: NMT reset %s", self.log.node_id, "node" if application else "communication")
        self.boot()

    def _tell_app(self, old_bits: int, old_period: int) -> None:
        """After RESET_NODE: the application's hooks for a resolution or sample period that changed."""
        bits, period = self.config().adc_bits, int(self.od.get(OD_SAMPLE_PERIOD))
        if bits != old_bits:
            hook = getattr(self.app, "on_adc_bits", None)
            if hook is not None:
                self.log.call_app("on_adc_bits", hook, bits)
        if period != old_period:
            hook = getattr(self.app, "on_sample_period", None)
            if hook is not None:
                self.log.call_app("on_sample_period", hook, period * 1e-6)
