"""What the controller's link watches on the CAN bus (see
:mod:`controller.plant_link`'s docstring for the rules): which frames are
its own coming back, the conflicts it has seen with their evidence, and the
plant's heartbeats and EMCYs held until the node had its word on them."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Final

import can

from controller.plant_link_counters import PlantLinkCounters
from protocol import can_map
from protocol.can_map import NmtState

log = logging.getLogger("controller.plant_link")

ECHO_MEMORY: Final[int] = 64
"""Frames sent and not yet echoed remembered per COB-ID (normally one or two)."""
LOG_INTERVAL_S: Final[float] = 10.0
"""Repeated bad input of one kind is logged once per this interval (and counted always)."""
CONFLICT_MEMORY: Final[int] = 64
"""Conflict events kept until :meth:`ConflictLog.take` (older ones are only counted)."""
CONFLICT_EMCYS: Final[frozenset[int]] = frozenset({int(can_map.EmcyCode.SYNC_CONFLICT), int(can_map.EmcyCode.RPDO_CONFLICT)})
PENDING_MEMORY: Final[int] = 16
"""Heartbeats and EMCYs held for the node's word on them (older ones are judged as they are)."""


class ConflictLog:
    """Conflicts with their evidence, kept until taken; bad input logged at most once per kind and interval."""

    def __init__(self, now: Callable[[], float]) -> None:
        self._now = now
        self.conflicts: deque[str] = deque(maxlen=CONFLICT_MEMORY)
        self._logged_at: dict[str, float] = {}

    def log_limited(self, kind: str, fmt: str, *args: object) -> None:
        """WARNING at most once per :data:`LOG_INTERVAL_S` per kind."""
        now = self._now()
        last = self._logged_at.get(kind)
        if last is None or now - last >= LOG_INTERVAL_S:
            self._logged_at[kind] = now
            log.warning(fmt + " (further ones counted, logged every %.0f s)", *args, LOG_INTERVAL_S)

    def add(self, detail: str) -> None:
        self.conflicts.append(detail)
        self.log_limited(f"conflict:{detail.split(':')[0]}", "CAN conflict: %s", detail)

    def stamp(self, msg: can.Message) -> str:
        """A frame's evidence: COB-ID, data and arrival time (the bus's timestamp, else the link's clock)."""
        at = msg.timestamp if msg.timestamp else self._now()
        return f"id 0x{msg.arbitration_id:03X} [{bytes(msg.data).hex(' ')}] at {at:.6f} s"

    def take(self) -> list[str]:
        """The conflicts since the last call."""
        if not self.conflicts:
            return []
        out = list(self.conflicts)
        self.conflicts.clear()
        return out


class EchoFilter:
    """The frames this link sent on the masters' COB-IDs and not yet seen again
    (udp_multicast loops a sender's frames back to it, in order)."""

    def __init__(self, cob_ids: Iterable[int], echoes: bool) -> None:
        self.echoes = echoes
        self._sent: dict[int, deque[bytes]] = {cob_id: deque(maxlen=ECHO_MEMORY) for cob_id in cob_ids}

    def note_sent(self, cob_id: int, data: bytes) -> None:
        if self.echoes:
            sent = self._sent.get(cob_id)
            if sent is not None:
                sent.append(bytes(data))

    def is_echo(self, cob_id: int, data: bytes) -> bool:
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


