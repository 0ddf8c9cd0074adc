"""The controller's side of the CAN bus: a small CANopen master for the
plant's analog I/O node (NMT start, SYNC producer, TPDO consumer, RPDO
producer, heartbeat consumer, EMCY consumer).

CAN has no authentication, so the link watches the bus instead: it sees
every frame, and knows which it sent itself (udp_multicast loops a sender's
frames back to it, in order: an echo is matched against the frames sent and
not yet seen again; on buses without echoes every such frame is someone
else's). A SYNC, NMT command, RPDO1 or SDO request (other than a read) to
the node that this link did not send is another master on the bus: counted
(``foreign_sync``, ``foreign_nmt``, ``foreign_rpdo``, ``foreign_sdo``), and
queued for :meth:`PlantLink.take_conflicts`, which the service turns into the
``can_conflict`` monitor, each with its evidence (COB-ID, data, arrival time).

Frames that claim to come from the plant are judged too, once the run is
going (after :meth:`PlantLink.start_node`):

* **TPDO1**: the node sends one per SYNC. More TPDO1s since the start
  than SYNCs sent (and foreign SYNCs seen) means another node answers on
  the plant's COB-ID: ``surplus_tpdos``, a conflict with both frames (late
  answers, however many a stalled plant sends in a burst, never exceed the
  SYNCs; each lost one leaves room for one forged frame, which the node
  itself still reports by EMCY CAN_ID_COLLISION);
  a tick whose TPDO1 came twice before it was taken gets no sample
  (``ambiguous_samples``: the loop holds the last one).
* **Heartbeat** other than OPERATIONAL, **conflict EMCYs** (SYNC_CONFLICT,
  RPDO_CONFLICT): held until the node had the chance to contradict them.
  The node answers any frame on its COB-IDs it did not send with EMCY
  CAN_ID_COLLISION (0x8150) carrying that frame's COB-ID and first bytes
  (:mod:`plant_emulator.canopen_node.node`): a heartbeat or EMCY it
  disowns, or a heartbeat STOPPED followed by a TPDO1 answering a later
  SYNC (or by the node's own OPERATIONAL heartbeat), is a forgery
  (``forged_heartbeats``, ``forged_emcys``) and a conflict, not a stop; a
  conflict EMCY not disowned by then is the plant's (``conflict_emcys``). A
  STOPPED or boot-up heartbeat followed by a SYNC without answer is real:
  :class:`PlantFault` "left OPERATIONAL". Every CAN_ID_COLLISION is a
  conflict of its own (``impersonations``). An EMCY PLANT_MODEL_FAULT not
  disowned is counted (``plant_model_faults``); one whose cause ends the
  model (Error, Fatal, Terminate: ``protocol.can_map.MODEL_DEAD_CAUSES``,
  counted in ``plant_model_dead``) is a :class:`PlantFault` "plant model
  dead", as a lost plant: the node still answers, with frozen samples.
* **SDO writes** by another master to the objects this link configured or
  relies on (0x1017, 0x1019, 0x1400 sub 5, 0x2000, 0x2003): a conflict, and
  the link writes its value back at once (``comm_restores``, no wait for
  the answer), so a policy that goes on runs with the node as configured.

Input the bus cannot even decode (a junk datagram on the udp_multicast
group) is counted in ``rx_errors`` and dropped, and the bus's own losses
(``kernel_drops``, ``fd_frames_dropped``, ``junk_frames`` of
:class:`service_kit.can_udp.LoopFreeUdpMulticastBus`) are copied into the
counters; each kind of bad input is logged at most once per
:data:`controller.bus_watch.LOG_INTERVAL_S`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import can
import numpy as np
import numpy.typing as npt

from controller.bus_watch import CONFLICT_EMCYS, ConflictLog, EchoFilter, ForeignMasters, HeldFrames
from controller.can_errors import CanErrorWatch
from controller.config_guard import ConfigGuard
from controller.node_start import configure_node, enter_operational, reset_communication, wait_for_node
from controller.plant_errors import PlantFault, StopRequested
from controller.plant_link_counters import PlantLinkCounters
from controller.sdo_client import SdoClient
from protocol import can_map
from protocol.can_map import (
    NmtCommand,
    NmtState,
)
from protocol.errors import FrameError
from service_kit.can_udp import echoing_bus

__all__ = ["PlantFault", "PlantLink", "PlantLinkCounters", "StopRequested", "echoing_bus"]

_DAC_SHIFT: Final = can_map.DAC12.shift(16)
_SYNC_PAYLOADS: Final = [b""] + [can_map.encode_sync(c) for c in range(1, can_map.SYNC_COUNTER_OVERFLOW + 1)]
"""SYNC payload per counter value (1..240), encoded once."""

log = logging.getLogger(__name__)

MAX_RX_ERRORS_PER_POLL: Final[int] = 64
"""A bus that raises on every receive ends a poll after this many errors instead of spinning."""
_COLLISION: Final = int(can_map.EmcyCode.CAN_ID_COLLISION)
PLANT_FRAMES: Final = ("tpdo1", "heartbeat", "sdo_tx", "emcy")
"""The node's frames the link reads (:func:`can_map.cob_ids` names)."""
MASTER_FRAMES: Final = ("nmt", "sync", "rpdo1", "sdo_rx")
"""A master's frames: the link's own, read back to see another master (:class:`ForeignMasters`)."""


