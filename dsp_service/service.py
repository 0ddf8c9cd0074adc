"""The DSP service: the emulated C40 board on zenoh.

Subscribes to sample batches and run-time configuration, runs one
identification step per batch (:class:`dsp_service.core.DspCore`), and
answers with the interrupt carrying the pole parameters, which also flags
the block empty again (thesis §3.2.3, Fig. 3.5 step 4: one message). Serving several rigs, each board's work happens
on its own thread, never in zenoh callbacks (one rig's batch never waits for
another's); a board serving one rig (``inline``) identifies in zenoh's batch
callback, so no thread wake-up lies on the batch -> interrupt path.

Time comes from an injected :class:`service_kit.clock.Scheduler`. The
emulated latency is a due time: the interrupt is held (the block stays
full) until it is due, while the board keeps taking events and notices a
stop within one wait of at most :data:`MAX_WAIT_S`.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import zenoh
from pydantic import ValidationError

from dsp_service.bank_file import load_bank, save_bank
from dsp_service.board import Admission
from dsp_service.core import BlockState, DspCore, identifier_config
from protocol.batch_codec import SampleBatch, decode_batch
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import BlockFlag, ConfigChange, Health, Interrupt, TfSnapshot, decode, encode, encode_fields
from protocol.settings import DspSettings
from protocol.tf_codec import encode_tf
from service_kit.clock import RealTimeScheduler, Scheduler
from service_kit.encodings import JSON, TF
from service_kit.inbox import LIMITS, Inbox
from service_kit.query_gate import OVER_RATE
from service_kit.query_gate import gate as query_gate
from service_kit.runtime import HealthPublisher, LatencyTracker

log = logging.getLogger(__name__)

__all__ = ["DspService", "identifier_config"]

MAX_WAIT_S = 0.05
"""The longest the board's thread waits for an event (so a stop is seen at once)."""
REANNOUNCE_S = 0.5
"""An idle board re-announces its empty block this often (a late controller learns it)."""


@dataclass
class _Event:
    kind: str
    payload: bytes = b""
    batch: SampleBatch | None = None
    admission: Admission | None = None
    arrival: float = 0.0
    change: ConfigChange | None = None
    held: _Held | None = None


@dataclass
class _Held:
    """An interrupt computed and waiting for its due time (the block stays full):
    its fields (:meth:`DspCore.process_fields`) and its wire bytes."""

    fields: dict[str, Any]
    payload: bytes
    due: float
    arrival: float

    @property
    def batch_seq(self) -> int:
        return int(self.fields["batch_seq"])


