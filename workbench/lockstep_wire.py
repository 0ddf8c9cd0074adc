"""The one-process lockstep rig's CAN bus with a wire (``can_bitrate`` set):
the co-simulation's timed wire (:mod:`workbench.cosim_wire`, its rules and
figures) between the controller's thread and the plant's.

:class:`LockstepWire` hands out two python-can buses, one per station
(:meth:`LockstepWire.controller_bus`, :meth:`LockstepWire.plant_bus`). The
wire's decisions depend on the frames alone, never on when a thread gets to
run: a transmission is decided only once no frame can still be queued
before its start, i.e. when

* the plant has answered every frame it was handed (it is back in
  ``recv``: its answers are queued at that frame's arrival), and
* the start is before the controller's "now", or the controller waits in
  ``recv`` (it queues nothing until a frame or its simulated timeout comes)
  and the start is before that timeout.

So the frames, their times and the plant's arrivals are those of the
co-simulation (tested: the records are bit-identical). Frames of no fixed
simulated time take no wire time in both: the start-up before the first
SYNC, and the node's heartbeat (its timer runs on the wall clock in lockstep).

With errors injected (a fault scenario's ``can_errors`` on the controller's
bus) the plant node is told each change of its CAN error state at the change's
time (a turn of its loop: its EMCY is queued then), and a frame it sends while bus off is
refused (``can.CanOperationError``, counted by its runner), as in the
co-simulation (:mod:`workbench.cosim_wire`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

import can

from plant_emulator.service import PlantApplication
from service_kit.can_wire.arbitration import ErrorInjection
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.restbus.traffic import Restbus
from workbench.cosim_wire import DEFAULT_GRID_NS, PLANT, RECV_FOREVER_NS, RESTBUS_TAG, SentTag, TimedCanWire, grid_of

WALL_GUARD_S = 120.0
"""A station that waits this long in wall time for the other (which died) gets nothing."""


class LockstepWire(TimedCanWire):
    """The shared wire of the two stations (module docstring)."""

    def __init__(self, *, node_id: int, bitrate: int, sample_period_s: float, restbus: Restbus | None = None) -> None:
        super().__init__(None, None, None, bitrate=bitrate, sample_period_s=sample_period_s, restbus=restbus, grid_ns=DEFAULT_GRID_NS, node_id=node_id)
        self._cv = threading.Condition()
        self._to_plant: deque[tuple[int | None, Any]] = deque()
        """Frames for the plant (their arrival, None: untimed), and changes of its CAN error state (their time)."""
        self._plant_handling = False
        self._plant_now: int | None = None
        self._ctrl_limit: int | None = None
        self._ctrl_waiting = False
        self._closed = False
        self._plant_node: Any = None

    # -- the buses ------------------------------------------------------------------------------------
    def controller_bus(self) -> can.BusABC:
        return _Station(self, controller=True)

    def plant_bus(self) -> can.BusABC:
        return _Station(self, controller=False)

    def bind_application(self, app: PlantApplication) -> None:
        """The plant's application: the model advances to each arrival (:attr:`PlantApplication.wire_arrival_ns`)."""
        self.app = app
        self.grid_ns = grid_of(app)

    def bind_node(self, node: Any) -> None:
        """The plant's CANopen node: told its CAN error state at each arrival (with errors on)."""
        self._plant_node = node

    def inject_can_errors(self, *specs: ErrorInjection) -> None:
        with self._cv:
            super().inject_can_errors(*specs)

    # -- the controller -------------------------------------------------------------------------------
    def send_frame(self, arbitration_id: int, data: bytes) -> None:
        with self._cv:
            super().send_frame(arbitration_id, data)
            self._advance()
            self._cv.notify_all()

    def _direct(self, arbitration_id: int, data: bytes) -> None:
        self._to_plant.append((None, can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)))

    def ctrl_recv(self, timeout: float | None) -> Any:
        guard = time.monotonic() + max(WALL_GUARD_S, timeout or 0.0)
        with self._cv:
            if not self._started:
                if not self._to_master:
                    self._cv.wait_for(lambda: bool(self._to_master) or self._closed, timeout)
                return self._take() if self._to_master else None
            limit = self._ctrl_now + (round(timeout * 1e9) if timeout is not None else RECV_FOREVER_NS)
            self._ctrl_limit, self._ctrl_waiting = limit, True
            try:
                while True:
                    self._advance()
                    if self._to_master:
                        return self._take()
                    if self._reached(limit):
                        if limit is not None:
                            self._ctrl_now = max(self._ctrl_now, limit)
                        return None
                    left = guard - time.monotonic()
                    if left <= 0 or self._closed:
                        return None
                    self._cv.wait(min(left, 1.0))
            finally:
                self._ctrl_waiting = False
                self._cv.notify_all()

    def _reached(self, limit: int | None) -> bool:
        """Nothing can reach the controller by ``limit`` any more."""
        if limit is None or self._plant_busy():
            return False
        if self._in_flight is not None:
            return self._in_flight[0] > limit
        start = self.bus.next_start()
        return start is None or start >= limit

    # -- the plant ------------------------------------------------------------------------------------
    def plant_send(self, msg: can.Message) -> None:
        with self._cv:
            cob = msg.arbitration_id
            if self._plant_now is None or cob == self._heartbeat:
                self._untimed_one(msg)
            elif self.plant_refuses(self._plant_now):
                raise can.CanOperationError("the plant node is bus off on the simulated wire: it sends nothing until it has recovered")
            else:
                self.bus.submit(PLANT, self._plant_now, frame_bits(cob, bytes(msg.data)), SentTag(msg, False, self._plant_sync_q))
            self._cv.notify_all()

    def plant_recv(self, timeout: float | None) -> can.Message | None:
        """A frame for the plant; for a change of its CAN error state, None after telling the node
        (its runner then polls: the EMCY is queued at the change's time)."""
        item = self._plant_take(timeout)
        if isinstance(item, ErrorState):
            if self._plant_node is not None:  # outside the wire's lock: the node takes its own
                self._plant_node.can_error_state(item)
            return None
        return item

    def _plant_take(self, timeout: float | None) -> can.Message | ErrorState | None:
        with self._cv:
            self._plant_handling = False
            self._plant_now = None  # the node's timers between frames: untimed (the heartbeat)
            self._advance()
            self._cv.notify_all()
            if not self._to_plant:
                self._cv.wait_for(lambda: bool(self._to_plant) or self._closed, timeout)
            if not self._to_plant:
                return None
            arrival, msg = self._to_plant.popleft()
            self._plant_handling = True
            self._plant_now = arrival
            if self.app is not None:
                grid = self.grid_ns
                self.app.wire_arrival_ns = None if arrival is None or isinstance(msg, ErrorState) else (arrival + grid // 2) // grid * grid
            return msg

    def _plant_events(self) -> bool:
        """Each change of the plant's CAN error state goes to its thread, at the change's time."""
        events = self.plant_state_changes()
        for t, state in events:
            self._to_plant.append((t, state))
        return bool(events)

    def _plant_busy(self) -> bool:
        return self._plant_handling or bool(self._to_plant)

    # -- the wire -------------------------------------------------------------------------------------
    def _advance(self) -> None:
        """Decides and delivers what the frames so far determine (module docstring); under the lock."""
        if not self._started:
            return
        while True:
            if self._timed_for_master:  # the controller takes it first: its "now" moves to its arrival
                return
            if self._in_flight is not None:
                arrival, tag = self._in_flight
                if tag is RESTBUS_TAG:
                    self._in_flight = None
                    continue
                if tag.to_plant:
                    self._in_flight = None
                    self._note_to_plant(arrival, tag)
                    cob, data = tag.frame
                    self._to_plant.append((arrival, can.Message(arbitration_id=cob, data=data, is_extended_id=False, timestamp=arrival / 1e9)))
                    continue
                if not self._ctrl_waiting or (self._ctrl_limit is not None and arrival > self._ctrl_limit):
                    return
                self._in_flight = None
                self._to_ctrl(arrival, tag)
                return
            if self._plant_busy():
                return
            bound = self._ctrl_limit if self._ctrl_waiting else self._ctrl_now
            self._feed_restbus(bound)
            start = self.bus.next_start()
            if start is None or (bound is not None and start >= bound):
                return
            if self.bus.errors_on and self._plant_events():
                continue  # the plant answers its new state first
            self._commit()

    def shutdown(self) -> None:
        """The rig's last frames reach the plant (without the restbus), then both stations stop waiting."""
        guard = time.monotonic() + 10.0
        with self._cv:
            if self._started:
                self._rb_next = None
                self._ctrl_limit, self._ctrl_waiting = None, True
                while (self.bus.pending or self._in_flight is not None or self._plant_busy()) and time.monotonic() < guard:
                    self._to_master.clear()  # nobody takes them any more (the co-simulation's drain drops them too)
                    self._timed_for_master = 0
                    self._advance()
                    self._cv.notify_all()
                    self._cv.wait(0.05)
                self._ctrl_waiting = False
            self._closed = True
            self._cv.notify_all()


class _Station(can.BusABC):
    """One station's python-can bus on a :class:`LockstepWire`."""

    def __init__(self, wire: LockstepWire, *, controller: bool) -> None:
        self._wire, self._controller = wire, controller
        self.channel_info = f"simulated CAN wire at {wire.bitrate} bit/s ({'controller' if controller else 'plant'})"
        super().__init__(channel="lockstep-wire")
        if controller:
            self.tpdo_late = wire.tpdo_late  # asked by the controller's SyncDriver
            self.inject_can_errors = wire.inject_can_errors  # a fault scenario's can_errors (service_kit.can_wire.scenario_errors)
        else:
            self.bind_application = wire.bind_application
            self.bind_node = wire.bind_node

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            raise can.CanOperationError("the simulated wire carries the rig's standard data frames only")
        if self._controller:
            self._wire.send_frame(msg.arbitration_id, bytes(msg.data))
        else:
            self._wire.plant_send(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """One frame, or None once the wire has decided nothing comes within ``timeout`` of simulated time
        (the controller), or after ``timeout`` of wall time (the plant). Not python-can's loop, which would
        ask again for the wall time left."""
        if self._controller:
            frame = self._wire.ctrl_recv(timeout)
            if frame is not None and not isinstance(frame, can.Message):
                frame = can.Message(arbitration_id=frame.arbitration_id, data=bytes(frame.data), is_extended_id=False)
            return frame
        return self._wire.plant_recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), False

    def shutdown(self) -> None:
        super().shutdown()


__all__ = ["LockstepWire"]
