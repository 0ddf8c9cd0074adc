"""The controller's end of the CPU-DSP handshake (thesis §3.2.3, Fig. 3.5).

What comes from the DSP (flags, interrupts, run-time commands, its
presence) is taken in here, between ticks; interrupts are applied at their
due tick (lockstep: waited for there, so results do not depend on the
host's load), batches go out when the link has one ready, and the run
starts with a reset the DSP must acknowledge. The link's state machine and
its bookkeeping are :class:`controller.dsp_link.DspLink`; decoding and
pairing at the edge are :class:`controller.dsp_inbox.DspInbox`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from controller.dsp_inbox import DspInbox
from controller.dsp_link import DspLink
from controller.dsp_port import DspPort
from controller.fault_stage import FaultStage
from controller.hop_timing import HopTimer
from controller.interrupt_wait import InterruptWait
from controller.loop import ControlLaw
from controller.monitors import Monitors
from controller.timing_counters import TimingCounters
from protocol.batch_codec import encode_batch
from protocol.command_fields import COMMAND_KEYS, TEST_KNOBS, changed_fields
from protocol.errors import ProtocolError
from protocol.messages import BlockFlag, ConfigChange, Interrupt, encode
from service_kit.clock import Scheduler
from service_kit.runtime import LatencyTracker

log = logging.getLogger(__name__)

RESET_RESEND_S = 1.0
"""Start-up: resend the run's reset to the DSP this often until it answers."""


@dataclass(frozen=True)
class ConfigChangeTaken:
    """A run-time command the controller took: when, on which key, what it changed."""

    sim_time_s: float
    kind: str
    """The command key's inbox kind: ``command`` (tools) or ``test_command`` (the tester's test knobs);
    a parameter change's path: ``xcp``, ``param`` or ``schedule`` (controller/params.py)."""
    fields: dict[str, Any]
    who: str = ""
    """Who sent a parameter change (kinds ``xcp``, ``param``, ``schedule``: docs/calibration.md); empty for the others."""


@dataclass(frozen=True)
class DspTimes:
    """The handshake's times, from the settings."""

    sample_period_s: float
    lockstep_timeout_s: float
    oatf_min_confidence: float


