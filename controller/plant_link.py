"""The controller's side of the CAN bus: a small CANopen master for the
plant's analog I/O node (NMT start, SYNC producer, TPDO consumer, RPDO
producer, heartbeat consumer, EMCY consumer)."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import can
import numpy as np
import numpy.typing as npt

from protocol import can_map
from protocol.can_map import OD_SAMPLE_PERIOD, NmtCommand, NmtState
from protocol.errors import FrameError

log = logging.getLogger(__name__)


class PlantFault(RuntimeError):
    """The plant node stopped answering (no heartbeat, no TPDO)."""


class StopRequested(Exception):
    """SIGINT/SIGTERM arrived while waiting for the plant: not a fault."""


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
    emergencies: list[can_map.Emergency] = field(default_factory=list)
    _pending_tpdo: npt.NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        ids = can_map.cob_ids(self.node_id)
        self._tpdo1 = ids["tpdo1"]
        self._rpdo1 = ids["rpdo1"]
        self._heartbeat = ids["heartbeat"]
        self._emcy = ids["emcy"]
        self._sdo_rx = ids["sdo_rx"]
        self._sdo_tx = ids["sdo_tx"]
        self._sdo_response: bytes | None = None

    def _now(self) -> float:
        return float(self.clock())  # type: ignore[operator]

    def _send(self, arbitration_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def nmt(self, command: NmtCommand) -> None:
        self._send(can_map.NMT_COB_ID, can_map.encode_nmt(command, self.node_id))

    def send_sync(self) -> int:
        """Emit the next SYNC; returns its counter (1..240). A TPDO still
        waiting (a late answer to an earlier SYNC) is read and dropped first,
        so a tick never takes the previous tick's sample."""
        self.poll(timeout=0.0)
        if self._pending_tpdo is not None:
            self._pending_tpdo = None
            self.counters.stale_tpdos += 1
        self.sync_counter = can_map.next_sync_counter(self.sync_counter)
        self._send(can_map.SYNC_COB_ID, can_map.encode_sync(self.sync_counter))
        self.counters.syncs_sent += 1
        return self.sync_counter

    def skip_sync(self) -> None:
        """Fault injection: advance the SYNC counter without sending the frame."""
        self.sync_counter = can_map.next_sync_counter(self.sync_counter)

    def send_outputs(self, volts: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """RPDO1 with two valve voltages; returns which were clipped to the D/A range."""
        data, clipped = can_map.volts_to_output_frame(volts)
        self._send(self._rpdo1, data)
        self.counters.rpdos_sent += 1
        self.counters.outputs_clipped += int(np.count_nonzero(clipped))
        return clipped

    def _dispatch(self, msg: can.Message) -> None:
        """Handle one received frame (TPDO kept for the caller, others consumed)."""
        if msg.is_error_frame or msg.is_remote_frame:
            return
        try:
            if msg.arbitration_id == self._tpdo1:
                words = can_map.decode_analog_inputs_16(msg.data)
                if self._pending_tpdo is not None:
                    self.counters.extra_tpdos += 1
                self._pending_tpdo = words
                self.counters.tpdos += 1
            elif msg.arbitration_id == self._heartbeat:
                self.node_state = can_map.decode_heartbeat(msg.data)
                self.last_heartbeat = self._now()
                self.counters.heartbeats += 1
            elif msg.arbitration_id == self._sdo_tx:
                self._sdo_response = bytes(msg.data)
            elif msg.arbitration_id == self._emcy:
                emcy = can_map.decode_emcy(msg.data)
                self.emergencies.append(emcy)
                self.counters.emergencies += 1
                log.warning("plant EMCY %s (0x%04x), register 0x%02x", emcy.name, emcy.code, emcy.register)
        except FrameError as exc:
            self.counters.malformed += 1
            log.warning("malformed frame 0x%03x from the plant: %s", msg.arbitration_id, exc)

    def poll(self, timeout: float = 0.0) -> None:
        """Read every frame already waiting (and wait up to ``timeout`` for the first)."""
        msg = self.bus.recv(timeout=timeout)
        while msg is not None:
            self._dispatch(msg)
            msg = self.bus.recv(timeout=0.0)

    def wait_tpdo(self, timeout: float) -> npt.NDArray[np.int64] | None:
        """The TPDO answering the last SYNC, or None after ``timeout`` seconds."""
        deadline = self._now() + timeout
        while self._pending_tpdo is None:
            remaining = deadline - self._now()
            if remaining <= 0:
                self.counters.tpdo_timeouts += 1
                return None
            msg = self.bus.recv(timeout=remaining)
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

    def start_node(self, timeout: float, stop: threading.Event | None = None, sample_period_s: float | None = None) -> None:
        """Configure the node's sample period by SDO (object 0x2000, so plant,
        watchdog and controller agree on it), NMT start, then wait until the
        heartbeat says operational."""
        self.wait_for_node(timeout, stop)
        if sample_period_s is not None:
            self.sdo_write_u32(OD_SAMPLE_PERIOD, 0, round(sample_period_s * 1e6))
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

    def sdo_write_u32(self, index: int, subindex: int, value: int, timeout: float = 1.0) -> None:
        """Expedited SDO download of a 32-bit value (CiA 301); an abort or no
        answer is a :class:`PlantFault` naming the object."""
        self._sdo_response = None
        data = bytes([0x23, index & 0xFF, index >> 8, subindex]) + int(value).to_bytes(4, "little")
        self._send(self._sdo_rx, data)
        deadline = self._now() + timeout
        while self._sdo_response is None:
            remaining = deadline - self._now()
            if remaining <= 0:
                raise PlantFault(f"no SDO answer from the plant node writing 0x{index:04X}:{subindex}")
            self.poll(timeout=min(remaining, 0.05))
        reply = self._sdo_response
        if reply[0] == 0x80:
            code = int.from_bytes(reply[4:8], "little")
            raise PlantFault(f"the plant node refused 0x{index:04X}:{subindex} = {value} (SDO abort 0x{code:08X})")
        if reply[0] != 0x60 or reply[1:4] != data[1:4]:
            raise PlantFault(f"unexpected SDO answer {reply.hex()} writing 0x{index:04X}:{subindex}")

    def heartbeat_age(self) -> float:
        return float("inf") if self.last_heartbeat is None else self._now() - self.last_heartbeat