def link_can_filters(node_id: int = can_map.DEFAULT_NODE_ID) -> list[can.typechecking.CanFilter]:
    """python-can filters for exactly the frames :class:`PlantLink` reads: the
    node's :data:`PLANT_FRAMES` and the masters' :data:`MASTER_FRAMES`."""
    ids = can_map.cob_ids(node_id)
    return [{"can_id": ids[name], "can_mask": 0x7FF, "extended": False} for name in PLANT_FRAMES + MASTER_FRAMES]


class _RxError(Exception):
    """One receive failed (already counted and logged)."""


@dataclass
class PlantLink:
    """Master-side frames for node ``node_id`` on ``bus``."""

    bus: can.BusABC
    node_id: int = can_map.DEFAULT_NODE_ID
    clock: object = time.monotonic
    counters: PlantLinkCounters = field(default_factory=PlantLinkCounters)
    sync_counter: int = 0
    node_state: NmtState | None = None
    last_heartbeat: float | None = None
    emergencies: deque[can_map.Emergency] = field(default_factory=lambda: deque(maxlen=256))
    """the latest emergencies (all are counted in ``counters.emergencies``)"""
    _pending_tpdo: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        ids = can_map.cob_ids(self.node_id)
        self._tpdo1 = ids["tpdo1"]
        self._rpdo1 = ids["rpdo1"]
        self._heartbeat = ids["heartbeat"]
        self._emcy = ids["emcy"]
        self._sdo_rx = ids["sdo_rx"]
        self._sdo_tx = ids["sdo_tx"]
        self.bootups = 0
        self._echoes = echoing_bus(self.bus)
        self._echo = EchoFilter((can_map.NMT_COB_ID, can_map.SYNC_COB_ID, self._rpdo1, self._sdo_rx), self._echoes)
        self._log = ConflictLog(self._now)
        kinds = {ids[name]: kind for name, kind in zip(MASTER_FRAMES, ("nmt", "sync", "rpdo", "sdo"), strict=True)}
        self._guard = ConfigGuard(lambda data: self._send(self._sdo_rx, data), lambda: self._running, self._log, self.counters)
        self._foreign = ForeignMasters(self.node_id, kinds, self._echo, self._log, self.counters, self._guard.restore)
        self._sdo = SdoClient(lambda data: self._send(self._sdo_rx, data), lambda timeout: self.poll(timeout=timeout), self._now)
        self._send_frame: Callable[[int, bytes], None] | None = self.bus.send_frame if callable(getattr(type(self.bus), "send_frame", None)) else None  # type: ignore[attr-defined]
        """A wire in this process whose class takes a standard data frame as its
        COB-ID and payload (the co-simulation's :class:`workbench.cosim.DirectCanWire`):
        no frame object built on the per-tick path (0.4 us a frame), no can.Message.
        Asked of the class, so a wrapper that forwards other attributes (the
        recording wire) still sees every frame through its ``send``."""
        self._direct = self._send_frame is not None
        self._running = False
        """True from a successful start_node until this link sends another NMT command: frames on the plant's COB-IDs are judged"""
        self._tpdo_credit = 0
        self._last_tpdo: can.Message | None = None
        self._held = HeldFrames(self._log, self.counters)
        self._loss_bus = self.bus if hasattr(self.bus, "kernel_drops") else None
        self.can_errors = CanErrorWatch(self.bus, self.counters)
        """CAN error states: the plant's EMCY 0x8120/0x8140 and this bus's own (controller.can_errors)."""

    def _now(self) -> float:
        return float(self.clock())  # type: ignore[operator]

    def _send(self, arbitration_id: int, data: bytes) -> None:
        if self._echoes:
            self._echo.note_sent(arbitration_id, data)
        if self._send_frame is not None:
            self._send_frame(arbitration_id, data)
            return
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def take_conflicts(self) -> list[str]:
        """Conflicts seen since the last call (foreign master frames, forged plant frames, the plant's
        conflict EMCYs), each with its evidence. Also copies the bus's loss counters."""
        bus = self._loss_bus
        if bus is not None:
            self.counters.kernel_drops = int(bus.kernel_drops)
            self.counters.fd_frames_dropped = int(getattr(bus, "fd_frames_dropped", 0))
            self.counters.junk_frames = int(getattr(bus, "junk_frames", 0))
        return self._log.take()

    def _check_foreign(self, msg: can.Message) -> bool:
        """True when ``msg`` is a master's frame (ours echoed, or another master's: counted, :class:`ForeignMasters`)."""
        kind = self._foreign.check(msg)
        if kind == "sync":
            self._tpdo_credit += 1  # the node answers it too
        return kind is not None

    # --- frames from the plant's COB-IDs, judged while running -------------------------------

    def _on_tpdo1(self, msg: can.Message, words: tuple[int, int, int, int]) -> None:
        if self._running:
            if self._tpdo_credit > 0:
                self._tpdo_credit -= 1
            else:
                self.counters.surplus_tpdos += 1
                prev = self._last_tpdo
                self._log.add(
                    "surplus tpdo1: more TPDO1 than SYNCs, another node answers on the plant's COB-ID: "
                    f"{self._log.stamp(msg)} after {self._log.stamp(prev) if prev is not None else 'none'}"
                )
                if self._pending_tpdo is not None:  # both still untaken: no telling which is the plant's
                    self._pending_tpdo = None
                    self.counters.ambiguous_samples += 1
                    self._last_tpdo = msg
                    return
            if self._held:
                self._judge_held(by_tpdo=True)
        if self._pending_tpdo is not None:
            self.counters.extra_tpdos += 1
        self._pending_tpdo = words
        self._last_tpdo = msg  # kept by reference: its evidence is written only for a surplus

    def _judge_held(self, by_tpdo: bool) -> None:
        """A TPDO1 answering a SYNC sent after a held frame (``by_tpdo``), or a SYNC left unanswered:
        the node has had its word on the frames held before that SYNC (:meth:`HeldFrames.judge`)."""
        state = self._held.judge(self.counters.syncs_sent, by_tpdo)
        if state is not None:
            self.node_state = state
            self._running = False
            raise PlantFault(f"plant node left OPERATIONAL (heartbeat says {state.name}, and SYNC {self.sync_counter} got no TPDO1)")
        if self._held.model_dead is not None:
            self._running = False
            raise PlantFault(f"plant model dead: {self._held.model_dead}")

    def nmt(self, command: NmtCommand) -> None:
        if command is not NmtCommand.START:
            self._running = False  # the node leaves OPERATIONAL on our word: nothing to judge
        self._send(can_map.NMT_COB_ID, can_map.encode_nmt(command, self.node_id))

    def send_sync(self) -> int:
        """Emit the next SYNC; returns its counter (1..240). A TPDO still
        waiting (a late answer to an earlier SYNC) is read and dropped first,
        so a tick never takes the previous tick's sample."""
        self.poll(timeout=0.0)
        if self._pending_tpdo is not None:
            self._pending_tpdo = None
            self.counters.stale_tpdos += 1
        counter = self.sync_counter = can_map.next_sync_counter(self.sync_counter)
        self._send(can_map.SYNC_COB_ID, _SYNC_PAYLOADS[counter])
        self.counters.syncs_sent += 1
        self._tpdo_credit += 1  # SYNCs sent whose TPDO1 has not come (yet, or lost)
        return counter

    def skip_sync(self) -> None:
        """Fault injection: advance the SYNC counter without sending the frame."""
        self.sync_counter = can_map.next_sync_counter(self.sync_counter)

    def send_outputs(self, volts: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """RPDO1 with two valve voltages; returns which were clipped to the D/A range."""
        if type(volts) is np.ndarray and volts.dtype == np.float64 and volts.shape == (2,):
            # can_map.volts_to_output_frame on plain ints (codes clipped to 12 bits: code << 4 fits INT16)
            (c0, c1), (s0, s1) = can_map.DAC12_VALUES(volts.tolist())
            data, clipped = can_map.encode_analog_outputs_values(c0 << _DAC_SHIFT, c1 << _DAC_SHIFT), np.array((s0, s1), dtype=np.bool_)
        else:
            data, clipped = can_map.volts_to_output_frame(volts)
        self._send(self._rpdo1, data)
        self.counters.rpdos_sent += 1
        self.counters.outputs_clipped += int(np.count_nonzero(clipped))
        return clipped

    def send_output_codes(self, c0: int, c1: int) -> None:
        """RPDO1 of two D/A codes already quantized by the law
                (:func:`controller.fast_tick.law_tick`, in ``DAC12``'s range):
        :meth:`send_outputs` of the volts ``c * lsb`` those codes stand
                for, which quantizes them back to ``c0, c1`` and never clips (tested),
                without the round trip through volts."""
        self._send(self._rpdo1, can_map.encode_analog_outputs_values(c0 << _DAC_SHIFT, c1 << _DAC_SHIFT))
        self.counters.rpdos_sent += 1

    def _dispatch(self, msg: can.Message) -> None:
        """Handle one received frame (TPDO kept for the caller, others consumed)."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        if msg.arbitration_id == self._tpdo1:  # the per-tick frame first (never a master's COB-ID)
            try:
                words = can_map.decode_analog_inputs_16_values(msg.data)
            except (FrameError, ValueError) as exc:
                self._malformed(msg, exc)
                return
            self.counters.tpdos += 1
            if self._running or self._pending_tpdo is not None:
                self._on_tpdo1(msg, words)
                return
            self._pending_tpdo = words
            return
        if self._check_foreign(msg):
            return
        try:
            if msg.arbitration_id == self._heartbeat:
                state = can_map.decode_heartbeat(msg.data)
                self.last_heartbeat = self._now()
                self.counters.heartbeats += 1
                if self._running:
                    if state is not NmtState.OPERATIONAL:  # held for the node's word (module docstring)
                        self._held.hold("heartbeat", msg, msg.timestamp or self._now(), self.counters.syncs_sent)
                        return
                    self._held.heartbeat_operational()
                self.node_state = state
                if state is NmtState.BOOT_UP:
                    self.bootups += 1
            elif msg.arbitration_id == self._sdo_tx:
                self._sdo.response = bytes(msg.data)
            elif msg.arbitration_id == self._emcy:
                emcy = can_map.decode_emcy(msg.data)
                self.emergencies.append(emcy)
                self.counters.emergencies += 1
                self.can_errors.on_emcy(emcy)
                self._log.log_limited(f"emcy:{emcy.code}", "plant EMCY %s (0x%04x), register 0x%02x", emcy.name, emcy.code, emcy.register)
                if emcy.code == _COLLISION:
                    self._held.on_collision(emcy, msg)
                elif self._running and emcy.code != 0:  # held: the node may disown it
                    self._held.hold("emcy", msg, msg.timestamp or self._now(), self.counters.syncs_sent)
                elif emcy.code in CONFLICT_EMCYS:
                    self._held.plant_conflict_emcy(emcy)
        except (FrameError, ValueError) as exc:
            self._malformed(msg, exc)

    def _malformed(self, msg: can.Message, exc: Exception) -> None:
        self.counters.malformed += 1
        self._log.log_limited(f"malformed:{msg.arbitration_id:x}", "malformed frame 0x%03x from the plant: %s", msg.arbitration_id, exc)

    def _recv(self, timeout: float) -> can.Message | None:
        """One frame, or None; what the bus cannot decode is counted and dropped
        (python-can raises CanOperationError for a junk udp_multicast datagram)."""
        try:
            return self.bus.recv(timeout=timeout)
        except (can.CanError, OSError, ValueError, TypeError) as exc:
            self.counters.rx_errors += 1
            cause = exc.__cause__ or exc
            self._log.log_limited(f"rx:{type(cause).__name__}", "dropped undecodable CAN input (%d so far): %s: %s", self.counters.rx_errors, exc, cause)
            raise _RxError from exc

    def poll(self, timeout: float = 0.0) -> None:
        """Read every frame already waiting (and wait up to ``timeout`` for the first)."""
        errors = 0
        while True:
            try:
                msg = self._recv(timeout)
            except _RxError:
                errors += 1
                if errors >= MAX_RX_ERRORS_PER_POLL:
                    return
                timeout = 0.0
                continue
            if msg is None:
                return
            self._dispatch(msg)
            timeout = 0.0

    def wait_tpdo(self, timeout: float) -> tuple[int, int, int, int] | None:
        """The TPDO answering the last SYNC (its four words, plain ints), or
        None after ``timeout`` seconds."""
        words = self._pending_tpdo
        if words is not None:
            self._pending_tpdo = None
            return words
        deadline = self._now() + timeout
        while self._pending_tpdo is None:
            remaining = deadline - self._now()
            if remaining <= 0:
                self.counters.tpdo_timeouts += 1
                if self._held:
                    self._judge_held(by_tpdo=False)  # a held STOPPED/boot-up heartbeat is real: PlantFault
                return None
            try:
                msg = self._recv(remaining)
            except _RxError:
                continue
            if msg is not None:
                self._dispatch(msg)
        words, self._pending_tpdo = self._pending_tpdo, None
        return words

    def discard_pending(self) -> None:
        self._pending_tpdo = None

    def start_node(self, timeout: float, stop: threading.Event | None = None, sample_period_s: float | None = None) -> None:
        """Bring the node up for the run (:mod:`controller.node_start`): its
        heartbeat, NMT reset-communication, the sample period and RPDO1's
        event timer by SDO, NMT start, OPERATIONAL; then frames on the plant's
        COB-IDs are judged."""
        wait_for_node(self, timeout, stop)
        reset_communication(self, timeout, stop)
        self._guard.values = configure_node(self._sdo, sample_period_s)
        enter_operational(self, timeout, stop)
        self.discard_pending()
        self._tpdo_credit = 0
        self._held.clear()
        self._running = True

    def sdo_write(self, index: int, subindex: int, value: int, size: int = 4, timeout: float = 1.0) -> None:
        """Expedited SDO download to the node (:meth:`SdoClient.write`)."""
        self._sdo.write(index, subindex, value, size, timeout)

    def sdo_read(self, index: int, subindex: int, timeout: float = 1.0) -> int:
        """Expedited SDO upload from the node (:meth:`SdoClient.read`)."""
        return self._sdo.read(index, subindex, timeout)

    def heartbeat_age(self) -> float:
        return float("inf") if self.last_heartbeat is None else self._now() - self.last_heartbeat
