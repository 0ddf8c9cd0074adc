"""The co-simulation's CAN bus with a wire: frames take simulated wire time,
arbitrate against a restbus, and reach the other station when their last
bit is gone (``can_bitrate`` set; docs/can-wire.md "In the simulated rig").

:class:`TimedCanWire` replaces :class:`workbench.cosim.DirectCanWire` when a
bit rate is set; the default path keeps the direct wire and its speed. The
bus is :class:`service_kit.can_wire.online.OnlineBus` (the rule of
:func:`service_kit.can_wire.arbitration.simulate`; error frames only when
injected), on its own axis of integer nanoseconds:

* **The wire starts with the run's first SYNC.** The start-up before it
  (boot-up, NMT, the SDO configuration) goes through untimed, as on the
  direct wire. SYNC ``n`` (``n`` = 1, 2, ..., counted from the SYNC
  counters, so a SYNC a link fault keeps off the bus still counts) is
  queued at ``n Ts``: the axis is the plant model's, on which SYNC ``n``
  finds the model at ``n Ts`` without a wire.
* The controller's other frames (RPDO1, NMT, SDO) are queued at its "now":
  the arrival of the last frame it received (it computes in no simulated
  time), never before its last SYNC. Its transmit queue is first in, first
  out (python-can's send queue): a frame contends once the one sent before
  it has won the bus (the plant node and the restbus nodes offer their
  highest-priority frame, as :func:`~service_kit.can_wire.arbitration.simulate`).
* The plant node answers a frame when the frame's last bit is gone: its
  frames (TPDO1, EMCY, SDO answers) are queued then. Its heartbeat goes
  beside the wire, untimed (in the one-process lockstep rig it runs on the
  wall clock: :mod:`workbench.lockstep_wire`).
* The restbus (``can_restbus``: :mod:`service_kit.can_wire.restbus.traffic`,
  its cycle times, start delays, initial values, counters and checksums)
  starts with the first SYNC. Its frames take wire time and arbitrate;
  neither rig station receives them (the rig's acceptance filters).

What the plant sees: the model advances to each frame's arrival rounded to
its sub-step grid (nearest step of ``internal_step_s``, 1 ms by default),
so a SYNC samples the state there and an RPDO1's D/A applies from there
(:attr:`plant_emulator.service.PlantApplication.wire_arrival_ns`).

Errors (off unless injected: :meth:`TimedCanWire.inject_can_errors`, or a fault
scenario's ``can_errors`` through
:func:`service_kit.can_wire.scenario_errors.attach`): the bus model's error
frames, retransmissions and fault confinement, the controller, the plant
and each restbus node a node with its counters. The plant node is told
each change of its error state at the change's time (its CAN controller's
interrupt), before the wire decides its next attempt
(:meth:`plant_emulator.canopen_node.node.CanopenNode.can_error_state`:
EMCY 0x8120, 0x8140 and the error register, its frames queued at that
time); a frame it sends while bus off is refused (its ``tx_errors``), as a
``ralfwire`` bus refuses it. The controller's frames wait in its transmit
queue while it is bus off.

What the controller's deadline sees: a TPDO1 that arrives more than
``TPDO_WINDOW`` of the period after its SYNC was queued is late, as in real
time: the tick gets no sample and holds the last one
(:meth:`TimedCanWire.tpdo_late`, asked by :class:`controller.sync_driver.SyncDriver`).
"""

from __future__ import annotations

from array import array
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from controller.fault_stage import TPDO_WINDOW
from plant_emulator.canopen_node.frames import Frame
from plant_emulator.node import CanopenNode
from plant_emulator.service import PlantApplication
from protocol import can_map
from protocol.errors import ConfigError
from service_kit.can_wire.arbitration import ErrorInjection
from service_kit.can_wire.bits import FrameBits, frame_bits
from service_kit.can_wire.bus_load import BusyInterval, bus_load
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.online import OnlineBus
from service_kit.can_wire.restbus import traffic
from service_kit.can_wire.restbus.traffic import Instance, Restbus, RestbusError
from service_kit.clock import SimulatedScheduler

CONTROLLER = "controller"
PLANT = "plant"
LOAD_WINDOW_NS = 100_000_000
"""The window of the busy share's maximum (100 ms, as ``python -m service_kit.can_wire.bus_load``)."""
RECV_FOREVER_NS = 3600 * 1_000_000_000
"""``recv(None)`` on a wire that the restbus keeps busy: an hour of simulated time, then None."""
DEFAULT_GRID_NS = 1_000_000
"""The plant's sub-step when its model names none (the built-in arm's ``internal_step_s``)."""
RESTBUS_TAG = object()


