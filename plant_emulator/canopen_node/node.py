"""The plant's CAN face: a CANopen (CiA 301) slave with the CiA 401 analog
I/O profile, emulating the rig's A/D (AVME 9325) and D/A (AVME 947X) boards.

:class:`CanopenNode` is a pure state machine: frames and the current time go
in (:meth:`~CanopenNode.handle`, :meth:`~CanopenNode.poll`), frames to send
come out, and the plant is reached only through the :class:`NodeApplication`
callbacks. No sockets, threads or clocks inside, so it is deterministic and
tested frame by frame. :func:`plant_emulator.canopen_node.runner.run_node` is
the thin I/O loop around it for a python-can bus.

The node keeps the object dictionary and the dispatch of frames by COB-ID;
the protocol's parts are their own classes, assembled here as
``canopen.LocalNode`` assembles its services: :class:`~.nmt.NmtSlave` (state,
commands, heartbeat) with :class:`~.lifecycle.Lifecycle` (what a state change
does), :class:`~.sync.SyncConsumer`, :class:`~.watchdog.Watchdog`,
:class:`~.tpdo.TpdoProducer`, :class:`~.rpdo.RpdoConsumer`,
:class:`~.emcy.EmcyProducer`, :class:`~.impersonation.CollisionMonitor` and
the :class:`~.sdo_server.SdoServer`. The behaviour on the wire, part by part,
is in docs/canopen.md ("Behaviour on the bus").

The node is not tied to a thread, but its public methods take an internal
re-entrant lock, so an application may call :meth:`CanopenNode.set_fault`
from another thread or from inside a callback.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Final

import can
import numpy as np
import numpy.typing as npt

from plant_emulator.canopen_node.application import ApplicationObjects, ConfigurableApplication, NodeApplication
from plant_emulator.canopen_node.can_state import CanStateReporter
from plant_emulator.canopen_node.config import NodeConfig
from plant_emulator.canopen_node.counters import NodeCounters, install_diagnostics
from plant_emulator.canopen_node.emcy import EmcyProducer, error_register_bits
from plant_emulator.canopen_node.frames import Frame
from plant_emulator.canopen_node.impersonation import COLLISION_CLEAR_S, COLLISION_EMCY_INTERVAL_S, CollisionMonitor
from plant_emulator.canopen_node.lifecycle import Lifecycle
from plant_emulator.canopen_node.live_config import LiveConfigReader
from plant_emulator.canopen_node.nmt import EMCY_STATES, NmtSlave
from plant_emulator.canopen_node.objects import object_table
from plant_emulator.canopen_node.od import ObjectDictionary
from plant_emulator.canopen_node.rpdo import RpdoConsumer
from plant_emulator.canopen_node.sdo_server import SdoServer
from plant_emulator.canopen_node.sync import CONFLICT_CLEAR_PERIODS, SyncConsumer
from plant_emulator.canopen_node.tpdo import TpdoProducer
from plant_emulator.canopen_node.transmit import ECHO_MEMORY, LOG_INTERVAL_S, NodeLog, Outbox, log
from plant_emulator.canopen_node.watchdog import Watchdog
from protocol.can_map import (
    DEFAULT_NODE_ID,
    OD_ANALOG_INPUT_16,
    OD_ANALOG_INPUT_32,
    OD_ANALOG_OUTPUT_16,
    EmcyCode,
    NmtState,
    cob_ids,
)
from service_kit.can_wire.error_state import ErrorState

__all__ = [
    "COLLISION_CLEAR_S",
    "COLLISION_EMCY_INTERVAL_S",
    "CONFLICT_CLEAR_PERIODS",
    "ECHO_MEMORY",
    "LOG_INTERVAL_S",
    "CanopenNode",
    "ConfigurableApplication",
    "NodeApplication",
    "error_register_bits",
    "node_can_filters",
]

TIME_COB_ID: Final[int] = 0x100
LSS_FIRST_COB_ID: Final[int] = 0x780
"""0x780.. (LSS 0x7E4/0x7E5 and friends) never belong to a node id."""
_OPERATIONAL: Final = NmtState.OPERATIONAL
_STOPPED: Final = NmtState.STOPPED


def node_can_filters(node_id: int = DEFAULT_NODE_ID) -> list[can.typechecking.CanFilter]:
    """python-can filters for a node's bus: NMT, SYNC and every COB-ID with the
    node's id (so misaddressed frames are still counted; udp_multicast echoes
    of our own frames pass and are counted as ``own_cob_id``)."""
    return [
        {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},
        {"can_id": 0x080, "can_mask": 0x7FF, "extended": False},
        {"can_id": node_id, "can_mask": 0x07F, "extended": False},
    ]


class CanopenNode:
    """The CANopen slave: the object dictionary, the parts, and frames dispatched to them."""

    def __init__(self, app: NodeApplication, cfg: NodeConfig | None = None) -> None:
        self.app = app
        self.cfg = cfg if cfg is not None else NodeConfig()
        self.node_id = self.cfg.node_id
        self.ids = ids = cob_ids(self.node_id)
        self.counters = counters = NodeCounters()
        self.od = od = ObjectDictionary.from_table(object_table(self.cfg), self.node_id)
        od.quiet = frozenset({OD_ANALOG_INPUT_16, OD_ANALOG_INPUT_32, OD_ANALOG_OUTPUT_16})
        self.sdo = SdoServer(od)
        counters.sdo = self.sdo.counters
        self._config = config = LiveConfigReader(od)
        self._lock = threading.RLock()
        self._outbox = outbox = Outbox(counters)
        self._log = nlog = NodeLog(self.node_id, counters)
        self._nmt = nmt = NmtSlave(od, self.node_id, ids["heartbeat"], outbox, counters, nlog)
        self._emcy = emcy = EmcyProducer(od, outbox, counters, ids["emcy"], lambda: nmt.state in EMCY_STATES)
        self._can_state = CanStateReporter(emcy)
        own_kind = {ids[k]: k for k in ("emcy", "tpdo1", "tpdo2", "tpdo3", "sdo_tx", "heartbeat")}
        self._own_ids = frozenset(own_kind)
        self._collisions = CollisionMonitor(own_kind, outbox, emcy, counters, nlog)
        self._sync = SyncConsumer(od, emcy, counters, nlog)
        self._tpdo = TpdoProducer(od, config, app.on_sync, ids, outbox, emcy, counters, nlog)
        self._rpdo = rpdo = RpdoConsumer(od, config, app, nmt, emcy, counters, nlog)
        self._watchdog = rpdo.watchdog = Watchdog(od, app.on_watchdog, rpdo.zero, emcy, counters, nlog)
        self._lifecycle = Lifecycle(app, od, config, nmt, self.sdo, self._sync, self._watchdog, rpdo, self._tpdo, emcy, self._collisions, nlog)
        self._sync_id, self._rpdo1_id, self._nmt_id, self._sdo_rx_id = ids["sync"], ids["rpdo1"], ids["nmt"], ids["sdo_rx"]
        self._quiet_until = -math.inf
        """No timer is due before this simulated time (see :meth:`poll_frames`)..."""
        self._quiet_generation = -1
        """...unless the object dictionary changed since (its ``generation``)."""
        self._quiet_exact = True
        """False after :meth:`exchange` kept an earlier quiet time than the deadlines now are (still a safe bound)."""
        install_diagnostics(od, counters)
        ApplicationObjects(od, app, config, self._tpdo.update_valid, nlog)
        self._lifecycle.boot()

    # --- public API ------------------------------------------------------------------

    @property
    def state(self) -> NmtState:
        """The NMT state."""
        return self._nmt.state

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        """Process one received frame; returns the frames to transmit."""
        with self._lock:
            self._outbox.now = now
            self._quiet_until = -math.inf  # the frame may restart a timer: the next poll runs them
            try:
                self._dispatch(msg, now)
            except Exception:  # noqa: BLE001 - nothing on the bus may kill the node
                self.counters.internal_errors += 1
                log.exception("node %d: internal error handling %s", self.node_id, msg)
            self._nmt.start_heartbeat(now, self._config().heartbeat_period_s)
            return [f.to_message() for f in self._outbox.take()]

    def poll(self, now: float) -> list[can.Message]:
        """Run the timers (heartbeat producer, SYNC watchdog); returns frames to transmit.
        Call it at least every few milliseconds, or at :meth:`next_deadline`."""
        return [f.to_message() for f in self.poll_frames(now)]

    def poll_frames(self, now: float) -> list[Frame]:
        """:meth:`poll`, the frames as the node made them (see :class:`Frame`)."""
        with self._lock:
            self._outbox.now = now
            if now < self._quiet_until and not self._outbox.frames and self.od.generation == self._quiet_generation:
                return []  # no timer due before _quiet_until (worked out by the last _timers)
            self._timers(now)
            return self._outbox.take()

    def exchange(self, cob_id: int, data: bytes | bytearray, now: float) -> list[Frame]:
        """:meth:`handle` of a standard data frame followed by :meth:`poll` at the
        same ``now``, in one call and without python-can objects (the
        co-simulation's direct wire): the same state changes, the same frames
        in the same order."""
        with self._lock:
            self._outbox.now = now
            data = bytes(data)
            watchdog = self._watchdog
            # A SYNC or an RPDO1 only moves the armed deadlines later: before the
            # last _timers' quiet time nothing can be due (as in poll_frames).
            quiet = (
                now < self._quiet_until
                and watchdog.sync_last is not None
                and watchdog.rpdo_last is not None
                and not watchdog.tripped
                and self.od.generation == self._quiet_generation
            )
            try:
                if cob_id == self._sync_id:  # the two frames of every tick first (_dispatch_data's order otherwise)
                    self._on_sync(cob_id, data, now)
                elif cob_id == self._rpdo1_id:
                    self._rpdo.receive(cob_id, data, now)
                else:
                    quiet = False
                    self._dispatch_data(cob_id, data, now)
            except Exception:  # noqa: BLE001 - nothing on the bus may kill the node
                self.counters.internal_errors += 1
                log.exception("node %d: internal error handling frame 0x%03X [%s]", self.node_id, cob_id, data.hex(" "))
                quiet = False
            if not quiet or watchdog.tripped or self.od.generation != self._quiet_generation:
                self._timers(now)
            else:
                self._quiet_exact = False  # an earlier bound than the deadlines now are: next_deadline works them out
            return self._outbox.take()

    @property
    def own_cob_ids(self) -> frozenset[int]:
        """The COB-IDs this node transmits on (EMCY, TPDO1-3, SDO reply, heartbeat):
        a standard data frame with one of them received is our own frame back."""
        return self._own_ids

    def expect_echoes(self, on: bool) -> None:
        """Whether the bus hands the node its own frames back (python-can's
        udp_multicast does): then frames on :attr:`own_cob_ids` matching the
        ones sent, in order, are echoes; without echoes (virtual, SocketCAN,
        the rig's loop-free udp_multicast) every such frame is another node's."""
        with self._lock:
            self._outbox.expect_echoes(self._own_ids if on else None)

    def own_cob_frame(self, cob_id: int, data: bytes | bytearray, now: float) -> list[Frame]:
        """What :meth:`handle` does with a standard data frame of :attr:`own_cob_ids`
        (an echo of ours, or another node's frame on our identifiers), without
        :meth:`poll`'s timers, for a runner that recognised the COB-ID; returns
        the frames to send (an EMCY CAN_ID_COLLISION)."""
        with self._lock:
            self._outbox.now = now
            self._collisions.frame(cob_id, bytes(data), now)
            return self._outbox.take()

    def next_deadline(self) -> float | None:
        """The earliest time :meth:`poll` has something to do (None: nothing scheduled)."""
        with self._lock:
            pending = bool(self._outbox.frames)
            if not pending and self._quiet_exact and self._quiet_until != -math.inf and self.od.generation == self._quiet_generation:
                # what the last _timers worked out: the heartbeat and watchdog deadlines (nothing changed since)
                quiet = self._quiet_until
                return None if quiet == math.inf else quiet
            times = [self._nmt.heartbeat_next] if self._nmt.heartbeat_next is not None else []
            if self._nmt.state is _OPERATIONAL and not self._watchdog.tripped:
                times += [t for t in self._watchdog.deadlines(self._config()) if t != math.inf]
            if pending:
                times.append(self._outbox.now)
            return min(times) if times else None

    def set_fault(self, code: EmcyCode | int, active: bool, vendor: bytes = b"") -> None:
        """Raise or clear an application fault (e.g. ``EmcyCode.JOINT_LIMIT``):
        EMCY on entry and the reset EMCY on exit; the frames go out with the
        next :meth:`handle`/:meth:`poll` result."""
        if not 0 <= int(code) <= 0xFFFF or int(code) == 0:
            raise ValueError(f"EMCY code must be 0x0001..0xFFFF, got {code}")
        with self._lock:
            self._emcy.set_fault(int(code), active, vendor[:5])

    def can_error_state(self, state: ErrorState) -> None:
        """The node's CAN controller's error state, as its bus tells it:
        EMCY 0x8120 on error passive, 0x8140 after bus off, the error reset
        when error active again (:mod:`.can_state`); the frames go out with
        the next :meth:`handle`/:meth:`poll` result."""
        with self._lock:
            self._can_state.update(state)

    @property
    def watchdog_tripped(self) -> bool:
        return self._watchdog.tripped

    @property
    def outputs_v(self) -> npt.NDArray[np.float64]:
        """Valve voltages as last given to the application."""
        return np.array(self._rpdo.volts, dtype=np.float64)

    @property
    def adc_bits(self) -> int:
        return self._config().adc_bits

    @property
    def valve_limit_v(self) -> float:
        return self._config().valve_limit_v

    @property
    def sample_period_s(self) -> float:
        return self._config().sample_period_s

    @property
    def heartbeat_period_s(self) -> float:
        return self._config().heartbeat_period_s

    @property
    def rpdo_timeout_s(self) -> float:
        """0x1400 sub 5, the RPDO1 event timer: deadline monitoring of RPDO1 (0 = off)."""
        return self._config().rpdo_timeout_s

    @property
    def watchdog_timeout_s(self) -> float:
        """0 when the watchdog is disabled."""
        return self._config().watchdog_timeout_s

    @property
    def error_register(self) -> int:
        return self._emcy.error_register

    @property
    def active_faults(self) -> tuple[int, ...]:
        return tuple(self._emcy.faults)

    # --- dispatch ---------------------------------------------------------------------------

    def _dispatch(self, msg: can.Message, now: float) -> None:
        if msg.is_error_frame:
            self.counters.rx["error_frame"] += 1
            return
        if msg.is_extended_id:
            self.counters.rx["extended"] += 1
            return
        cob_id = msg.arbitration_id
        if msg.is_remote_frame:
            ours = cob_id < LSS_FIRST_COB_ID and (cob_id & 0x7F) == self.node_id
            if ours or cob_id in (self._nmt_id, self._sync_id):
                self._log.malformed("rtr", cob_id, bytes(msg.data), "remote frames (node guarding, PDO requests) are not supported")
            else:
                self.counters.rx["foreign"] += 1
            return
        self._dispatch_data(cob_id, bytes(msg.data), now)

    def _dispatch_data(self, cob_id: int, data: bytes, now: float) -> None:
        """A standard data frame, by COB-ID."""
        if cob_id == self._sync_id:
            self._on_sync(cob_id, data, now)
            return
        ours = cob_id < LSS_FIRST_COB_ID and (cob_id & 0x7F) == self.node_id
        if cob_id == self._rpdo1_id:
            self._rpdo.receive(cob_id, data, now)
        elif cob_id == self._nmt_id:
            command = self._nmt.command(cob_id, data)
            if command is not None:
                self._lifecycle.command(command)
        elif cob_id == TIME_COB_ID:
            self.counters.rx["time"] += 1
        elif not ours:
            self.counters.rx["foreign"] += 1
        elif cob_id == self._sdo_rx_id:
            self._on_sdo(cob_id, data)
        elif cob_id in self._own_ids:
            self._collisions.frame(cob_id, data, now)
        else:
            self._log.malformed("unknown_cob_id", cob_id, data, "no such object on this node")

    def _on_sync(self, cob_id: int, data: bytes, now: float) -> None:
        """A SYNC: counter checks, then in OPERATIONAL the RPDO period, the watchdog and one sample."""
        self.counters.rx["sync"] += 1
        state = self._nmt.state
        if state is _STOPPED:
            self.counters.rx["sync_stopped"] += 1
            return
        conf = self._config()
        received = self._sync.receive(cob_id, data, conf.sync_overflow)
        if received is None:
            return
        counter, missed = received
        if self._collisions.last is not None:
            self._collisions.check_clear(now)
        if state is not _OPERATIONAL:
            return
        self._rpdo.end_period(missed, conf)
        watchdog = self._watchdog
        if watchdog.tripped and watchdog.cause == "sync":
            watchdog.recover(now)
        watchdog.sync_last = now
        self._tpdo.sample(counter)

    def _on_sdo(self, cob_id: int, data: bytes) -> None:
        self.counters.rx["sdo"] += 1
        if self._nmt.state is _STOPPED:
            self.counters.rx["sdo_stopped"] += 1  # well formed; CiA 301 serves no SDO in STOPPED: no answer
            return
        if len(data) != 8:
            self._log.malformed("sdo_dlc", cob_id, data, f"SDO requests take 8 bytes, got {len(data)}")
            return
        response = self.sdo.handle(data)
        if response is None:
            return
        self._outbox.emit(self.ids["sdo_tx"], response, "sdo")
        index = data[1] | data[2] << 8
        if response[0] == 0x60 and data[0] >> 5 == 1 and 0x1000 <= index <= 0x1FFF:
            self.counters.comm_writes[f"0x{index:04X}"] += 1
            self._log.limited(
                f"comm_write:{index:04X}",
                self._outbox.now,
                "node %d: SDO write of communication object 0x%04X sub %d [%s]",
                self.node_id,
                index,
                data[3],
                data[4:].hex(" "),
                level=logging.INFO,  # the master configures them at every start; it compares the counts
            )

    def _timers(self, now: float) -> None:
        """What :meth:`poll` does: the heartbeat when due, the watchdog at its
        deadline; remembers until when nothing can be due."""
        conf = self._config()
        quiet = self._nmt.heartbeat(now, conf.heartbeat_period_s)
        if self._nmt.state is _OPERATIONAL and not self._watchdog.tripped:
            due = self._watchdog.check(now, conf, self._sync.last_counter)
            if due < quiet:
                quiet = due
        self._quiet_until = quiet
        self._quiet_generation = self.od.generation
        self._quiet_exact = True
