"""Lockstep: the interrupt of the batch in flight, waited for at its due tick.

The DSP's emulated latency sets the tick at which a batch's interrupt is
applied (simulated time); the loop waits there for it, however long it
takes to arrive (the DSP's presence is not asked), resending the batch
every ``BATCH_RESEND_S`` (a message lost when a starved peer's zenoh
session dropped), up to ``lockstep_timeout_s``: then it is declared lost.
A batch or interrupt a link fault dropped (controller/fault_stage.py) is
lost at its due tick.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from controller.dsp_inbox import DspInbox
from controller.dsp_link import DspLink
from controller.dsp_port import DspPort
from controller.fault_stage import FaultStage
from controller.timing_counters import TimingCounters
from service_kit.clock import Scheduler

BATCH_RESEND_S = 5.0
"""Lockstep: resend the batch in flight when its interrupt has not come this
long after it was due (a message lost when a starved peer's zenoh session
dropped); the DSP answers a repeated batch with the interrupt it raised for
it, or takes it if it never arrived."""


class InterruptWait:
    """Waits for one batch's interrupt, taking the DSP's other messages meanwhile."""

    def __init__(
        self,
        port: DspPort,
        link: DspLink,
        clock: Scheduler,
        inbox: DspInbox,
        take: Callable[[str, Any, float], None],
        faults: FaultStage | None,
        timing: TimingCounters,
        timeout_s: float,
    ) -> None:
        self.port, self.link, self.clock, self.inbox = port, link, clock, inbox
        self._take = take
        """Takes one DSP message in (:meth:`controller.dsp_side.DspSide.take_event`)."""
        self.faults, self.timing = faults, timing
        self._timeout_s = timeout_s

    def wait(self, seq: int, tick: int) -> str | None:
        """Lockstep: block until the interrupt of batch ``seq`` is in, however
        long it takes to arrive (the DSP's presence is not asked), up to
        ``lockstep_timeout_s``: then it is declared lost. Returns the miss
        (for the ``deadline`` monitor) when it is lost, else None."""
        link = self.link
        if self.faults is not None and self.faults.lost(seq):
            came = True
            if not self._dsp_never_got(seq):
                # Only the interrupt was dropped: it still releases the DSP's block, and the
                # next batch waits for that, so the handshake waits for it to come (and be
                # dropped) here, not whenever the DSP's thread gets to it.
                came = self._await_interrupt(lambda: seq in link.dropped_arrived)
                link.dropped_arrived.discard(seq)
            return self._fault_lost(seq, tick, answered=came)
        if not self._await_interrupt(lambda: any(irq.batch_seq == seq for irq in link.held)):
            # It will not come: count it lost, fire the deadline monitor, go on without it.
            link.declare_lost()
            link.note_batch(True)
            return f"batch {seq}: no interrupt within {self._timeout_s:.1f} s (lockstep); declared lost"
        return None

    def _await_interrupt(self, arrived: Callable[[], bool]) -> bool:
        """Take DSP-side events until ``arrived()``, resending the batch every
        ``BATCH_RESEND_S``; False after ``lockstep_timeout_s``, at a stop, or
        at once when the port answers synchronously and it is not in."""
        clock, port = self.clock, self.port
        deadline = clock.now() + self._timeout_s
        resend_at = clock.now() + BATCH_RESEND_S
        self.timing.lockstep_waits += 1
        while not arrived():
            if not port.synchronous and self.link.last_payload is not None and clock.now() >= resend_at:
                port.send_batch(self.link.last_payload)
                self.timing.batch_resends += 1
                resend_at = clock.now() + BATCH_RESEND_S
            remaining = deadline - clock.now()
            event = self.inbox.next_event(min(remaining, 0.1)) if remaining > 0 and not clock.stopping else None
            if event is None and (remaining <= 0 or port.synchronous or clock.stopping):
                return False
            if event is not None:
                self._take(*event)
        return True

    def _fault_lost(self, seq: int, tick: int, answered: bool = True) -> str:
        """Lockstep: batch ``seq`` or its interrupt was dropped by a link fault,
        so it is lost at its due tick (once a dropped interrupt has come:
        ``answered`` False if the board did not answer within
        ``lockstep_timeout_s`` either, which the miss says). A batch that never
        reached the DSP leaves its block empty and expecting ``seq`` (the flag
        the CPU reads, Fig. 3.5): the next batch takes that number again and
        says its samples are missing, so the DSP restarts its history."""
        assert self.faults is not None
        link = self.link
        link.declare_lost()
        link.note_batch(True)
        sent = link.sent_unix.pop(seq, None)
        if self.faults.engine.covers("batch") and self._dsp_never_got(seq):
            link.next_seq = seq
            link.block_empty = True
            link.note_lost_samples(sent[1] if sent is not None else 0)
        miss = f"batch {seq}: interrupt lost at its due tick {tick} ({self.faults.blame(seq)})"
        if not answered:
            miss += f"; the board did not answer within {self._timeout_s:.1f} s either"
        return miss

    def _dsp_never_got(self, seq: int) -> bool:
        assert self.faults is not None
        return seq in self.faults.batches_dropped
