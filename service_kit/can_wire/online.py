"""The bus of :func:`service_kit.can_wire.arbitration.simulate`, one frame at a time.

:func:`~service_kit.can_wire.arbitration.simulate` needs every frame up
front; a co-simulation learns its frames as it goes (a node answers a frame
when it arrives). :class:`OnlineBus` takes frames as they are queued and
decides the next attempt when asked, by the same rule: the bus starts at
``max(bus free, earliest queued frame)``; of the frames queued by then the
lowest ``(arbitration_key, queued_ns, submission order)`` wins (each node's
own best first, then the best of those: the same frame); it occupies the
bus for its exact bits, intermission included.

**Errors** (off unless :meth:`OnlineBus.inject` is given injections): the
same rules as :func:`simulate` with ``errors``, through the same parts: an
:class:`~service_kit.can_wire.arbitration.Injector` per
:class:`~service_kit.can_wire.arbitration.ErrorInjection` decides which
attempt fails, :func:`~service_kit.can_wire.wire_errors.error_attempt`
gives its bits, and every node is a
:class:`~service_kit.can_wire.wire_errors.WireNode` whose
:class:`~service_kit.can_wire.error_state.FaultConfinement` counts (rules
1-3 and 7-12), with an error-passive transmitter's suspend transmission
and a bus-off node's recovery after 128 x 11 recessive bits. A failed
attempt (:attr:`Sent.transmission` None) leaves its frame queued: it
contends again at the next idle moment. Without injections nothing of this
runs (no counters, no ACK errors: a lone sender is never refused).

The caller's promise: before :meth:`OnlineBus.commit` every frame that
will ever be queued at or before :meth:`OnlineBus.next_start` has been
submitted (a node's answer to a frame is queued when that frame's last bit
is gone, which is before the bus is free again). Given all frames in
submission order equal to :func:`simulate`'s input order (and, with errors,
the same nodes and injections), the attempts, transmissions and every
node's state timeline are :func:`simulate`'s (tested), the submission index
standing for the input index.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

from service_kit.can_wire.arbitration import INTERMISSION_BITS, Attempt, ErrorInjection, Injector, Transmission
from service_kit.can_wire.bits import FrameBits
from service_kit.can_wire.error_state import SUSPEND_BITS, ErrorState, FaultConfinement
from service_kit.can_wire.timing import bit_time_ns
from service_kit.can_wire.wire_errors import ACTIVE_STATUS, ErrorStatus, WireNode, error_attempt, monitor_error_attempt


@dataclass(frozen=True)
class _Queued:
    key: tuple[int, ...]
    queued_ns: int
    seq: int
    node: str
    frame: FrameBits
    tag: Any


@dataclass(frozen=True)
class Sent:
    """One attempt and what its sender attached to the frame; ``transmission`` is None
    when an error frame cut it (the frame stays queued)."""

    transmission: Transmission | None
    frame: FrameBits
    tag: Any
    attempt: Attempt | None = None
    """The attempt as :attr:`BusRun.attempts <service_kit.can_wire.arbitration.BusRun.attempts>` (with errors on only)."""


@dataclass
class OnlineBus:
    """A CAN bus fed frame by frame (module docstring)."""

    bitrate: int
    bus_free_ns: int = 0
    nodes: dict[str, WireNode] = field(default_factory=dict)
    """Every node with its counters and state timeline (with errors on; :meth:`add_node`, or its first frame)."""
    error_frames: int = 0
    """Attempts cut by an error frame."""
    rec_after_passive_success: int = 127
    _pending: list[_Queued] = field(default_factory=list)
    _seq: int = 0
    _injectors: list[Injector] = field(default_factory=list)
    _attempts: dict[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._bit = bit_time_ns(self.bitrate)

    @property
    def errors_on(self) -> bool:
        """Whether errors are injected (:meth:`inject`): only then are counters kept and ACK errors made."""
        return bool(self._injectors)

    def inject(self, *specs: ErrorInjection) -> None:
        """Adds error injections; their counts and draws start now."""
        self._injectors.extend(Injector(s) for s in specs)

    def add_node(self, name: str) -> WireNode:
        """A node on the bus (a receiver that acknowledges, and counts, even before it sends)."""
        node = self.nodes.get(name)
        if node is None:
            node = self.nodes[name] = WireNode(name, FaultConfinement(rec_after_passive_success=self.rec_after_passive_success))
            self.nodes = dict(sorted(self.nodes.items()))  # the bus model's order of nodes
        return node

    def submit(self, node: str, queued_ns: int, frame: FrameBits, tag: Any = None) -> int:
        """Queue ``frame`` of ``node`` at ``queued_ns``; returns its submission index."""
        seq = self._seq
        self._seq += 1
        if node not in self.nodes:
            self.add_node(node)
        self._pending.append(_Queued(frame.arbitration_key, queued_ns, seq, node, frame, tag))
        return seq

    @property
    def pending(self) -> int:
        return len(self._pending)

    def next_start(self) -> int | None:
        """When the next attempt starts, from the frames known (None: none pending)."""
        if not self._pending:
            return None
        if not self._injectors:
            return max(self.bus_free_ns, min(q.queued_ns for q in self._pending))
        fcs = {n: copy.copy(w.fc) if w.fc.bus_off else w.fc for n, w in self.nodes.items()}  # idle bits change bus-off nodes only
        return self._settle(fcs, None)

    def settle(self) -> int | None:
        """Runs the bus up to the next attempt's start without starting it (with errors on, bus-off
        nodes count the idle bits and may recover: :attr:`WireNode.changes`); returns the start.
        Frames then submitted at or before it still contend for it."""
        if not self._pending or not self._injectors:
            return self.next_start()
        self.bus_free_ns = self._settle({n: w.fc for n, w in self.nodes.items()}, self.nodes)
        return self.bus_free_ns

    def _ready(self, q: _Queued, bus_free: int, fcs: dict[str, FaultConfinement]) -> bool:
        return q.queued_ns <= bus_free and not fcs[q.node].bus_off and self.nodes[q.node].suspend_until_ns <= bus_free

    def _settle(self, fcs: dict[str, FaultConfinement], notes: dict[str, WireNode] | None) -> int:
        """:func:`simulate`'s idle loop: from the bus's free moment to the first moment a frame may start,
        bus-off nodes counting the idle bits (rule 12); ``notes``: record their recoveries (else a dry run)."""
        bus_free = self.bus_free_ns
        while not any(self._ready(q, bus_free, fcs) for q in self._pending):
            later = [q.queued_ns for q in self._pending if q.queued_ns > bus_free]
            wake = [min(later)] if later else []
            for name in {q.node for q in self._pending if q.queued_ns <= bus_free}:
                to_recover = fcs[name].idle_bits_to_recover()
                wake.append(bus_free + to_recover * self._bit if to_recover is not None else self.nodes[name].suspend_until_ns)
            t = max(min(wake), bus_free)
            n_bits = (t - bus_free) // self._bit
            for name, fc in fcs.items():
                done = fc.monitor_idle(n_bits)
                if done is not None and notes is not None:
                    notes[name].note(bus_free + done * self._bit)
            bus_free = t
        return bus_free

    def commit(self) -> Sent:
        """Puts the next attempt on the bus (the caller's promise: module docstring)."""
        if not self._pending:
            raise ValueError("no frame pending")
        if self._injectors:
            return self._commit_with_errors()
        start = max(self.bus_free_ns, min(q.queued_ns for q in self._pending))
        winner = min((q for q in self._pending if q.queued_ns <= start), key=lambda q: (q.key, q.queued_ns, q.seq))
        self._pending.remove(winner)
        end = start + winner.frame.n_bits * self._bit
        self.bus_free_ns = end
        return Sent(self._transmission(winner, start, end, 1), winner.frame, winner.tag)

    def _transmission(self, q: _Queued, start: int, end: int, attempts: int) -> Transmission:
        return Transmission(
            index=q.seq,
            node=q.node,
            arbitration_id=q.frame.arbitration_id,
            queued_ns=q.queued_ns,
            start_ns=start,
            last_bit_ns=end - INTERMISSION_BITS * self._bit,
            end_ns=end,
            attempts=attempts,
        )

    def _commit_with_errors(self) -> Sent:
        """One attempt as :func:`simulate` makes it, errors and fault confinement included."""
        nodes, bit = self.nodes, self._bit
        start = self.bus_free_ns = self._settle({n: w.fc for n, w in nodes.items()}, nodes)
        best: dict[str, _Queued] = {}
        for q in self._pending:
            if self._ready(q, start, {q.node: nodes[q.node].fc}):
                b = best.get(q.node)
                if b is None or (q.key, q.queued_ns, q.seq) < (b.key, b.queued_ns, b.seq):
                    best[q.node] = q
        offers = sorted(best.values(), key=lambda q: (q.key, q.queued_ns, q.seq))
        winner = offers[0]
        frame = winner.frame
        tx = nodes[winner.node]
        attempt_no = self._attempts[winner.seq] = self._attempts.get(winner.seq, 0) + 1
        receivers = [n for n in nodes.values() if n is not tx and not n.fc.bus_off]
        injected = next((i.spec for i in self._injectors if i.fires(winner.node, frame, start, attempt_no)), None)
        ack_error = injected is None and not receivers
        transmission = None
        if injected is None and not ack_error:
            self._pending.remove(winner)
            del self._attempts[winner.seq]
            end = start + frame.n_bits * bit
            n_bits = frame.n_bits
            tx.fc.transmit_success()
            for n in receivers:
                n.fc.receive_success()
            for n in nodes.values():
                done = n.fc.monitor(frame.bits)
                if done is not None:
                    n.note(start + done * bit)
            transmission = self._transmission(winner, start, end, attempt_no)
        else:
            self.error_frames += 1
            was_bus_off = {n.name for n in nodes.values() if n.fc.bus_off}
            tx.fc.transmit_error(ack_error=ack_error, dominant_during_passive_flag=False)
            for n in receivers:
                n.fc.receive_error()
            cut = error_attempt(frame, injected, tx.fc.state is ErrorState.PASSIVE)
            for n in nodes.values():
                n.note(start + len(cut.sent) * bit)
            n_bits = cut.n_bits
            end = start + n_bits * bit
            monitor_error_attempt(list(nodes.values()), was_bus_off, cut, start, bit)
        for n in nodes.values():
            n.note(end)
        if tx.fc.state is ErrorState.PASSIVE:
            tx.suspend_until_ns = end + SUSPEND_BITS * bit
        self.bus_free_ns = end
        attempt = Attempt(
            index=winner.seq,
            node=winner.node,
            arbitration_id=frame.arbitration_id,
            start_ns=start,
            end_ns=end,
            ok=transmission is not None,
            bits=n_bits,
            losers=tuple(q.seq for q in offers[1:]),
            ack_error=ack_error,
        )
        return Sent(transmission, frame, winner.tag, attempt)

    def status(self, node: str, t_ns: int) -> ErrorStatus:
        """``node``'s error state and counters in force at ``t_ns`` (:meth:`WireNode.status_at`; error active for a node never seen)."""
        w = self.nodes.get(node)
        return w.status_at(t_ns) if w is not None else ACTIVE_STATUS