def rig_identifiers(node_id: int) -> dict[int, str]:
    """The rig's own standard identifiers for node ``node_id``: NMT, SYNC, EMCY, PDOs, SDO, heartbeat
    (:func:`protocol.can_map.cob_ids`) and every frame of ``protocol/ralf.dbc``. XCP runs over UDP/TCP: no CAN id."""
    ids = {cob: f"{name.upper()} of node {node_id}" for name, cob in can_map.cob_ids(node_id).items()}
    for cob, name in traffic.rig_identifiers().items():
        ids.setdefault(cob, name)
    return ids


def load_restbus(path: str, bitrate: int, node_id: int) -> Restbus:
    """The ``can_restbus`` DBC checked for a start beside the rig: ConfigError (one line naming it) when it
    does not parse, its load with the rig's cycle exceeds 100 %, or an identifier is the rig's own."""
    try:
        restbus = traffic.load(Path(path))
    except RestbusError as exc:
        raise ConfigError(f"can_restbus {path}: {exc}") from None
    problems = traffic.check(restbus, bitrate, rig_ids=rig_identifiers(node_id), rig=traffic.rig_cycle())
    if problems:
        raise ConfigError(f"can_restbus {path}: {'; '.join(problems)}")
    return restbus


def _us(values: Sequence[int]) -> dict[str, float | None]:
    """min, p50 (the lower median: a figure seen, never one between two modes) and max of nanosecond figures, in microseconds (None: no figure)."""
    if not values:
        return {"min": None, "p50": None, "max": None}
    median = float(np.percentile(np.asarray(values, dtype=np.int64), 50, method="inverted_cdf"))  # a value the wire saw
    return {"min": min(values) / 1e3, "p50": median / 1e3, "max": max(values) / 1e3}


@dataclass
class WireStats:
    """What the wire saw: every transmission's times and the control cycle's latencies (ns)."""

    starts: array[int] = field(default_factory=lambda: array("q"))
    """Each transmission's SOF, end (intermission included), identifier and bits (with its queuing delay: 32 bytes a frame)."""
    ends: array[int] = field(default_factory=lambda: array("q"))
    ids: array[int] = field(default_factory=lambda: array("i"))
    bits: array[int] = field(default_factory=lambda: array("i"))
    delays: dict[int, array[int]] = field(default_factory=dict)
    """Queuing delay (queued to SOF) per identifier."""
    sync_to_tpdo: list[int] = field(default_factory=list)
    """SYNC queued to its TPDO1 delivered to the controller."""
    sync_to_rpdo: list[int] = field(default_factory=list)
    """SYNC queued to the same tick's RPDO1 delivered to the plant (the control cycle's bus latency)."""
    late_tpdos: int = 0
    first_ns: int | None = None
    plant_refused: int = 0
    """Frames the plant node sent while bus off (refused, with errors on)."""


@dataclass
class SentTag:
    frame: Any
    to_plant: bool
    sync_q: int
    """Queue time of the SYNC the frame belongs to (a TPDO1 answers it, an RPDO1 follows it)."""