class DspService:
    """The board on zenoh: the core, publishers, health."""

    def __init__(self, settings: DspSettings, session: zenoh.Session, scheduler: Scheduler | None = None, inline: bool = False) -> None:
        self.settings = settings
        self.inline = inline
        """Identify in zenoh's batch callback instead of handing the batch to the board's thread
        (a DSP serving one rig: no thread wake-up on the path; several rigs keep one thread each)."""
        self._out_lock = threading.Lock()  # flags are numbered and sent from the board's thread and, inline, zenoh's
        self.keys = Keys(settings.rig_id)
        self.core = DspCore(settings)
        load_bank(self.core.identifier, settings)  # RALF_ARX_REGIME_BANK_FILE: the regimes earlier runs learned
        self.scheduler: Scheduler = scheduler or RealTimeScheduler()
        self.compute_time = LatencyTracker()
        self.turnaround = LatencyTracker()
        self.put_time = LatencyTracker()
        """Wall time of the interrupt's put (zenoh hands the message to its transmit thread when the put
        returns: docs/dsp-performance.md, "The zenoh path"); health's ``interrupt_put``."""
        self._events = Inbox("dsp", capacity=64, limits=LIMITS)  # size-capped, decoded in zenoh's threads, bounded (service_kit/inbox.py)
        self._held: _Held | None = None
        self._last_raised: _Held | None = None
        self._tf_gate = query_gate("tf")
        self._health_on = False
        """Health is being published (from :meth:`run` on): a new session's publisher starts at once."""
        self._binds = 0
        """Sessions the board was put on: its first, then one per move (service_kit/relink.py)."""
        self.bind(session)

    def bind(self, session: zenoh.Session) -> None:
        """Publishers, subscribers, the TF queryable, the liveliness token and
        health on ``session`` (at start, and on a new session after
        :meth:`unbind`: service_kit/relink.py)."""
        self.session = session
        block = zenoh.CongestionControl.BLOCK
        self._flag_pub = session.declare_publisher(self.keys.flag, encoding=JSON, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._irq_pub = session.declare_publisher(self.keys.interrupt, encoding=JSON, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._ack_pub = session.declare_publisher(self.keys.dsp_config_ack, encoding=JSON, congestion_control=block)
        self.board_id = str(session.info.zid()).encode()  # sent with flags and interrupts: the controller pairs with one board
        self._attachment = zenoh.ZBytes(self.board_id)  # converted once, not at every put
        self._subs = [
            session.declare_subscriber(self.keys.batch, self._events.subscriber("batch", self._on_batch_payload)),
            session.declare_subscriber(self.keys.dsp_config, self._events.subscriber("config", self._decode_config)),
        ]
        self._queryable = session.declare_queryable(self.keys.tf, self._on_tf_query)
        self._token = session.liveliness().declare_token(self.keys.alive("dsp"))
        self._health = HealthPublisher(session, self.keys.health("dsp"), self.settings.health_period_s, self._build_health)
        if self._health_on:
            self._health.start()
        self._binds += 1

    @property
    def out_lock(self) -> threading.Lock:
        """Held while a message goes out (and while the board moves to a new session)."""
        return self._out_lock

    def unbind(self) -> None:
        """Everything :meth:`bind` declared, undeclared (the session may be
        broken: what fails is logged, the rest goes on); health stopped."""
        self._health.stop()
        handles: list[Any] = [*self._subs, self._queryable, self._token, self._flag_pub, self._irq_pub, self._ack_pub]
        for handle in handles:
            try:
                handle.undeclare()
            except Exception as exc:  # noqa: BLE001 (a closed session's handles)
                log.debug("undeclare on the old session: %s", exc)

    # -- the core's state, as the tests and the composition read it ----------------------
    @property
    def identifier(self):
        return self.core.identifier

    @property
    def block(self):
        return self.core.block

    @property
    def batch_size(self) -> int:
        return self.core.batch_size

    @property
    def emulated_latency_s(self) -> float:
        return self.core.emulated_latency_s

    @property
    def interrupt_seq(self) -> int:
        return self.core.interrupt_seq

    @property
    def last_result(self):
        return self.core.last_result

    def budget_s(self, batch: SampleBatch) -> float:
        return self.core.budget_s(batch)

    # -- messages out -----------------------------------------------------------------
    def _publish_flag(self, state: BlockState) -> None:
        with self._out_lock:
            self._put_flag(self.core.flag(state))

    def _put_flag(self, flag: BlockFlag) -> None:
        self._flag_pub.put(encode(flag), attachment=self._attachment)

    def _build_health(self, seq: int) -> Health:
        counters = self.core.block.counters.as_dict()
        counters.update(self._events.as_dict())
        counters.update(self._tf_gate.as_dict())
        counters["interrupts"] = self.core.interrupt_seq
        counters["zenoh_relinks"] = max(0, self._binds - 1)
        state = "degraded" if self.core.last_batch_missed else "running"
        return Health(
            seq=seq,
            sim_time_s=self.core.last_sim_time,
            service="dsp",
            state=state,
            counters=counters,
            latencies={"compute": self.compute_time.stats(), "batch_to_interrupt": self.turnaround.stats(), "interrupt_put": self.put_time.stats()},
            last_miss=self.core.block.last_violation,
        )

    # -- handlers -----------------------------------------------------------------------
    def _decode_config(self, payload: bytes) -> _Event:
        """A config change decoded in zenoh's thread; an invalid one counts as a decode error."""
        try:
            return _Event("config", change=decode(ConfigChange, payload))
        except ProtocolError:
            with self.core.block_lock:
                self.core.block.counters.decode_errors += 1
            raise

    def _on_batch_payload(self, payload: bytes) -> None:
        """A batch arrives in the block (zenoh's thread, size-capped by the
        inbox): decoded, checked and admitted here, so a batch arriving while
        the block is full is seen as the protocol violation it is; the
        identification runs on our thread. Queues itself; returns None."""
        arrival = self.scheduler.now()
        try:
            batch = decode_batch(payload)
        except ProtocolError as exc:
            with self.core.block_lock:
                self.core.block.counters.decode_errors += 1
                self.core.block.last_violation = f"undecodable batch: {exc}"
            self._events.log.warning("batch:undecodable", "dropped an undecodable batch: %s", exc)
            return None
        last = self._last_raised
        if last is not None and batch.seq == last.batch_seq and batch.seq == self.core.block.next_seq - 1 and not self.core.block.full:
            # The CPU sent the batch we answered last again: its interrupt was lost
            # (a starved peer's session dropped). Answer it again, the same interrupt.
            self._events.put("batch", _Event("repeat", arrival=arrival))
            return None
        admission = self.core.admit(batch)
        if not admission.accepted:
            return None
        if not self.inline:
            self._events.put("batch", _Event("batch", batch=batch, admission=admission, arrival=arrival))
            return None
        try:
            held = self._compute(batch, admission, arrival)
        except Exception as exc:
            self._internal_error("batch", exc)
            return None
        if self.scheduler.now() >= held.due:
            self._raise_safely(held)  # latency 0: raised here, no thread on the path
        else:
            self._events.put("batch", _Event("held", held=held, arrival=arrival))  # the board's thread holds it until due
        return None

    def _on_tf_query(self, query: zenoh.Query) -> None:
        """A TF query: answered within the rate (:mod:`service_kit.query_gate`), else refused with a short error, counted."""
        try:
            if not self._tf_gate.admit():
                query.reply_err(OVER_RATE)
                return
            query.reply(self.keys.tf, encode_tf(self.snapshot()), encoding=TF)
            self._tf_gate.note_answered()
        except Exception as exc:  # never let a query kill zenoh's thread
            self._tf_gate.note_failed()
            log.exception("TF query failed")
            query.reply_err(str(exc).encode())

    def snapshot(self) -> TfSnapshot:
        """The current transfer-function estimates (magnitude and phase); a
        query gets them in the binary layout of :mod:`protocol.tf_codec`."""
        return self.core.snapshot()

    def apply_config(self, change: ConfigChange) -> None:
        self.core.apply_config(change)

    def _compute(self, batch: SampleBatch, admission: Admission, arrival: float) -> _Held:
        fields = self.core.process_fields(batch, admission)
        due = arrival + self.core.due_after(fields["compute_time_s"], self.settings.clock == "realtime")
        return _Held(fields, encode_fields(fields), due, arrival)

    def _raise(self, held: _Held) -> Interrupt | None:
        """Fig. 3.5 step 4: release the block and raise the interrupt, one message.

        The interrupt *is* the block-empty flag of its batch: the board
        releases the block before it raises the interrupt, so an interrupt for
        batch ``k`` says the block is empty and batch ``k + 1`` is expected
        (:meth:`controller.dsp_link.DspLink.on_interrupt` takes it so). No
        separate empty flag follows it (one put per batch on the batch ->
        interrupt path, nothing behind it in zenoh's callback); flags still
        go at start, after every config change, on a re-announce and after an
        internal error, and a controller takes a trailing flag of an older
        board as the echo it is (``ControllerService._echoes_interrupt``).
        The bookkeeping comes after the put, and so does the interrupt's own
        validation: its bytes were made from its fields by pydantic's
        serializer (:func:`protocol.messages.encode_fields`) and the model is
        built from the same fields once they are out, so a field the model
        refuses is an internal error here (counted, reported, an empty flag
        sent; the block is already released) as the controller refuses the
        payload (counted there), and a resend of that batch is not answered
        with the same bytes again. Returns the validated interrupt (None if
        it was refused)."""
        self._last_raised = held  # before the release: a resend seeing an empty block finds it
        core = self.core
        with self._out_lock:
            with core.block_lock:
                core.block.release()
            started = perf_counter()
            self._irq_pub.put(held.payload, attachment=self._attachment)
            put_s = perf_counter() - started
        self.put_time.add(put_s)
        self.turnaround.add(self.scheduler.now() - held.arrival)
        self.compute_time.add(held.fields["compute_time_s"])
        try:
            return Interrupt(**held.fields)
        except ValidationError as exc:
            self._last_raised = None
            self._internal_error(f"interrupt (batch {held.batch_seq}, sent and refused by the model)", exc, release=False)
            return None

    def _raise_safely(self, held: _Held) -> None:
        """:meth:`_raise` where nothing may escape (zenoh's callback, the board's
        loop): anything else that fails on the way out is an internal error too."""
        try:
            self._raise(held)
        except Exception as exc:
            self._internal_error("interrupt", exc)

    def process_batch(self, batch: SampleBatch, admission: Admission | None = None) -> Interrupt | None:
        """One pass of Fig. 3.5 steps 3-4 for a batch (admitted here unless it
        already was on arrival), raised at once: for tests and direct callers."""
        if admission is None:
            admission = self.core.admit(batch)
        if not admission.accepted:
            return None
        return self._raise(self._compute(batch, admission, self.scheduler.now()))

    def _handle(self, event: _Event) -> None:
        if event.kind == "batch" and event.batch is not None and event.admission is not None:
            self._held = self._compute(event.batch, event.admission, event.arrival)
        elif event.kind == "held" and event.held is not None:
            self._held = event.held  # computed inline in zenoh's thread, due later
        elif event.kind == "repeat" and self._last_raised is not None and self._held is None:
            self.core.block.counters.interrupts_repeated += 1
            log.warning("batch %d came again: its interrupt is raised again", self._last_raised.batch_seq)
            with self._out_lock:
                self._irq_pub.put(self._last_raised.payload, attachment=self._attachment)  # the same interrupt: the block is empty again
        elif event.kind == "config" and event.change is not None:
            change = event.change  # decoded (and counted if invalid) by the inbox
            refused = ""
            try:
                self.apply_config(change)
            except ValueError as exc:
                refused = str(exc)
                self.core.block.counters.config_rejected += 1
                self.core.block.last_violation = f"config change refused: {exc}"
                log.warning("refused a config change the board cannot take: %s", exc)
            with self._out_lock:
                self._ack_pub.put(encode(self.core.config_ack(change, refused)))
            self._publish_flag("empty" if not self.core.block.full else "full")

    def _handle_safely(self, event: _Event) -> None:
        """Nothing a peer sends may kill the board: an unexpected error is
        counted and reported, and the block is released so the CPU goes on."""
        try:
            self._handle(event)
        except Exception as exc:
            self._held = None
            self._internal_error(event.kind, exc)

    def _internal_error(self, kind: str, exc: Exception, release: bool = True) -> None:
        """Counted and reported; an empty flag tells the controller where the
        block stands (``release``: released first; False when it already is,
        e.g. an interrupt refused after its put)."""
        core = self.core
        core.block.counters.internal_errors += 1
        core.block.last_violation = f"internal error on a {kind}: {exc!r}"
        log.exception("internal error while handling a %s; block %s", kind, "released" if release else "left as it is")
        with self._out_lock:
            self._put_flag(core.release() if release else core.flag("full" if core.block.full else "empty"))

    def _save_bank(self) -> None:
        """Write the ARX regime bank (``RALF_ARX_REGIME_BANK_FILE``) once no batch can come any more (the
        subscribers are gone) and under the identifier's lock (a batch identified in zenoh's thread a moment
        ago has finished with it)."""
        with self.core.tf_lock:
            save_bank(self.core.identifier, self.settings)

    def run(self, stop: threading.Event) -> None:
        """Serve until ``stop`` is set (seen within :data:`MAX_WAIT_S`, whatever is held)."""
        if isinstance(self.scheduler, RealTimeScheduler):
            self.scheduler.stop = stop
        self._health_on = True
        self._health.start()
        self._publish_flag("empty")  # Fig. 3.5 step 1: the block starts empty
        last_flag = self.scheduler.now()
        while not stop.is_set():
            now = self.scheduler.now()
            if self._held is not None and now >= self._held.due:
                held, self._held = self._held, None
                self._raise_safely(held)
                last_flag = now
                continue
            timeout = MAX_WAIT_S if self._held is None else min(MAX_WAIT_S, max(0.0, self._held.due - now))
            item = self._events.get(timeout=timeout)
            if item is None:
                # Re-announce an empty block now and then, so a controller that
                # starts after us (or missed the first flag) learns it.
                if self._held is None and not self.core.block.full and self.scheduler.now() - last_flag > REANNOUNCE_S:
                    self._publish_flag("empty")
                    last_flag = self.scheduler.now()
                continue
            self._handle_safely(item.message)
            last_flag = self.scheduler.now()

    def close(self) -> None:
        self._health.stop()
        for sub in self._subs:
            sub.undeclare()
        self._save_bank()
        self._queryable.undeclare()
        self._token.undeclare()
        self._flag_pub.undeclare()
        self._irq_pub.undeclare()
        self._ack_pub.undeclare()
