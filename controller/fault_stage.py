"""Fault injection at the controller's edges: the scripted link faults of
:mod:`service_kit.link_faults` and the scenario's loop stalls.

The stage sits between the controller's loop and its two links (the CAN
master :class:`controller.plant_link.PlantLink`, the DSP port) and acts on
each message at a point of the loop that is the same in real time, in the
three-process lockstep and in the co-simulation, keyed by a deterministic
sequence number (the tick for SYNC, TPDO1 and RPDO1; for batches and interrupts the tick
the batch went out at). In lockstep and the co-simulation every delay is
applied in simulated ticks, so a faulted run is still bit for bit
reproducible and the co-simulation still equals the lockstep run:

=========  ==========================================================================
kind       effect (sim = lockstep and co-simulation; rt = real time)
=========  ==========================================================================
sync       drop / outage: the frame is not sent (the SYNC counter still advances,
           so the node sees the gap); the controller expects no TPDO for the tick
           and holds the last sample. delay: rt waits that long before sending it
           (wake-up jitter as stimulus); sim: no effect on the data.
tpdo       drop / outage / reorder (the next sample overtakes it): the tick gets no
           sample and holds the last one. delay: at or past ``TPDO_WINDOW`` of the
           period it is late (as drop); shorter: rt waits it out, sim no effect.
           duplicate: the copy is stale and ignored.
rpdo       drop / outage: the valves keep the previous D/A command. delay: held for
           ``floor(delay / Ts)`` ticks, then sent after that tick's own command (so
           the older command wins at the node); reorder: held one tick.
           duplicate: sent twice.
batch      drop / outage: never sent (nor resent): its interrupt never comes, the
           deadline monitor fires. delay: sim shifts the batch's due tick by
           ``ceil(delay / Ts)``; rt sends it that late.
interrupt  drop / outage: refused when it arrives (sim: the batch is declared lost
           at its due tick). delay: sim shifts the due tick; rt holds it until
           arrival + delay. duplicate: taken twice (the copy is unexpected).
=========  ==========================================================================
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from service_kit.counters import Counters
from service_kit.link_faults import PASS, Fate, FaultEngine, Scenario

log = logging.getLogger(__name__)

TPDO_WINDOW = 0.8
"""Fraction of the period the real-time loop waits for TPDO1 after its SYNC."""


@dataclass
class StageCounters(Counters):
    syncs_faulted: int = 0
    tpdos_faulted: int = 0
    rpdos_faulted: int = 0
    batches_faulted: int = 0
    interrupts_faulted: int = 0


@dataclass
class FaultStage:
    """Applies a :class:`FaultEngine` at the controller's edges (see the module docstring)."""

    engine: FaultEngine
    sample_period_s: float
    simulated: bool
    """True in lockstep and the co-simulation: delays act in ticks."""
    wall: Callable[[], float]
    """Seconds since the run began (for faults with ``time_base: wall`` and real-time releases)."""
    counters: StageCounters = field(default_factory=StageCounters)
    _no_tpdo: set[int] = field(default_factory=set)
    _rpdo_held: list[tuple[int, np.ndarray]] = field(default_factory=list)
    _lost_batches: set[int] = field(default_factory=set)
    batches_dropped: set[int] = field(default_factory=set)
    """Batches a fault kept from the DSP (it never saw them)."""
    _batch_held: list[tuple[float, int, bytes]] = field(default_factory=list)
    _irq_fate: dict[int, Fate] = field(default_factory=dict)
    _irq_held: list[tuple[float, object]] = field(default_factory=list)
    _batch_delay: dict[int, float] = field(default_factory=dict)

    @classmethod
    def from_scenario(cls, scenario: Scenario, sample_period_s: float, simulated: bool, wall: Callable[[], float]) -> FaultStage:
        return cls(FaultEngine(scenario), sample_period_s, simulated, wall)

    def _decide(self, kind: str, seq: int, tick: int) -> Fate:
        return self.engine.decide(kind, seq, tick * self.sample_period_s, self.wall())

    def as_counters(self) -> dict[str, int]:
        return {**self.counters.as_dict(), **self.engine.counters.as_dict()}

    # -- CAN ------------------------------------------------------------------------------
    def sync(self, tick: int) -> float | None:
        """The fate of tick ``tick``'s SYNC: None = dropped, else the delay (s) before sending it."""
        if not self.engine.covers("sync"):
            return 0.0
        fate = self._decide("sync", tick, tick)
        if fate is PASS:
            return 0.0
        self.counters.syncs_faulted += 1
        if fate.dropped:
            self._no_tpdo.add(tick)
            return None
        return 0.0 if self.simulated else fate.delay_s

    def expects_tpdo(self, tick: int) -> bool:
        """False if this tick's SYNC was dropped (nothing will answer it)."""
        if not self._no_tpdo:
            return True
        if tick in self._no_tpdo:
            self._no_tpdo.discard(tick)
            return False
        return True

    def tpdo(self, tick: int) -> float | None:
        """The fate of tick ``tick``'s TPDO1: None = no sample this tick, else a delay (s) to wait (real time)."""
        if not self.engine.covers("tpdo"):
            return 0.0
        fate = self._decide("tpdo", tick, tick)
        if fate is PASS:
            return 0.0
        self.counters.tpdos_faulted += 1
        if fate.dropped or fate.reordered or fate.delay_s >= TPDO_WINDOW * self.sample_period_s:
            return None
        return 0.0 if self.simulated else fate.delay_s

    def rpdo(self, tick: int, volts: np.ndarray) -> list[np.ndarray]:
        """The D/A commands to send at tick ``tick`` (this tick's, faulted, then held ones now due), in order."""
        if not self.engine.covers("rpdo") and not self._rpdo_held:
            return [volts]
        fate = self._decide("rpdo", tick, tick) if self.engine.covers("rpdo") else PASS
        out: list[np.ndarray] = []
        if fate is not PASS:
            self.counters.rpdos_faulted += 1
        if fate.dropped:
            pass
        elif fate.reordered or fate.delay_s >= self.sample_period_s:
            hold = max(1, math.floor(round(fate.delay_s / self.sample_period_s, 9)))
            self._rpdo_held.append((tick + hold, np.array(volts, dtype=float)))
        else:
            out.extend([volts] * fate.copies)
        due = [v for t, v in self._rpdo_held if t <= tick]
        if due:
            self._rpdo_held = [(t, v) for t, v in self._rpdo_held if t > tick]
            out.extend(due)
        return out

    # -- zenoh ----------------------------------------------------------------------------
    def batch(self, seq: int, tick: int, payload: bytes) -> tuple[bool, int]:
        """The fate of batch ``seq`` sent at ``tick``: (send now, ticks its interrupt's due tick moves)."""
        shift = 0
        send = True
        # a batch number is taken again after a lost batch: its new attempt starts clean
        self._lost_batches.discard(seq)
        self.batches_dropped.discard(seq)
        self._irq_fate.pop(seq, None)
        self._batch_delay.pop(seq, None)
        while len(self._batch_delay) > 64:
            del self._batch_delay[next(iter(self._batch_delay))]
        # keyed by the tick it goes out at (unique per attempt, deterministic)
        if self.engine.covers("batch"):
            fate = self._decide("batch", tick, tick)
            if fate is not PASS:
                self.counters.batches_faulted += 1
                if fate.dropped:
                    self._lost_batches.add(seq)
                    self.batches_dropped.add(seq)
                    return False, 0
                if fate.delay_s > 0:
                    self._batch_delay[seq] = fate.delay_s
                    if self.simulated:
                        shift += math.ceil(round(fate.delay_s / self.sample_period_s, 9))
                    else:
                        self._batch_held.append((self.wall() + fate.delay_s, seq, payload))
                        send = False
        if self.engine.covers("interrupt"):
            fate = self._decide("interrupt", tick, tick)
            if fate is not PASS:
                self.counters.interrupts_faulted += 1
                self._irq_fate[seq] = fate
                if fate.dropped:
                    self._lost_batches.add(seq)
                elif fate.delay_s > 0 and self.simulated:
                    shift += math.ceil(round(fate.delay_s / self.sample_period_s, 9))
                while len(self._irq_fate) > 64:
                    del self._irq_fate[next(iter(self._irq_fate))]
        for bounded in (self._lost_batches, self.batches_dropped):
            while len(bounded) > 64:
                bounded.discard(min(bounded))
        return send, shift

    def batches_due(self) -> list[bytes]:
        """Real time: delayed batches whose time has come."""
        if not self._batch_held:
            return []
        now = self.wall()
        due = [p for t, _, p in self._batch_held if t <= now]
        self._batch_held = [h for h in self._batch_held if h[0] > now]
        return due

    def lost(self, seq: int) -> bool:
        """Batch ``seq`` or its interrupt was dropped by a fault: it will never be answered."""
        return seq in self._lost_batches

    def interrupt(self, irq: object, batch_seq: int) -> list[object]:
        """An interrupt as it arrives: what the controller takes now (none, it, or it twice)."""
        fate = self._irq_fate.get(batch_seq)
        if fate is None:
            return [irq]
        if fate.dropped:
            return []
        if fate.delay_s > 0 and not self.simulated:
            self._irq_held.append((self.wall() + fate.delay_s, irq))
            return []
        return [irq] * fate.copies

    def interrupts_due(self) -> list[object]:
        """Real time: delayed interrupts whose time has come."""
        if not self._irq_held:
            return []
        now = self.wall()
        due = [irq for t, irq in self._irq_held if t <= now]
        self._irq_held = [h for h in self._irq_held if h[0] > now]
        return due

    def blame(self, seq: int) -> str | None:
        """The fault that acted on batch ``seq`` or its interrupt, for a miss's text."""
        fate = self._irq_fate.get(seq)
        if seq in self._lost_batches:
            return "link fault: batch or interrupt dropped on zenoh"
        if fate is not None and fate.delay_s > 0:
            return f"link fault: interrupt delayed {fate.delay_s * 1e3:.1f} ms on zenoh (faults {list(fate.faults)})"
        if seq in self._batch_delay:
            return f"link fault: batch delayed {self._batch_delay[seq] * 1e3:.1f} ms on zenoh"
        return None


@dataclass
class LoopStalls:
    """The scenario's ``stalls``: before tick ``t`` the loop freezes ``at_ticks[t]`` seconds of wall-clock time."""

    at_ticks: dict[int, float] = field(default_factory=dict)
    stall_at_tick: int | None = None
    """The first tick with a stall (None: no stall; the loop then checks nothing)."""

    @classmethod
    def from_scenario(cls, scenario: Scenario | None, sample_rate_hz: float) -> LoopStalls:
        at: dict[int, float] = {}
        for stall in scenario.stalls if scenario is not None else ():
            tick = int(round(stall.at_s * sample_rate_hz))
            at[tick] = at.get(tick, 0.0) + stall.wall_s
        return cls(at, min(at) if at else None)

    def stall_now(self, tick: int) -> float:
        """Seconds the loop freezes before tick ``tick`` (0: none)."""
        return self.at_ticks.get(tick, 0.0)