class TimedCanWire:
    """:class:`workbench.cosim.DirectCanWire`'s two stations on a timed wire (module docstring)."""

    def __init__(
        self,
        node: CanopenNode | None,
        scheduler: SimulatedScheduler | None,
        app: PlantApplication | None,
        *,
        bitrate: int,
        sample_period_s: float,
        restbus: Restbus | None = None,
        grid_ns: int | None = None,
        node_id: int | None = None,
    ) -> None:
        self.node: Any = node
        self.scheduler: Any = scheduler
        self.app: Any = app
        self.bitrate = bitrate
        self.bus = OnlineBus(bitrate)
        for name in (CONTROLLER, PLANT, *(m.node for m in (restbus.messages if restbus is not None else ()))):
            self.bus.add_node(name)  # every station a node: it acknowledges and counts (with errors on)
        self.ts_ns = round(sample_period_s * 1e9)
        self.grid_ns = grid_ns if grid_ns is not None else grid_of(app)
        self.window_ns = round(TPDO_WINDOW * self.ts_ns)
        self.restbus = restbus
        self.stats = WireStats()
        self._to_master: deque[Any] = deque()
        """Frames for the controller: (arrival ns, or None for an untimed one; the frame; late)."""
        self._timed_for_master = 0
        self._ctrl_fifo: deque[tuple[int, FrameBits, SentTag]] = deque()
        self._ctrl_on_bus = False
        self._started = False
        self._syncs = 0
        self._last_counter: int | None = None
        self._ctrl_now = 0
        self._ctrl_sync_q = 0
        self._plant_sync_q = 0
        self._in_flight: tuple[int, SentTag] | None = None
        self._last_tpdo_late = False
        self._rb_iter: Iterator[Instance] | None = None
        self._rb_next: Instance | None = None
        self._rb_frames: dict[tuple[str, int], FrameBits] = {}
        self._sync_frames: dict[bytes, FrameBits] = {}
        if node_id is None:
            node_id = node.node_id if node is not None else can_map.DEFAULT_NODE_ID
        ids = can_map.cob_ids(node_id)
        self._tpdo1, self._rpdo1, self._heartbeat = ids["tpdo1"], ids["rpdo1"], ids["heartbeat"]
        self.frames_to_node = 0
        self._plant_seen = 0
        self._plant_reported = ErrorState.ACTIVE
        self.frames_to_master = 0

    def inject_can_errors(self, *specs: ErrorInjection) -> None:
        """Error frames on the wire (module docstring); times on the wire's axis (simulated, the plant model's: SYNC n at n Ts)."""
        self.bus.inject(*specs)

    # -- the controller's side (python-can's BusABC as PlantLink uses it) ---------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            raise can.CanOperationError("the co-simulated wire carries the rig's standard data frames only")
        self.send_frame(msg.arbitration_id, bytes(msg.data))

    def send_frame(self, arbitration_id: int, data: bytes) -> None:
        self.frames_to_node += 1
        if arbitration_id == can_map.SYNC_COB_ID:
            self._queue_sync(data)
            return
        if not self._started:  # the start-up: untimed, as on the direct wire
            self._direct(arbitration_id, data)
            return
        q = max(self._ctrl_now, self._ctrl_sync_q)
        self._ctrl_submit(q, frame_bits(arbitration_id, data), SentTag((arbitration_id, data), True, self._ctrl_sync_q))

    def _ctrl_submit(self, q: int, frame: FrameBits, tag: SentTag) -> None:
        """The controller's transmit queue is first in, first out (python-can's send queue): a frame
        contends once the one sent before it has won the bus."""
        self._ctrl_fifo.append((q, frame, tag))
        if not self._ctrl_on_bus:
            self._ctrl_next()

    def _ctrl_next(self) -> None:
        if self._ctrl_fifo:
            q, frame, tag = self._ctrl_fifo.popleft()
            self.bus.submit(CONTROLLER, q, frame, tag)
            self._ctrl_on_bus = True
        else:
            self._ctrl_on_bus = False

    def _queue_sync(self, data: bytes) -> None:
        counter = data[0] if data else None
        if counter is not None and self._last_counter is not None:
            self._syncs += (counter - self._last_counter - 1) % can_map.SYNC_COUNTER_OVERFLOW + 1
        else:
            self._syncs += 1
        self._last_counter = counter
        if not self._started:
            self._start()
        q = max(self._syncs * self.ts_ns, self._ctrl_now)
        self._ctrl_sync_q = q
        frame = self._sync_frames.get(data)
        if frame is None:
            frame = self._sync_frames[data] = frame_bits(can_map.SYNC_COB_ID, data)
        self._ctrl_submit(q, frame, SentTag((can_map.SYNC_COB_ID, data), True, q))

    def _start(self) -> None:
        self._started = True
        first = self._syncs * self.ts_ns
        self.bus.bus_free_ns = first
        self.stats.first_ns = first
        if self.restbus is not None and self.restbus.messages:
            self._rb_iter = traffic.schedule(self.restbus.messages, 1 << 62, start_ns=first)
            self._rb_next = next(self._rb_iter, None)

    def _direct(self, arbitration_id: int, data: bytes) -> None:
        self._untimed(self.node.exchange(arbitration_id, data, self.scheduler.now()))

    def _untimed(self, frames: list[Frame]) -> None:
        for f in frames:
            self._untimed_one(f)

    def _untimed_one(self, frame: Any) -> None:
        """A frame for the controller that takes no wire time (the start-up, the heartbeat)."""
        self._to_master.append((None, frame, False))
        self.frames_to_master += 1

    def recv(self, timeout: float | None = None) -> Frame | can.Message | None:
        if self._to_master:
            return self._take()
        if not self._started:
            if timeout:
                self.scheduler.wait(timeout)
            self._untimed(self.node.poll_frames(self.scheduler.now()))
            return self._take() if self._to_master else None
        limit = self._ctrl_now + (round(timeout * 1e9) if timeout is not None else RECV_FOREVER_NS)
        self._run(limit, until_master=True)
        if self._to_master:
            return self._take()
        if timeout:  # nothing came: the time passes, the node's timers run
            self._ctrl_now = max(self._ctrl_now, limit)
            self.scheduler.wait(timeout)
            self._plant_frames(self.node.poll_frames(self.scheduler.now()), self._ctrl_now)
        return None

    def _take(self) -> Any:
        arrival, frame, late = self._to_master.popleft()
        if arrival is not None:
            self._timed_for_master -= 1
            self._ctrl_now = max(self._ctrl_now, arrival)
        if frame.arbitration_id == self._tpdo1:
            self._last_tpdo_late = late
        return frame

    def tpdo_late(self) -> bool:
        """The last TPDO1 handed to the controller arrived after its deadline (module docstring)."""
        return self._last_tpdo_late

    def shutdown(self) -> None:
        """The frames still queued by the rig go out (the end's valves to zero, NMT), without the restbus."""
        if self._started:
            self._rb_next = None
            self._run(None, until_master=False)
        self._to_master.clear()

    # -- the wire -----------------------------------------------------------------------------------------
    def _feed_restbus(self, bound: int | None = None) -> None:
        """The restbus's instances queued by the bus's next start (``bound``: not needed beyond it)."""
        it = self._rb_iter
        while self._rb_next is not None and it is not None:
            start = self.bus.next_start()
            inst = self._rb_next
            if start is not None and inst.time_ns > start:
                return
            m = inst.message
            key = (m.name, inst.k % m.counter_period)
            frame = self._rb_frames.get(key)
            if frame is None:
                frame = self._rb_frames[key] = m.frame(inst.k)
            self.bus.submit(m.node, inst.time_ns, frame, RESTBUS_TAG)
            self._rb_next = next(it, None)

    def _run(self, limit: int | None, *, until_master: bool) -> None:
        """Deliver frames in wire order up to ``limit`` (None: until the rig's frames are out);
        stops at the first frame for the controller when ``until_master``."""
        while True:
            if self._in_flight is None:
                self._feed_restbus()
                start = self.bus.next_start()
                if start is None or (limit is not None and start >= limit):
                    return
                if limit is None and not self._rig_pending():
                    return
                if self.bus.errors_on and self._plant_events():
                    continue  # the node's answers to its new state contend too
                self._commit()
            if self._in_flight is None:  # an attempt cut by an error frame: the frame contends again
                continue
            arrival, tag = self._in_flight
            if limit is not None and arrival > limit:
                return
            self._in_flight = None
            if tag is RESTBUS_TAG:
                continue
            if tag.to_plant:
                self._deliver_to_plant(arrival, tag)
            else:
                self._to_ctrl(arrival, tag)
                if until_master:
                    return

    def _commit(self) -> None:
        """The next transmission on the wire, in flight until its last bit."""
        sent = self.bus.commit()
        tx = sent.transmission
        if tx is None:
            return
        self._note(tx, sent.frame)
        if tx.node == CONTROLLER:
            self._ctrl_next()
        self._in_flight = (tx.last_bit_ns, sent.tag)

    def _to_ctrl(self, arrival: int, tag: SentTag) -> None:
        """A plant frame's last bit is gone: the controller may take it (a TPDO1 judged against its deadline)."""
        late = False
        if tag.frame.arbitration_id == self._tpdo1:
            latency = arrival - tag.sync_q
            self.stats.sync_to_tpdo.append(latency)
            late = latency > self.window_ns
            self.stats.late_tpdos += late
        self._to_master.append((arrival, tag.frame, late))
        self._timed_for_master += 1
        self.frames_to_master += 1

    def _note_to_plant(self, arrival: int, tag: SentTag) -> None:
        cob = tag.frame[0]
        if cob == can_map.SYNC_COB_ID:
            self._plant_sync_q = tag.sync_q
        elif cob == self._rpdo1:
            self.stats.sync_to_rpdo.append(arrival - tag.sync_q)

    def _rig_pending(self) -> bool:
        return self.bus.pending > 0

    def _note(self, tx: Any, frame: FrameBits) -> None:
        s = self.stats
        s.starts.append(tx.start_ns)
        s.ends.append(tx.end_ns)
        s.ids.append(tx.arbitration_id)
        s.bits.append(frame.n_bits)
        delays = s.delays.get(tx.arbitration_id)
        if delays is None:
            delays = s.delays[tx.arbitration_id] = array("q")
        delays.append(tx.queuing_delay_ns)

    def _deliver_to_plant(self, arrival: int, tag: SentTag) -> None:
        cob, data = tag.frame
        grid = self.grid_ns
        self.app.wire_arrival_ns = (arrival + grid // 2) // grid * grid
        self._note_to_plant(arrival, tag)
        try:
            frames = self.node.exchange(cob, data, self.scheduler.now())
        finally:
            self.app.wire_arrival_ns = None
        self._plant_frames(frames, arrival)

    def plant_state(self, at_ns: int) -> ErrorState:
        """The plant node's CAN error state at ``at_ns`` (error active without errors)."""
        return self.bus.status(PLANT, at_ns).state

    def plant_state_changes(self) -> list[tuple[int, ErrorState]]:
        """The plant node's changes of error state since the last call, with their times (its CAN
        controller's interrupt). The bus first runs up to its next attempt (:meth:`OnlineBus.settle`),
        so a recovery in the idle time before it is among them; every change is at or before that start."""
        self.bus.settle()
        changes = self.bus.nodes[PLANT].changes
        out = []
        for c in changes[self._plant_seen :]:
            if c.state is not self._plant_reported:
                self._plant_reported = c.state
                out.append((c.time_ns, c.state))
        self._plant_seen = len(changes)
        return out

    def _plant_events(self) -> bool:
        """The plant node told each change of its error state when it happens; its frames (EMCY) queued then."""
        events = self.plant_state_changes()
        for t, state in events:
            self.node.can_error_state(state)
            self._plant_frames(self.node.poll_frames(self.scheduler.now()), t)
        return bool(events)

    def plant_refuses(self, at_ns: int) -> bool:
        """The plant node is bus off at ``at_ns``: a frame it sends then is refused (and counted)."""
        if self.bus.errors_on and self.plant_state(at_ns) is ErrorState.BUS_OFF:
            self.stats.plant_refused += 1
            return True
        return False

    def _plant_frames(self, frames: list[Frame], at_ns: int) -> None:
        for f in frames:
            if f.arbitration_id == self._heartbeat:  # beside the wire: a wall-clock timer in lockstep
                self._untimed_one(f)
                continue
            if self.plant_refuses(at_ns):
                self.node.counters.tx_errors += 1  # as the node's runner counts a send its bus refused
                continue
            self.bus.submit(PLANT, at_ns, frame_bits(f.arbitration_id, bytes(f.data)), SentTag(f, False, self._plant_sync_q))

    # -- figures ------------------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any] | None:
        """The bus load and the control cycle's latencies (docs/can-wire.md); None before the first SYNC."""
        s = self.stats
        if s.first_ns is None or not s.starts:
            return None
        end = max(s.ends)
        intervals = [BusyInterval(*iv) for iv in zip(s.starts, s.ends, s.ids, s.bits, strict=True)]
        report = bus_load(intervals, self.bitrate, LOAD_WINDOW_NS, start_ns=s.first_ns, end_ns=end)
        windows = [w.busy for w in report.windows]
        return {
            "bitrate": self.bitrate,
            "restbus": self.restbus.source if self.restbus is not None else "",
            "span_s": (end - s.first_ns) / 1e9,
            "busy_mean_pct": 100 * float(np.mean(windows)) if windows else 0.0,
            "busy_max_pct": 100 * report.peak_window_busy,
            "frames_per_s": report.frames_per_s,
            "bits_per_s": report.bits_per_s,
            "sync_to_tpdo1_us": _us(s.sync_to_tpdo),
            "sync_to_rpdo1_us": _us(s.sync_to_rpdo),
            "late_tpdo1": s.late_tpdos,
            "queuing_delay_us": {f"0x{ident:03X}": {"n": len(d), **_us(d)} for ident, d in sorted(s.delays.items())},
            **({"errors": self.error_summary()} if self.bus.errors_on else {}),
        }

    def error_summary(self) -> dict[str, Any]:
        """With errors on: error frames, the plant's refused frames, and per node its entries into
        error passive and bus off and its state, TEC and REC at the end."""
        nodes = {}
        for name, node in self.bus.nodes.items():
            states = [c.state for c in node.changes]
            entered = [b for a, b in zip([ErrorState.ACTIVE, *states], states, strict=False) if a is not b]
            end = node.status_at(1 << 62)
            nodes[name] = {
                "error_passive": entered.count(ErrorState.PASSIVE),
                "bus_off": entered.count(ErrorState.BUS_OFF),
                "state": end.state.value,
                "tec": end.tec,
                "rec": end.rec,
            }
        return {"error_frames": self.bus.error_frames, "plant_refused": self.stats.plant_refused, "nodes": nodes}


def grid_of(app: PlantApplication | None) -> int:
    cfg = getattr(app.arm, "cfg", None) if app is not None else None
    step = getattr(cfg, "internal_step_s", None)
    return round(float(step) * 1e9) if step else DEFAULT_GRID_NS