class DspSide:
    """Takes the DSP's messages in, applies interrupts, sends batches."""

    def __init__(
        self,
        port: DspPort,
        link: DspLink,
        clock: Scheduler,
        times: DspTimes,
        *,
        lockstep: bool,
        faults: FaultStage | None,
        monitors: Monitors,
        timing: TimingCounters,
        law: ControlLaw,
        tick: Callable[[], int],
    ) -> None:
        self.port, self.link, self.clock, self.times = port, link, clock, times
        self.lockstep, self.faults, self.monitors, self.timing, self.law = lockstep, faults, monitors, timing, law
        self._tick = tick
        """The loop's current tick."""
        self.inbox = DspInbox(lambda seq: seq in link.sent_wall, port.synchronous)
        self.waiter = InterruptWait(port, link, clock, self.inbox, self.take_event, faults, timing, times.lockstep_timeout_s)
        self.irq_latency = LatencyTracker()
        self.hops = HopTimer()
        """Per-hop stamps of the tick and batch paths (controller/hop_timing.py)."""
        self.dsp_alive = False
        self.latest_interrupt: Interrupt | None = None
        self.latest_frequency_hz: float | None = None
        self.last_fresh_tick = 0
        self.last_miss: str | None = None
        self.liveliness: list[tuple[float, str, bool]] = []
        self.config_seq = int.from_bytes(os.urandom(4), "little") >> 2
        """ConfigChange numbers start at random, so a flag of an earlier run never acknowledges this one's reset."""
        self.dsp_config_seq: int | None = None
        """The DSP's last applied ConfigChange, from its latest flag."""
        self.flags_seen = 0
        self.config_changes: list[ConfigChangeTaken] = []
        """Every run-time command taken, in order (the run's result lists them)."""
        self._unix_offset = time.time() - time.monotonic()
        """Unix - monotonic: converts the port's arrival stamps for the batch path's hops (real time)."""
        self._irq_source: Interrupt | None = None
        self._irq_columns: tuple[float, float, float, float] = (math.nan, math.nan, math.nan, 0.0)
        """f_id_hz, f_id2_hz, zeta_id, id_confidence of ``_irq_source`` (the latest interrupt)."""

    # -- taking messages in -----------------------------------------------------------
    def take_event(self, kind: str, payload: Any, arrival: float) -> None:
        """One decoded message from the inbox (never raw bytes: decoding happened at the edge)."""
        try:
            if kind == "flag":
                self._take_flag(payload)
            elif kind == "interrupt":
                self._take_interrupt(payload, arrival)
            elif kind in ("command", "test_command"):
                self.reconfigure(payload, kind)
            elif kind == "alive":
                self._take_presence(bool(payload))
        except ProtocolError as exc:
            self.timing.undecodable += 1
            log.warning("dropped an invalid %s: %s", kind, exc)

    def _take_flag(self, flag: BlockFlag) -> None:
        if flag.state == "full":
            self.link.acked = True
        if not self._echoes_interrupt(flag):
            self.link.on_flag(flag)
        self.flags_seen += 1
        self.dsp_config_seq = flag.config_seq

    def _take_interrupt(self, irq: Interrupt, arrival: float) -> None:
        link = self.link
        link.note_arrival(irq.batch_seq, arrival)
        if self.faults is None:
            link.held.append(irq)
            return
        taken = self.faults.interrupt(irq, irq.batch_seq)
        if not taken and self.faults.lost(irq.batch_seq):
            link.on_released(irq)  # dropped: its block-empty part still holds (no flag follows it)
            if self.lockstep:  # its due tick waits for it (real time never does)
                link.note_dropped_arrival(irq.batch_seq)
        link.held.extend(taken)  # type: ignore[arg-type]

    def _take_presence(self, up: bool) -> None:
        if up != self.dsp_alive and not up:
            self.inbox.paired_board = None  # a restarted board pairs anew with its first flag
        if up != self.dsp_alive:
            tick = self._tick()
            self.liveliness.append((tick * self.times.sample_period_s, "dsp", up))
            if up:
                self.timing.dsp_found += 1
            else:
                self.timing.dsp_lost += 1
            # Lockstep: presence is reported, never acted on; the handshake
            # (an interrupt within lockstep_timeout_s) decides.
            if not self.lockstep and up:
                self.monitors.clear("dsp_lost")
                log.info("DSP present at tick %d", tick)
            elif not self.lockstep:
                self.last_miss = f"DSP lost at tick {tick}"
                self.link.in_flight = None
                self.link.block_empty = False
                then = "" if self.monitors.policies.get("dsp_lost") == "stop" else "; controlling on with the fallback parameters"
                self.monitors.fire("dsp_lost", f"DSP lost at tick {tick}{then}")
        self.dsp_alive = up

    def _echoes_interrupt(self, flag: BlockFlag) -> bool:
        """The empty flag the DSP sends just after an interrupt (it raises the
        interrupt first, docs/design.md): that interrupt already emptied the
        block and our next batch may be in flight, so the flag is no news for
        the link (not a late flag)."""
        irq, sent = self.latest_interrupt, self.link.in_flight
        return flag.state == "empty" and irq is not None and sent is not None and flag.next_batch_seq == irq.batch_seq + 1 == sent.seq

    def reconfigure(self, change: ConfigChange, kind: str = "command") -> None:
        """A run-time command (thesis §3.2.3), taken on the command key
        ``kind`` (its fields already checked, protocol/command_fields.py):
        the batch size applies here from the next batch on; the FFT width,
        alpha and latency go to the DSP, which zeroes its history on an
        FFT-width change. Every change taken is counted and listed
        (:attr:`config_changes`)."""
        if change.batch_size is not None:
            log.info("batch size %d -> %d", self.link.batch_size, change.batch_size)
            self.link.batch_size = change.batch_size
        self.config_seq += 1
        sim_time_s = self._tick() * self.times.sample_period_s
        forwarded = change.model_copy(update={"seq": self.config_seq, "sim_time_s": sim_time_s})
        self.port.send_config(encode(forwarded))
        fields = {name: getattr(change, name) for name in sorted(changed_fields(change))}
        self.config_changes.append(ConfigChangeTaken(sim_time_s, kind, fields))
        self.timing.reconfigurations += 1
        if changed_fields(change) & TEST_KNOBS:
            self.timing.test_knob_changes += 1
        log.info("configuration changed under the run at %.3f s (%s): %s", sim_time_s, COMMAND_KEYS[kind], fields)

    def drain(self) -> None:
        """Take what the inbox holds; real time with link faults: release what they held and is due now."""
        self.inbox.drain(self.take_event)
        faults = self.faults
        if faults is not None and not self.lockstep:
            self.link.held.extend(faults.interrupts_due())  # type: ignore[arg-type]
            for payload in faults.batches_due():
                self.port.send_batch(payload)

    # -- interrupts ---------------------------------------------------------------------
    def apply_interrupts(self) -> bool:
        """Apply held interrupts that are due; True if one was applied this tick.
        Lockstep: the interrupt of the batch in flight is applied exactly at
        its due tick (waited for there), never earlier or later."""
        link, tick = self.link, self._tick()
        sent = link.in_flight
        if self.lockstep and sent is not None and tick >= sent.due_tick:
            miss = self.waiter.wait(sent.seq, tick)
            if miss is not None:
                self.last_miss = miss
                self.monitors.fire("deadline", miss)
        if not link.held:
            return False
        applied = False
        keep: list[Interrupt] = []
        for irq in link.held:
            sent = link.in_flight
            if self.lockstep and sent is not None and irq.batch_seq == sent.seq and tick < sent.due_tick:
                keep.append(irq)  # not due yet in simulated time
                continue
            if link.on_interrupt(irq) is None:
                continue
            self._stamp_answer(irq)
            self._note_answer(irq, tick)
            applied = True
        link.held = keep
        return applied

    def _stamp_answer(self, irq: Interrupt) -> None:
        """The batch-to-interrupt latency and, in real time, the batch path's hops."""
        link = self.link
        sent_wall = link.sent_wall.pop(irq.batch_seq, None)
        arrived = link.irq_arrival.pop(irq.batch_seq, self.clock.now())
        if sent_wall is not None:
            self.irq_latency.add(arrived - sent_wall)
        sent_unix = link.sent_unix.pop(irq.batch_seq, None)
        if sent_unix is not None and not self.port.synchronous:
            now_unix = time.time()
            hold = 0.0 if self.lockstep else max(0.0, link.dsp_latency_s - irq.compute_time_s)
            self.hops.batch(sent_unix[0], irq.wall_time_s, irq.compute_time_s, hold, arrived + self._unix_offset, now_unix)

    def _note_answer(self, irq: Interrupt, tick: int) -> None:
        """An interrupt matched its batch: counted, the deadline monitor told, the law offered its poles."""
        self.timing.interrupts_applied += 1
        self.link.note_batch(self.link.missed_current)
        if not self.link.missed_current:
            self.monitors.clear("deadline")
        self.latest_interrupt = irq
        if irq.poles:
            self.latest_frequency_hz = irq.poles[0].frequency_hz
        if irq.poles and irq.confidence >= self.times.oatf_min_confidence:
            self.last_fresh_tick = tick
        if self.law.apply_interrupt(irq):
            self.timing.oatf_updates += 1

    def interrupt_columns(self) -> tuple[float, float, float, float]:
        """The run record's f_id_hz, f_id2_hz, zeta_id, id_confidence of the latest interrupt (computed once per interrupt)."""
        irq = self.latest_interrupt
        if irq is not self._irq_source:
            self._irq_source = irq
            poles = irq.poles if irq is not None else ()
            self._irq_columns = (
                poles[0].frequency_hz if poles else math.nan,
                poles[1].frequency_hz if len(poles) > 1 else math.nan,
                poles[0].damping_ratio if poles else math.nan,
                irq.confidence if irq is not None else 0.0,
            )
        return self._irq_columns

    # -- batches ------------------------------------------------------------------------
    def after_sample(self, tick: int) -> None:
        """The tick's sample is in the link: a batch out if one is ready; the deadline of the one in flight checked."""
        link = self.link
        if link.ready():
            self.send_batch(tick)
        if link.in_flight is not None and link.check_deadline(tick):
            self.last_miss = f"batch {link.in_flight.seq if link.in_flight else '?'}: no interrupt within {link.deadline * 1e3:.0f} ms ({self.blame_batch()})"
            self.monitors.fire("deadline", self.last_miss)

    def send_batch(self, tick: int) -> None:
        """The link's batch, if one is ready, out through the link faults (if any) and the port."""
        link = self.link
        taken = link.take_batch(tick, tick * self.times.sample_period_s)
        if taken is None:
            return
        sent, batch = taken
        sent_unix = time.time()
        if not self.port.synchronous:
            batch = type(batch)(**{**batch.__dict__, "wall_time_s": sent_unix})
        payload = encode_batch(batch)
        link.note_sent(sent.seq, self.clock.now(), sent_unix, batch.n_samples, payload)
        if self.faults is not None:
            link.dropped_arrived.discard(sent.seq)  # a number taken again (a lost batch, a DSP restart) starts clean
            send, shift = self.faults.batch(sent.seq, tick, payload)
            if shift and link.in_flight is sent:
                link.in_flight = dataclasses.replace(sent, due_tick=sent.due_tick + shift)
            if not send:
                if self.faults.lost(sent.seq):
                    link.last_payload = None  # lost on the wire: never resent
                return
        self.port.send_batch(payload)

    def blame_batch(self) -> str:
        """Which hop of the batch in flight ate its deadline: a link fault, the
        DSP (it acknowledged the batch: block full) or the way there (no
        acknowledgement yet)."""
        sent = self.link.in_flight
        if sent is not None and self.faults is not None:
            fault = self.faults.blame(sent.seq)
            if fault:
                return fault
        if sent is not None and sent.due_tick > sent.deadline_tick:
            return f"the DSP's emulated latency ({(sent.due_tick - sent.tick) * self.times.sample_period_s * 1e3:.0f} ms) exceeds the deadline"
        if not self.link.block_empty and self.link.acked:
            return "hop dsp_compute: the DSP acknowledged the batch and has not answered"
        return "hop batch_to_dsp: no acknowledgement from the DSP yet"

    # -- the run's start ----------------------------------------------------------------
    def wait_for_dsp(self, stop: threading.Event, timeout: float) -> None:
        """Tell the DSP a new run starts (sequence numbers from 0, history
        restarted) and wait until a flag says it applied exactly that reset
        (``config_seq``) with an empty block expecting batch 0. The reset goes
        once the DSP is present (its subscriptions exist then) and again, with
        a new number, every ``RESET_RESEND_S`` while unanswered; so tick 0 never
        depends on when the DSP started or on message order."""
        deadline = self.clock.now() + timeout
        link = self.link
        link.next_seq = 0
        reset_sent_at: float | None = None
        while not stop.is_set():
            now = self.clock.now()
            answered = reset_sent_at is not None and self._reset_answered()
            if answered or now >= deadline:
                break
            if self.dsp_alive and (reset_sent_at is None or now - reset_sent_at >= RESET_RESEND_S):
                self.send_reset()
                reset_sent_at = now
            event = self.inbox.next_event(0.05)
            if event is not None:
                self.take_event(*event)
            elif self.port.synchronous and not self.dsp_alive:
                break
        if not self._reset_answered():
            log.warning("no DSP answered within %.1f s; controlling without identification until it does", timeout)
            if reset_sent_at is None:
                # Tell a DSP that turns up later all the same.
                self.send_reset()

    def _reset_answered(self) -> bool:
        return self.dsp_config_seq == self.config_seq and self.link.block_empty and self.link.next_seq == 0

    def send_reset(self) -> None:
        """The run-start reset (a new number each time); after it, the next flag pairs."""
        self.config_seq += 1
        self.inbox.reset_sent = True
        self.link.next_seq = 0
        self.link.last_answered = None
        self.port.send_config(encode(ConfigChange(seq=self.config_seq, sim_time_s=0.0, reset=True)))
