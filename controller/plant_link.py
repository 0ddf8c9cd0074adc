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
  conflict of its own (``impersonations``).
* **SDO writes** by another master to the objects this link configured or
  relies on (0x1017, 0x1019, 0x1400 sub 5, 0x2000, 0x2003): a conflict, and
  the link writes its value back at once (``comm_restores``, no wait for
  the answer), so a policy that goes on runs with the node as configured.

Input the bus cannot even decode (a junk datagram on the udp_multicast
group) is counted in ``rx_errors`` and dropped, and the bus's own losses
(``kernel_drops``, ``fd_frames_dropped`` of
:class:`service_kit.can_udp.LoopFreeUdpMulticastBus`) are copied into the
counters; each kind of bad input is logged at most once per
:data:`LOG_INTERVAL_S`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import can
import numpy as np
import numpy.typing as npt

from protocol import can_map
from protocol.can_map import (
    OD_RPDO1_COMM,
    OD_RPDO_EVENT_TIMER_SUB,
    OD_SAMPLE_PERIOD,
    OD_WATCHDOG_PERIODS,
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

ECHO_MEMORY: Final[int] = 64
"""Frames sent and not yet echoed remembered per COB-ID (normally one or two)."""
LOG_INTERVAL_S: Final[float] = 10.0
"""Repeated bad input of one kind is logged once per this interval (and counted always)."""
MAX_RX_ERRORS_PER_POLL: Final[int] = 64
"""A bus that raises on every receive ends a poll after this many errors instead of spinning."""
CONFLICT_MEMORY: Final[int] = 64
"""Conflict events kept until :meth:`PlantLink.take_conflicts` (older ones are only counted)."""
CONFLICT_EMCYS: Final[frozenset[int]] = frozenset({int(can_map.EmcyCode.SYNC_CONFLICT), int(can_map.EmcyCode.RPDO_CONFLICT)})
PENDING_MEMORY: Final[int] = 16
"""Heartbeats and EMCYs held for the node's word on them (older ones are judged as they are)."""
_SDO_SIZES: Final[dict[tuple[int, int], int]] = {
    (0x1017, 0): 2,
    (0x1019, 0): 1,
    (OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB): 2,
    (OD_SAMPLE_PERIOD, 0): 4,
    (OD_WATCHDOG_PERIODS, 0): 2,
}
"""The objects the link configures or relies on, with their sizes: written back after a foreign write."""
_COLLISION: Final = int(can_map.EmcyCode.CAN_ID_COLLISION)


@dataclass
class _Held:
    """A frame from the plant's COB-IDs awaiting the node's word (see the module docstring)."""

    kind: str
    """'heartbeat' or 'emcy'"""
    cob_id: int
    data: bytes
    at: float
    syncs: int
    """SYNCs sent when it arrived: a TPDO1 after a later SYNC judges it"""


class PlantFault(RuntimeError):
    """The plant node stopped answering (no heartbeat, no TPDO)."""


class StopRequested(Exception):
    """SIGINT/SIGTERM arrived while waiting for the plant: not a fault."""


class _RxError(Exception):
    """One receive failed (already counted and logged)."""


@dataclass
class PlantLinkCounters:
    syncs_sent: int = 0
    tpdos: int = 0
    tpdo_timeouts: int = 0
    extra_tpdos: int = 0
    stale_tpdos: int = 0
    rpdos_sent: int = 0
    heartbeats: int = 0
    emergencies: int = 0
    malformed: int = 0
    outputs_clipped: int = 0
    rx_errors: int = 0
    """received datagrams/frames the bus could not decode (dropped)"""
    own_echoes: int = 0
    """our own frames seen again (udp_multicast loopback)"""
    foreign_sync: int = 0
    """SYNC frames this link did not send: a second SYNC producer"""
    foreign_nmt: int = 0
    """NMT commands this link did not send"""
    foreign_rpdo: int = 0
    """RPDO1 frames to the node this link did not send"""
    foreign_sdo: int = 0
    """SDO requests to the node this link did not send"""
    foreign_sdo_reads: int = 0
    """of those, reads (uploads): counted, not a conflict (they change nothing)"""
    conflict_emcys: int = 0
    """SYNC_CONFLICT / RPDO_CONFLICT emergencies from the plant (not disowned by it)"""
    comm_resets: int = 0
    """NMT RESET_COMMUNICATION sent before starting the node"""
    surplus_tpdos: int = 0
    """TPDO1 frames beyond one per SYNC sent (one late answer allowed): another node answers on the plant's TPDO1"""
    ambiguous_samples: int = 0
    """ticks whose TPDO1 came twice before it was taken: no sample (the loop holds the last one)"""
    forged_heartbeats: int = 0
    """heartbeats on the plant's COB-ID contradicted by the plant (its EMCY 0x8150, a later TPDO1 or heartbeat)"""
    forged_emcys: int = 0
    """EMCYs on the plant's COB-ID the plant disowned (its EMCY 0x8150)"""
    impersonations: int = 0
    """EMCY CAN_ID_COLLISION from the plant: frames on its COB-IDs it did not send"""
    comm_restores: int = 0
    """SDO writes of a configured object sent back after another master's write"""
    kernel_drops: int = 0
    """datagrams the kernel dropped for a full receive buffer (the bus's count)"""
    fd_frames_dropped: int = 0
    """CAN FD frames the bus dropped (the rig speaks classic CAN)"""

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))


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
        self._sdo_response: bytes | None = None
        self._bootups = 0
        self._echoes = echoing_bus(self.bus)
        self._sent: dict[int, deque[bytes]] = {
            cob_id: deque(maxlen=ECHO_MEMORY) for cob_id in (can_map.NMT_COB_ID, can_map.SYNC_COB_ID, self._rpdo1, self._sdo_rx)
        }
        self._foreign_kind = {can_map.NMT_COB_ID: "nmt", can_map.SYNC_COB_ID: "sync", self._rpdo1: "rpdo", self._sdo_rx: "sdo"}
        self._conflicts: deque[str] = deque(maxlen=CONFLICT_MEMORY)
        self._logged_at: dict[str, float] = {}
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
        self._held: deque[_Held] = deque(maxlen=PENDING_MEMORY)
        self._configured: dict[tuple[int, int], int] = {}
        """values of the objects in _SDO_SIZES as this link configured or found them at start"""
        self._loss_bus = self.bus if hasattr(self.bus, "kernel_drops") else None

    def _now(self) -> float:
        return float(self.clock())  # type: ignore[operator]

    def _send(self, arbitration_id: int, data: bytes) -> None:
        if self._echoes:
            sent = self._sent.get(arbitration_id)
            if sent is not None:
                sent.append(bytes(data))
        if self._send_frame is not None:
            self._send_frame(arbitration_id, data)
            return
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def _log_limited(self, kind: str, fmt: str, *args: object) -> None:
        """WARNING at most once per :data:`LOG_INTERVAL_S` per kind."""
        now = self._now()
        last = self._logged_at.get(kind)
        if last is None or now - last >= LOG_INTERVAL_S:
            self._logged_at[kind] = now
            log.warning(fmt + " (further ones counted, logged every %.0f s)", *args, LOG_INTERVAL_S)

    def _is_echo(self, cob_id: int, data: bytes) -> bool:
        """True when ``data`` on ``cob_id`` is one of our own frames coming back.
        Echoes return in send order, so the frames sent before the matching one
        are forgotten (their echoes were lost)."""
        sent = self._sent[cob_id]
        for i, d in enumerate(sent):
            if d == data:
                for _ in range(i + 1):
                    sent.popleft()
                return True
        return False

    def _conflict(self, detail: str) -> None:
        self._conflicts.append(detail)
        self._log_limited(f"conflict:{detail.split(':')[0]}", "CAN conflict: %s", detail)

    def _stamp(self, msg: can.Message) -> str:
        """A frame's evidence: COB-ID, data and arrival time (the bus's timestamp, else the link's clock)."""
        at = msg.timestamp if msg.timestamp else self._now()
        return f"id 0x{msg.arbitration_id:03X} [{bytes(msg.data).hex(' ')}] at {at:.6f} s"

    def take_conflicts(self) -> list[str]:
        """Conflicts seen since the last call (foreign master frames, forged plant frames, the plant's
        conflict EMCYs), each with its evidence. Also copies the bus's loss counters."""
        bus = self._loss_bus
        if bus is not None:
            self.counters.kernel_drops = int(bus.kernel_drops)
            self.counters.fd_frames_dropped = int(getattr(bus, "fd_frames_dropped", 0))
        if not self._conflicts:
            return []
        out = list(self._conflicts)
        self._conflicts.clear()
        return out

    def _check_foreign(self, msg: can.Message) -> bool:
        """True when ``msg`` is a master's frame (ours echoed, or another master's: counted)."""
        cob_id = msg.arbitration_id
        kind = self._foreign_kind.get(cob_id)
        if kind is None:
            return False
        data = bytes(msg.data)
        if self._is_echo(cob_id, data):
            self.counters.own_echoes += 1
            return True
        if kind == "nmt" and len(data) == 2 and data[1] not in (0, self.node_id):
            return True  # a command for another node: not ours to judge
        setattr(self.counters, f"foreign_{kind}", getattr(self.counters, f"foreign_{kind}") + 1)
        if kind == "sync":
            self._tpdo_credit += 1  # the node answers it too
        if kind == "sdo":
            return self._foreign_sdo(msg, data)
        what = {"sync": "SYNC", "nmt": "NMT command", "rpdo": "RPDO1"}[kind]
        self._conflict(f"foreign {kind}: a {what} this controller did not send, {self._stamp(msg)}")
        return True

    def _foreign_sdo(self, msg: can.Message, data: bytes) -> bool:
        """Another master's SDO request: a read is counted; anything else is a conflict, and a write of
        an object this link configured is undone at once (the node as configured, whatever the policy)."""
        ccs = data[0] >> 5 if data else -1
        if ccs in (2, 3):  # initiate upload / upload segment: reads change nothing
            self.counters.foreign_sdo_reads += 1
            return True
        index, sub = (data[1] | data[2] << 8, data[3]) if len(data) >= 4 else (-1, -1)
        what = f"a write of 0x{index:04X}:{sub}" if ccs == 1 else "an SDO request"
        if ccs == 1 and len(data) == 8 and data[0] & 0x02:  # expedited: the value is in the frame
            n = 4 - ((data[0] >> 2) & 0x3) if data[0] & 0x01 else 4
            what += f" = {int.from_bytes(data[4 : 4 + n], 'little')}"
        self._conflict(f"foreign sdo: {what} this controller did not send, {self._stamp(msg)}")
        value = self._configured.get((index, sub))
        if ccs == 1 and value is not None and self._running:
            self._sdo_write_back(index, sub, value, _SDO_SIZES[(index, sub)])
        return True

    def _sdo_write_back(self, index: int, sub: int, value: int, size: int) -> None:
        """Expedited download of this link's value, without waiting for the answer (the loop runs on)."""
        command = 0x23 | ((4 - size) << 2)
        self._send(self._sdo_rx, bytes([command, index & 0xFF, index >> 8, sub]) + int(value).to_bytes(size, "little").ljust(4, b"\x00"))
        self.counters.comm_restores += 1
        self._log_limited(f"restore:{index:04X}", "wrote 0x%04X:%d = %d back after another master changed it", index, sub, value)

    # --- frames from the plant's COB-IDs, judged while running -------------------------------

    def _on_tpdo1(self, msg: can.Message, words: tuple[int, int, int, int]) -> None:
        if self._running:
            if self._tpdo_credit > 0:
                self._tpdo_credit -= 1
            else:
                self.counters.surplus_tpdos += 1
                prev = self._last_tpdo
                self._conflict(
                    "surplus tpdo1: more TPDO1 than SYNCs, another node answers on the plant's COB-ID: "
                    f"{self._stamp(msg)} after {self._stamp(prev) if prev is not None else 'none'}"
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
        the node has had its word on the frames held before that SYNC."""
        sent = self.counters.syncs_sent
        keep: deque[_Held] = deque(maxlen=PENDING_MEMORY)
        for h in self._held:
            if h.syncs >= sent:
                keep.append(h)
            elif h.kind == "heartbeat" and by_tpdo:
                self._forged(h, "the plant answered a later SYNC")
            elif h.kind == "heartbeat":
                self._held = keep
                self.node_state = can_map.decode_heartbeat(h.data)
                self._running = False
                raise PlantFault(f"plant node left OPERATIONAL (heartbeat says {self.node_state.name}, and SYNC {self.sync_counter} got no TPDO1)")
            else:  # an EMCY the node has not disowned: the plant's own
                emcy = can_map.decode_emcy(h.data)
                if emcy.code in CONFLICT_EMCYS:
                    self._plant_conflict_emcy(emcy)
        self._held = keep

    def _forged(self, h: _Held, why: str) -> None:
        what = "heartbeat " + can_map.NmtState(h.data[0] & 0x7F).name if h.kind == "heartbeat" else "EMCY " + can_map.decode_emcy(h.data).name
        if h.kind == "heartbeat":
            self.counters.forged_heartbeats += 1
        else:
            self.counters.forged_emcys += 1
        self._conflict(f"forged {h.kind}: {what} id 0x{h.cob_id:03X} [{h.data.hex(' ')}] at {h.at:.6f} s is not the plant's ({why})")

    def _plant_conflict_emcy(self, emcy: can_map.Emergency) -> None:
        self.counters.conflict_emcys += 1
        self._conflict(f"plant EMCY {emcy.name}: the plant sees a second master")

    def _on_collision(self, emcy: can_map.Emergency, msg: can.Message) -> None:
        """The plant's EMCY CAN_ID_COLLISION: a frame on its COB-IDs it did not send."""
        cob_id, dlc, head = can_map.decode_collision_evidence(emcy.vendor)
        self.counters.impersonations += 1
        for h in list(self._held):
            if h.cob_id == cob_id and h.data[: len(head)] == head:
                self._held.remove(h)
                self._forged(h, "the plant disowns it by EMCY CAN_ID_COLLISION")
                return
        self._conflict(f"impersonation: the plant reports a frame id 0x{cob_id:03X} DLC {dlc} [{head.hex(' ')}...] it did not send ({self._stamp(msg)})")

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
            s0, s1 = self.send_output_values(volts.tolist())
            return np.array((s0, s1), dtype=np.bool_)
        data, clipped = can_map.volts_to_output_frame(volts)
        self._send(self._rpdo1, data)
        self.counters.rpdos_sent += 1
        self.counters.outputs_clipped += int(np.count_nonzero(clipped))
        return clipped

    def send_output_values(self, volts: list[float]) -> tuple[bool, bool]:
        """:meth:`send_outputs` of two plain floats (the loop's per-tick form):
        can_map.volts_to_output_frame on plain ints (the codes are clipped to
        12 bits, so ``code << 4`` always fits the INT16 word); returns which
        were clipped."""
        (c0, c1), (s0, s1) = can_map.DAC12_VALUES(volts)
        self._send(self._rpdo1, can_map.encode_analog_outputs_values(c0 << _DAC_SHIFT, c1 << _DAC_SHIFT))
        counters = self.counters
        counters.rpdos_sent += 1
        counters.outputs_clipped += s0 + s1
        return s0, s1

    def send_output_codes(self, c0: int, c1: int) -> None:
        """RPDO1 of two D/A codes already quantized by the law
        (:func:`controller.fast_tick.law_tick`, in ``DAC12``'s range):
        :meth:`send_output_values` of the volts ``c * lsb`` those codes stand
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
                        self._held.append(_Held("heartbeat", msg.arbitration_id, bytes(msg.data), msg.timestamp or self._now(), self.counters.syncs_sent))
                        return
                    for h in [h for h in self._held if h.kind == "heartbeat"]:
                        self._held.remove(h)
                        self._forged(h, "the plant's next heartbeat says OPERATIONAL")
                self.node_state = state
                if state is NmtState.BOOT_UP:
                    self._bootups += 1
            elif msg.arbitration_id == self._sdo_tx:
                self._sdo_response = bytes(msg.data)
            elif msg.arbitration_id == self._emcy:
                emcy = can_map.decode_emcy(msg.data)
                self.emergencies.append(emcy)
                self.counters.emergencies += 1
                self._log_limited(f"emcy:{emcy.code}", "plant EMCY %s (0x%04x), register 0x%02x", emcy.name, emcy.code, emcy.register)
                if emcy.code == _COLLISION:
                    self._on_collision(emcy, msg)
                elif self._running and emcy.code != 0:  # held: the node may disown it
                    self._held.append(_Held("emcy", msg.arbitration_id, bytes(msg.data), msg.timestamp or self._now(), self.counters.syncs_sent))
                elif emcy.code in CONFLICT_EMCYS:
                    self._plant_conflict_emcy(emcy)
        except (FrameError, ValueError) as exc:
            self._malformed(msg, exc)

    def _malformed(self, msg: can.Message, exc: Exception) -> None:
        self.counters.malformed += 1
        self._log_limited(f"malformed:{msg.arbitration_id:x}", "malformed frame 0x%03x from the plant: %s", msg.arbitration_id, exc)

    def _recv(self, timeout: float) -> can.Message | None:
        """One frame, or None; what the bus cannot decode is counted and dropped
        (python-can raises CanOperationError for a junk udp_multicast datagram)."""
        try:
            return self.bus.recv(timeout=timeout)
        except (can.CanError, OSError, ValueError, TypeError) as exc:
            self.counters.rx_errors += 1
            cause = exc.__cause__ or exc
            self._log_limited(f"rx:{type(cause).__name__}", "dropped undecodable CAN input (%d so far): %s: %s", self.counters.rx_errors, exc, cause)
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

    def wait_for_node(self, timeout: float, stop: threading.Event | None = None) -> NmtState:
        """Wait for the node's heartbeat (its boot-up or a periodic one)."""
        deadline = self._now() + timeout
        while self.last_heartbeat is None:
            if stop is not None and stop.is_set():
                raise StopRequested("stopped while waiting for the plant")
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"no heartbeat from plant node {self.node_id} within {timeout:.1f} s: is ralf-plant running on the same CAN channel?")
            self.poll(timeout=min(remaining, 0.1))
        assert self.node_state is not None
        return self.node_state

    def reset_communication(self, timeout: float, stop: threading.Event | None = None) -> None:
        """NMT RESET_COMMUNICATION, then wait for the node's boot-up: whatever
        state an earlier (or a rogue) master left it in (STOPPED, a changed
        heartbeat or 0x1019), it is PRE-OPERATIONAL with its communication
        objects at their defaults afterwards. The application objects
        (0x2000-0x2FFF, 0x6000-) keep their values: the plant is not reset."""
        bootups = self._bootups
        self.nmt(NmtCommand.RESET_COMMUNICATION)
        self.counters.comm_resets += 1
        deadline = self._now() + timeout
        while self._bootups == bootups:
            if stop is not None and stop.is_set():
                raise StopRequested("stopped while resetting the plant node's communication")
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"plant node {self.node_id} did not boot up after NMT reset-communication within {timeout:.1f} s")
            self.poll(timeout=min(remaining, 0.05))

    def start_node(self, timeout: float, stop: threading.Event | None = None, sample_period_s: float | None = None) -> None:
        """Reset the node's communication (NMT, so a rogue STOP or another
        master's settings do not block this run), configure its sample period
        by SDO (object 0x2000, so plant, watchdog and controller agree on it)
        and RPDO1's event timer (0x1400 sub 5 = the SYNC watchdog time, so a
        foreign SYNC stream cannot keep the valves open if this controller
        freezes), NMT start, then wait until the heartbeat says operational."""
        self.wait_for_node(timeout, stop)
        self.reset_communication(timeout, stop)
        self._configured = {key: self.sdo_read(*key) for key in ((0x1017, 0), (0x1019, 0), (OD_WATCHDOG_PERIODS, 0))}
        if sample_period_s is not None:
            period_us = round(sample_period_s * 1e6)
            self.sdo_write_u32(OD_SAMPLE_PERIOD, 0, period_us)
            # RPDO1 is cyclic from here on: its event timer (deadline monitoring) = the SYNC watchdog time
            timer_ms = min(0xFFFF, math.ceil(self._configured[(OD_WATCHDOG_PERIODS, 0)] * sample_period_s * 1e3))
            self.sdo_write(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, timer_ms, 2)
            self._configured[(OD_SAMPLE_PERIOD, 0)] = period_us
            self._configured[(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB)] = timer_ms
        deadline = self._now() + timeout
        self.nmt(NmtCommand.START)
        while self.node_state != NmtState.OPERATIONAL:
            if stop is not None and stop.is_set():
                raise StopRequested("stopped while starting the plant")
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"plant node {self.node_id} did not become operational (state {self.node_state})")
            self.poll(timeout=min(remaining, 0.05))
            if self.node_state != NmtState.OPERATIONAL and self.counters.heartbeats and remaining < timeout / 2:
                self.nmt(NmtCommand.START)
        self.discard_pending()
        self._tpdo_credit = 0
        self._held.clear()
        self._running = True

    def _sdo(self, request: bytes, what: str, timeout: float) -> bytes:
        """Send an expedited SDO request and return the node's answer to it
        (an answer for another object, e.g. to someone else's request, is skipped)."""
        self._sdo_response = None
        self._send(self._sdo_rx, request)
        deadline = self._now() + timeout
        while True:
            reply = self._sdo_response
            if reply is not None and reply[1:4] == request[1:4]:
                break
            self._sdo_response = None
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"no SDO answer from the plant node {what}")
            self.poll(timeout=min(remaining, 0.05))
        if reply[0] == 0x80:
            code = int.from_bytes(reply[4:8], "little")
            raise PlantFault(f"the plant node refused {what} (SDO abort 0x{code:08X})")
        return reply

    def sdo_write(self, index: int, subindex: int, value: int, size: int = 4, timeout: float = 1.0) -> None:
        """Expedited SDO download of a ``size``-byte unsigned value (CiA 301); an
        abort or no answer is a :class:`PlantFault` naming the object."""
        command = 0x23 | ((4 - size) << 2)
        data = bytes([command, index & 0xFF, index >> 8, subindex]) + int(value).to_bytes(size, "little").ljust(4, b"\x00")
        reply = self._sdo(data, f"writing 0x{index:04X}:{subindex} = {value}", timeout)
        if reply[0] != 0x60:
            raise PlantFault(f"unexpected SDO answer {reply.hex()} writing 0x{index:04X}:{subindex}")

    def sdo_write_u32(self, index: int, subindex: int, value: int, timeout: float = 1.0) -> None:
        self.sdo_write(index, subindex, value, 4, timeout)

    def sdo_read(self, index: int, subindex: int, timeout: float = 1.0) -> int:
        """Expedited SDO upload of an unsigned value (up to 4 bytes)."""
        what = f"reading 0x{index:04X}:{subindex}"
        reply = self._sdo(bytes([0x40, index & 0xFF, index >> 8, subindex, 0, 0, 0, 0]), what, timeout)
        if reply[0] & 0xE2 != 0x42:
            raise PlantFault(f"unexpected SDO answer {reply.hex()} {what}")
        n = 4 - ((reply[0] >> 2) & 0x3) if reply[0] & 0x01 else 4
        return int.from_bytes(reply[4 : 4 + n], "little")

    def heartbeat_age(self) -> float:
        return float("inf") if self.last_heartbeat is None else self._now() - self.last_heartbeat