class HeldFrames:
    """The plant's heartbeats (other than OPERATIONAL) and EMCYs held while
    running, judged forged or real once the node had its word on them."""

    def __init__(self, conflicts: ConflictLog, counters: PlantLinkCounters) -> None:
        self.conflicts = conflicts
        self.counters = counters
        self.frames: deque[_Held] = deque(maxlen=PENDING_MEMORY)
        self.model_dead: str | None = None
        """Set once the plant reported its model dead (EMCY PLANT_MODEL_FAULT of a cause in
        :data:`protocol.can_map.MODEL_DEAD_CAUSES`, not disowned): what it said."""

    def __len__(self) -> int:
        return len(self.frames)

    def clear(self) -> None:
        self.frames.clear()

    def hold(self, kind: str, msg: can.Message, at: float, syncs: int) -> None:
        self.frames.append(_Held(kind, msg.arbitration_id, bytes(msg.data), at, syncs))

    def judge(self, syncs_sent: int, by_tpdo: bool) -> NmtState | None:
        """A TPDO1 answering a SYNC sent after a held frame (``by_tpdo``), or a
        SYNC left unanswered: the node has had its word on the frames held
        before that SYNC. Returns the state of a real heartbeat (the node left
        OPERATIONAL: the caller faults), else None."""
        keep: deque[_Held] = deque(maxlen=PENDING_MEMORY)
        for h in self.frames:
            if h.syncs >= syncs_sent:
                keep.append(h)
            elif h.kind == "heartbeat" and by_tpdo:
                self.forged(h, "the plant answered a later SYNC")
            elif h.kind == "heartbeat":
                self.frames = keep
                return can_map.decode_heartbeat(h.data)
            else:  # an EMCY the node has not disowned: the plant's own
                emcy = can_map.decode_emcy(h.data)
                if emcy.code in CONFLICT_EMCYS:
                    self.plant_conflict_emcy(emcy)
                elif emcy.code == can_map.EmcyCode.PLANT_MODEL_FAULT:
                    self.plant_model_fault(emcy)
        self.frames = keep
        return None

    def heartbeat_operational(self) -> None:
        """The plant's next heartbeat says OPERATIONAL: the held heartbeats were forged."""
        for h in [h for h in self.frames if h.kind == "heartbeat"]:
            self.frames.remove(h)
            self.forged(h, "the plant's next heartbeat says OPERATIONAL")

    def forged(self, h: _Held, why: str) -> None:
        what = "heartbeat " + can_map.NmtState(h.data[0] & 0x7F).name if h.kind == "heartbeat" else "EMCY " + can_map.decode_emcy(h.data).name
        if h.kind == "heartbeat":
            self.counters.forged_heartbeats += 1
        else:
            self.counters.forged_emcys += 1
        self.conflicts.add(f"forged {h.kind}: {what} id 0x{h.cob_id:03X} [{h.data.hex(' ')}] at {h.at:.6f} s is not the plant's ({why})")

    def plant_model_fault(self, emcy: can_map.Emergency) -> None:
        """The plant's EMCY PLANT_MODEL_FAULT: counted; a cause that ends the model marks it dead."""
        self.counters.plant_model_faults += 1
        cause = emcy.vendor[0] if emcy.vendor else 0
        if cause in can_map.MODEL_DEAD_CAUSES:
            self.counters.plant_model_dead += 1
            self.model_dead = f"EMCY PLANT_MODEL_FAULT, cause {cause} ({can_map.MODEL_FAULT_CAUSES[cause]}): no further model steps, samples frozen"

    def plant_conflict_emcy(self, emcy: can_map.Emergency) -> None:
        self.counters.conflict_emcys += 1
        self.conflicts.add(f"plant EMCY {emcy.name}: the plant sees a second master")

    def on_collision(self, emcy: can_map.Emergency, msg: can.Message) -> None:
        """The plant's EMCY CAN_ID_COLLISION: a frame on its COB-IDs it did not send."""
        cob_id, dlc, head = can_map.decode_collision_evidence(emcy.vendor)
        self.counters.impersonations += 1
        for h in list(self.frames):
            if h.cob_id == cob_id and h.data[: len(head)] == head:
                self.frames.remove(h)
                self.forged(h, "the plant disowns it by EMCY CAN_ID_COLLISION")
                return
        self.conflicts.add(
            f"impersonation: the plant reports a frame id 0x{cob_id:03X} DLC {dlc} [{head.hex(' ')}...] it did not send ({self.conflicts.stamp(msg)})"
        )


class ForeignMasters:
    """Frames on the masters' COB-IDs (NMT, SYNC, RPDO1, SDO requests) that
    this link did not send: another master on the bus."""

    def __init__(
        self,
        node_id: int,
        kinds: dict[int, str],
        echo: EchoFilter,
        conflicts: ConflictLog,
        counters: PlantLinkCounters,
        restore: Callable[[int, int], None],
    ) -> None:
        self.node_id = node_id
        self._kinds = kinds
        """COB-ID -> 'nmt', 'sync', 'rpdo' or 'sdo'."""
        self._echo, self._log, self.counters = echo, conflicts, counters
        self._restore = restore
        """Writes this link's value of an object back after another master's write (if it configured it)."""

    def check(self, msg: can.Message) -> str | None:
        """The kind of master frame ``msg`` is ('nmt', 'sync', 'rpdo', 'sdo': ours
        echoed, or another master's, counted and a conflict), or None: not a master's."""
        cob_id = msg.arbitration_id
        kind = self._kinds.get(cob_id)
        if kind is None:
            return None
        data = bytes(msg.data)
        if self._echo.is_echo(cob_id, data):
            self.counters.own_echoes += 1
            return kind
        if kind == "nmt" and len(data) == 2 and data[1] not in (0, self.node_id):
            return kind  # a command for another node: not ours to judge
        setattr(self.counters, f"foreign_{kind}", getattr(self.counters, f"foreign_{kind}") + 1)
        if kind == "sdo":
            self._foreign_sdo(msg, data)
            return kind
        what = {"sync": "SYNC", "nmt": "NMT command", "rpdo": "RPDO1"}[kind]
        self._log.add(f"foreign {kind}: a {what} this controller did not send, {self._log.stamp(msg)}")
        return kind

    def _foreign_sdo(self, msg: can.Message, data: bytes) -> None:
        """Another master's SDO request: a read is counted; anything else is a conflict, and a write of
        an object this link configured is undone at once (the node as configured, whatever the policy)."""
        ccs = data[0] >> 5 if data else -1
        if ccs in (2, 3):  # initiate upload / upload segment: reads change nothing
            self.counters.foreign_sdo_reads += 1
            return
        index, sub = (data[1] | data[2] << 8, data[3]) if len(data) >= 4 else (-1, -1)
        what = f"a write of 0x{index:04X}:{sub}" if ccs == 1 else "an SDO request"
        if ccs == 1 and len(data) == 8 and data[0] & 0x02:  # expedited: the value is in the frame
            n = 4 - ((data[0] >> 2) & 0x3) if data[0] & 0x01 else 4
            what += f" = {int.from_bytes(data[4 : 4 + n], 'little')}"
        self._log.add(f"foreign sdo: {what} this controller did not send, {self._log.stamp(msg)}")
        if ccs == 1:
            self._restore(index, sub)
