"""What the loop checks after each tick, and what it does about it: the
monitors' per-tick inputs (``overrun``, ``can_conflict``, ``can_error_passive``) and the plant's
liveness (TPDOs missing in a row, heartbeat, NMT state), which end the run
with :class:`controller.plant_link.PlantFault`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from controller.monitors import Monitors
from controller.plant_link import PlantFault, PlantLink
from protocol.can_map import NmtState


@dataclass
class TickPolicy:
    monitors: Monitors
    plant: PlantLink
    sample_period_s: float
    heartbeat_timeout_s: float
    counters: Any
    """The controller's timing counters (``overruns``)."""
    missed_in_row: int = 0
    overrun_run: int = 0
    overrun_run_max: int = 0
    """Consecutive overrunning ticks: now, and the longest run."""

    def sample(self, tick: int, arrived: bool) -> None:
        """This tick's TPDO1 came (or not): too many missing in a row is a plant fault."""
        if arrived:
            self.missed_in_row = 0
            return
        self.missed_in_row += 1
        age = self.plant.heartbeat_age()
        if age > self.heartbeat_timeout_s or self.missed_in_row * self.sample_period_s > self.heartbeat_timeout_s:
            raise PlantFault(f"plant did not answer SYNC at tick {tick}: {self.missed_in_row} TPDOs missing in a row (heartbeat age {age:.2f} s)")

    def after_tick(self, tick: int, overran: bool, tet_s: float, blame: str) -> None:
        """The overrun and CAN-conflict monitors (may raise MonitorStop under policy stop)."""
        m = self.monitors
        if overran:
            self.counters.overruns += 1
            self.overrun_run += 1
            self.overrun_run_max = max(self.overrun_run_max, self.overrun_run)
            m.fire("overrun", f"tick {tick} took {tet_s * 1e3:.2f} ms, past the next SYNC (blame: {blame})")
        else:
            self.overrun_run = 0
            if "overrun" in m.active:
                m.clear("overrun")
        conflicts = self.plant.take_conflicts()  # another master on the bus (see PlantLink)
        if conflicts:
            m.fire("can_conflict", f"tick {tick}: " + "; ".join(conflicts[:3]))
        elif "can_conflict" in m.active:
            m.clear("can_conflict")
        can_error = self.plant.can_errors.condition()  # a node not error active (controller.can_errors)
        if can_error is not None:
            if "can_error_passive" not in m.active:
                m.fire("can_error_passive", f"tick {tick}: {can_error}")
        elif "can_error_passive" in m.active:
            m.clear("can_error_passive")

    def check_plant(self) -> None:
        """Heartbeat lost or the node out of OPERATIONAL: a plant fault."""
        age = self.plant.heartbeat_age()
        if age > self.heartbeat_timeout_s:
            raise PlantFault(f"plant heartbeat lost for {age:.2f} s")
        if self.plant.node_state is not NmtState.OPERATIONAL and self.plant.node_state is not None:
            raise PlantFault(f"plant node left OPERATIONAL (heartbeat says {self.plant.node_state.name})")
