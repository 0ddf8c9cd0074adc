"""The rest of the bus from a DBC: the cyclic traffic of the vehicle's other
nodes, as a HIL restbus sends it. Off by default: nothing in the rig uses it
unless asked.

A DBC message is sent when it has the ``GenMsgCycleTime`` attribute (ms,
> 0); the others are listed as not sent. ``GenMsgStartDelayTime`` (ms, if
present) delays its first instance. Each sender node (the message's
transmitter, ``Restbus`` if none) is a CAN controller with
priority-ordered transmit buffers. Signals start at ``GenSigStartValue``
(raw, cantools' ``raw_initial``; 0 if absent) and keep it, except:

- **counter**: a signal with the attribute ``RestbusRole`` = ``"counter"``
  (factor 1, offset 0) takes ``lo + (start - lo + k) mod (hi - lo + 1)`` in
  the message's ``k``-th instance, ``start`` its start value and ``lo..hi``
  its DBC range (the whole raw range if the DBC gives none; AUTOSAR E2E
  profile 1's 4-bit counter is ``[0|14]``);
- **checksum**: a signal with ``RestbusRole`` = ``"crc8_sae_j1850"`` or
  ``"crc8_h2f"`` must fill one whole byte; it carries the CRC over the
  message's data ID (attribute ``RestbusDataId``, default its frame id;
  low byte then high byte, as E2E profile 1's data-ID mode "both") followed
  by the payload's other bytes in order. CRC-8/SAE-J1850 (poly 0x1D, init
  and final XOR 0xFF, check 0x4B; AUTOSAR's ``Crc_CalculateCRC8``, the CRC of
  E2E profile 1) and CRC-8/8H2F (poly 0x2F, init and final XOR 0xFF, check
  0xDF; AUTOSAR's ``Crc_CalculateCRC8H2F``, E2E profile 2), both computed by
  crccheck. The layout is E2E-like; it does not claim any E2E profile's
  exact data-ID handling.

Payloads are encoded by cantools. :func:`schedule` lists the instances in
time order; two back-ends send them: :func:`simulate_restbus` (the
arbitration model, simulated time, deterministic) and
:class:`service_kit.can_wire.restbus.sender.RestbusSender` (a python-can
bus, real time or an injected clock).

:func:`check` lists what forbids a start: an unsupported bit rate, a load
above 100 %, an identifier of the rig's own (``protocol/ralf.dbc``). The CLI
(``python -m service_kit.can_wire.restbus DBC --bitrate 1000000``) prints
them, one line each, and exits 2.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from crccheck.crc import Crc8Autosar, Crc8SaeJ1850

from service_kit.can_wire.arbitration import BusRun, QueuedFrame, simulate
from service_kit.can_wire.bits import FrameBits, frame_bits
from service_kit.can_wire.timing import STANDARD_BITRATES, bit_time_ns

ROLE_ATTRIBUTE = "RestbusRole"
DATA_ID_ATTRIBUTE = "RestbusDataId"
COUNTER = "counter"
CHECKSUMS: dict[str, Any] = {"crc8_sae_j1850": Crc8SaeJ1850, "crc8_h2f": Crc8Autosar}
"""Checksum kinds: crccheck's classes (CRC-8/SAE-J1850 and CRC-8/AUTOSAR, i.e. 8H2F)."""
DEFAULT_NODE = "Restbus"
NS_PER_MS = 1_000_000


class RestbusError(ValueError):
    """A DBC or a setting the restbus cannot use (one line)."""


@dataclass(frozen=True)
class CyclicMessage:
    """A DBC message the restbus sends every ``cycle_ns``."""

    name: str
    frame_id: int
    extended: bool
    node: str
    cycle_ns: int
    offset_ns: int
    raw_values: dict[str, float]
    """Every signal's raw start value."""
    counter: str | None = None
    counter_range: tuple[int, int] = (0, 0)
    checksum: str | None = None
    checksum_kind: str = ""
    checksum_byte: int = 0
    data_id: int = 0
    message: Any = field(default=None, compare=False, repr=False)
    """The cantools message."""

    @property
    def counter_period(self) -> int:
        """Instances after which the payload repeats."""
        if self.counter is None:
            return 1
        lo, hi = self.counter_range
        return hi - lo + 1

    def counter_value(self, k: int) -> int:
        lo, hi = self.counter_range
        start = int(self.raw_values[self.counter]) if self.counter is not None else lo
        return lo + (start - lo + k) % (hi - lo + 1)

    def payload(self, k: int) -> bytes:
        """The ``k``-th instance's data (module docstring), encoded by cantools."""
        values = dict(self.raw_values)
        if self.counter is not None:
            values[self.counter] = self.counter_value(k)
        if self.checksum is not None:
            values[self.checksum] = 0
        data = bytearray(self.message.encode(values, scaling=False, strict=False))
        if self.checksum is not None:
            data[self.checksum_byte] = checksum(self.checksum_kind, self.data_id, data, self.checksum_byte)
        return bytes(data)

    def frame(self, k: int) -> FrameBits:
        return frame_bits(self.frame_id, self.payload(k), extended=self.extended)

    @property
    def dlc(self) -> int:
        return int(self.message.length)


def checksum(kind: str, data_id: int, data: bytes | bytearray, skip: int) -> int:
    """The CRC of ``kind`` over the data ID (low, high byte) and ``data`` without byte ``skip``."""
    body = bytes([data_id & 0xFF, (data_id >> 8) & 0xFF]) + bytes(data[:skip]) + bytes(data[skip + 1 :])
    return int(CHECKSUMS[kind].calc(body))


@dataclass(frozen=True)
class Restbus:
    """The cyclic messages of a DBC, and the ones it leaves out."""

    messages: tuple[CyclicMessage, ...]
    not_sent: tuple[str, ...]
    """Messages without a cycle time."""
    source: str = ""


@dataclass(frozen=True)
class Instance:
    time_ns: int
    message: CyclicMessage
    k: int

    def payload(self) -> bytes:
        return self.message.payload(self.k)


def _attribute(obj: Any, name: str) -> Any:
    dbc = getattr(obj, "dbc", None)
    if dbc is None or name not in dbc.attributes:
        return None
    return dbc.attributes[name].value


def _checksum_byte(message: Any, signal: Any, raw: dict[str, float]) -> int:
    """The byte the 8-bit ``signal`` fills alone (RestbusError otherwise)."""
    if signal.length != 8 or signal.is_signed or signal.scale != 1 or signal.offset != 0:
        raise RestbusError(f"checksum {message.name}.{signal.name} must be an unsigned 8-bit signal, factor 1, offset 0")
    zeros = {name: 0 for name in raw}
    base = bytes(message.encode(zeros, scaling=False, strict=False))
    full = bytes(message.encode({**zeros, signal.name: 0xFF}, scaling=False, strict=False))
    changed = [i for i, (a, b) in enumerate(zip(base, full, strict=True)) if a != b]
    if len(changed) != 1 or full[changed[0]] != 0xFF or base[changed[0]] != 0:
        raise RestbusError(f"checksum {message.name}.{signal.name} must fill exactly one byte")
    return changed[0]


def _raw_limits(signal: Any) -> tuple[int, int]:
    if signal.is_signed:
        return -(1 << (signal.length - 1)), (1 << (signal.length - 1)) - 1
    return 0, (1 << signal.length) - 1


def _counter_range(message: Any, signal: Any) -> tuple[int, int]:
    if signal.scale != 1 or signal.offset != 0:
        raise RestbusError(f"counter {message.name}.{signal.name} must have factor 1, offset 0")
    raw_lo, raw_hi = _raw_limits(signal)
    lo = raw_lo if signal.minimum is None else max(raw_lo, math.ceil(signal.minimum))
    hi = raw_hi if signal.maximum is None else min(raw_hi, math.floor(signal.maximum))
    if hi <= lo:
        raise RestbusError(f"counter {message.name}.{signal.name} has no range to count in ({lo}..{hi})")
    return lo, hi


def _cyclic(message: Any) -> CyclicMessage | None:
    cycle = message.cycle_time
    if not cycle:
        return None
    if message.is_fd or message.length > 8:
        raise RestbusError(f"message {message.name} is CAN FD or longer than 8 bytes: classical CAN only")
    if message.is_multiplexed():
        raise RestbusError(f"message {message.name} is multiplexed: not supported")
    raw = {s.name: float(s.raw_initial) if s.raw_initial is not None else 0.0 for s in message.signals}
    delay = _attribute(message, "GenMsgStartDelayTime")
    data_id = _attribute(message, DATA_ID_ATTRIBUTE)
    counter: str | None = None
    counter_range = (0, 0)
    csum: str | None = None
    kind = ""
    csum_byte = 0
    for s in message.signals:
        role = _attribute(s, ROLE_ATTRIBUTE)
        if role in (None, ""):
            continue
        if role == COUNTER:
            if counter is not None:
                raise RestbusError(f"message {message.name} has two counters ({counter}, {s.name})")
            counter, counter_range = s.name, _counter_range(message, s)
        elif role in CHECKSUMS:
            if csum is not None:
                raise RestbusError(f"message {message.name} has two checksums ({csum}, {s.name})")
            csum, kind, csum_byte = s.name, str(role), _checksum_byte(message, s, raw)
        else:
            known = ", ".join([COUNTER, *CHECKSUMS])
            raise RestbusError(f"signal {message.name}.{s.name}: {ROLE_ATTRIBUTE} {role!r} is none of {known}")
    if counter is not None:
        lo, hi = counter_range
        if not lo <= raw[counter] <= hi:
            raise RestbusError(f"counter {message.name}.{counter} starts at {raw[counter]:g}, outside {lo}..{hi}")
    for s in message.signals:
        if s.is_float:
            continue
        lo, hi = _raw_limits(s)
        if not lo <= raw[s.name] <= hi or raw[s.name] != int(raw[s.name]):
            kind = "signed" if s.is_signed else "unsigned"
            raise RestbusError(f"signal {message.name}.{s.name}: start value {raw[s.name]:g} is no raw value of {s.length} {kind} bits")
    cyclic = CyclicMessage(
        name=message.name,
        frame_id=int(message.frame_id),
        extended=bool(message.is_extended_frame),
        node=message.senders[0] if message.senders else DEFAULT_NODE,
        cycle_ns=int(round(float(cycle) * NS_PER_MS)),
        offset_ns=int(round(float(delay) * NS_PER_MS)) if delay else 0,
        raw_values=raw,
        counter=counter,
        counter_range=counter_range,
        checksum=csum,
        checksum_kind=kind,
        checksum_byte=csum_byte,
        data_id=int(data_id) if data_id is not None else int(message.frame_id),
        message=message,
    )
    try:
        cyclic.payload(0)
    except Exception as exc:  # cantools' encoders raise several types
        raise RestbusError(f"message {message.name} cannot be encoded from its start values: {exc}") from exc
    return cyclic


def from_database(db: Any, source: str = "") -> Restbus:
    """The restbus of a cantools database (module docstring); RestbusError for what it cannot send."""
    cyclic: list[CyclicMessage] = []
    not_sent: list[str] = []
    for message in db.messages:
        c = _cyclic(message)
        if c is None:
            not_sent.append(message.name)
        else:
            cyclic.append(c)
    return Restbus(tuple(cyclic), tuple(not_sent), source)


def load(path: Path | str) -> Restbus:
    """Reads a DBC; RestbusError (one line) when it does not parse or cannot be sent."""
    import cantools

    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except (OSError, UnicodeDecodeError) as exc:
        raise RestbusError(f"cannot read {path}: {exc}") from exc
    except Exception as exc:  # cantools raises its own errors and pyparsing's/textparser's
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RestbusError(f"{path} is not a DBC cantools can parse: {first}") from exc
    return from_database(db, str(path))


def drifted(t_ns: int, ppm: int) -> int:
    """``t_ns`` on a clock that runs slow by ``ppm`` parts per million (integer nanoseconds)."""
    return t_ns + t_ns * ppm // 1_000_000


def schedule(messages: Sequence[CyclicMessage], until_ns: int, start_ns: int = 0, *, drift_ppm: Mapping[str, int] | None = None) -> Iterator[Instance]:
    """Every instance queued in ``[start_ns, start_ns + until_ns)``, in time order (ties by
    identifier). ``drift_ppm`` slows nodes' clocks: their offsets and cycle times stretch by that
    many parts per million."""
    drift = drift_ppm or {}
    heap: list[tuple[int, int, int, int]] = []
    periods = [drifted(m.cycle_ns, drift.get(m.node, 0)) for m in messages]
    for i, m in enumerate(messages):
        offset = drifted(m.offset_ns, drift.get(m.node, 0))
        if offset < until_ns:
            heap.append((start_ns + offset, m.frame_id, i, 0))
    heapq.heapify(heap)
    while heap:
        t, ident, i, k = heapq.heappop(heap)
        yield Instance(t, messages[i], k)
        t_next = t + periods[i]
        if t_next < start_ns + until_ns:
            heapq.heappush(heap, (t_next, ident, i, k + 1))


def spread_drift(nodes: Sequence[str], max_ppm: int) -> dict[str, int]:
    """Clocks slow by 0..``max_ppm`` ppm, spread evenly over ``nodes`` in name order."""
    names = sorted(set(nodes))
    if len(names) < 2:
        return dict.fromkeys(names, 0)
    return {n: j * max_ppm // (len(names) - 1) for j, n in enumerate(names)}


# -- the rig's own frames --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RigMessage:
    """One of the rig's frames that crosses the bus every sample period."""

    name: str
    node: str
    frame: FrameBits
    cycle_ns: int


def rig_identifiers() -> dict[int, str]:
    """Every identifier of ``protocol/ralf.dbc`` (NMT, SYNC, EMCY, PDOs, SDO, heartbeat)."""
    from service_kit.can_wire.report import load_dbc

    return {int(m.frame_id): m.name for m in load_dbc().messages}


def rig_cycle() -> tuple[RigMessage, ...]:
    """SYNC, TPDO1 and RPDO1 at the rig's SYNC cycle time (``GenMsgCycleTime`` of SYNC in
    ``protocol/ralf.dbc``), their payloads at rest (as in ``docs/results/can-wire-times.md``): the
    rig's traffic in every sample period."""
    from service_kit.can_wire.report import CYCLE, at_rest_value, load_dbc

    db = load_dbc()
    cycle_ns = int(db.get_message_by_name("SYNC").cycle_time) * NS_PER_MS
    out = []
    for name in CYCLE:
        m = db.get_message_by_name(name)
        data = bytes(m.encode({s.name: at_rest_value(s) for s in m.signals}))
        out.append(RigMessage(name, m.senders[0], frame_bits(m.frame_id, data, extended=bool(m.is_extended_frame)), cycle_ns))
    return tuple(out)


# -- load and checks --------------------------------------------------------------------------------------------


def mean_bits(m: CyclicMessage) -> float:
    """Mean exact frame length (stuff bits, intermission) over one period of its payloads."""
    n = m.counter_period
    return sum(m.frame(k).n_bits for k in range(n)) / n


def offered_load(restbus: Restbus, bitrate: int, *, rig: Sequence[RigMessage] = ()) -> float:
    """Share of the bus the messages take in the long run: sum of mean exact frame time / cycle time."""
    bit = bit_time_ns(bitrate)
    total = sum(mean_bits(m) * bit / m.cycle_ns for m in restbus.messages)
    return total + sum(r.frame.n_bits * bit / r.cycle_ns for r in rig)


def check(restbus: Restbus, bitrate: int, *, rig_ids: dict[int, str] | None = None, rig: Sequence[RigMessage] = ()) -> list[str]:
    """What forbids sending this restbus at ``bitrate`` beside the rig (one line each; empty: fine)."""
    problems: list[str] = []
    if bitrate not in STANDARD_BITRATES:
        rates = ", ".join(str(r) for r in STANDARD_BITRATES)
        problems.append(f"unsupported bit rate {bitrate} bit/s (one of {rates})")
        return problems
    ids = rig_identifiers() if rig_ids is None else rig_ids
    for m in restbus.messages:
        if not m.extended and m.frame_id in ids:
            problems.append(f"message {m.name} uses identifier 0x{m.frame_id:03X}, the rig's {ids[m.frame_id]}")
    seen: dict[tuple[int, bool], str] = {}
    for m in restbus.messages:
        key = (m.frame_id, m.extended)
        if key in seen:
            problems.append(f"messages {seen[key]} and {m.name} share identifier 0x{m.frame_id:X}")
        seen[key] = m.name
    load = offered_load(restbus, bitrate, rig=rig)
    if load > 1.0:
        problems.append(f"load {100 * load:.1f} % at {bitrate} bit/s is above 100 %")
    return problems


# -- back-end (a): the arbitration model -----------------------------------------------------------------------


@dataclass(frozen=True)
class SimulatedRun:
    run: BusRun
    names: dict[int, str]
    """Message name per input index of the run."""


def simulate_restbus(
    restbus: Restbus,
    bitrate: int,
    until_ns: int,
    *,
    rig: Sequence[RigMessage] = (),
    drift_ppm: Mapping[str, int] | None = None,
) -> SimulatedRun:
    """The restbus and the rig's cyclic frames (released together at 0, every cycle) on the
    arbitration model for ``until_ns`` of queuing; the bus runs until every queued frame is sent.
    ``drift_ppm`` slows the nodes' clocks (:func:`schedule`; the rig's nodes too)."""
    drift = drift_ppm or {}
    queued: list[QueuedFrame] = []
    names: dict[int, str] = {}
    frames: dict[tuple[str, int], FrameBits] = {}
    for inst in schedule(restbus.messages, until_ns, drift_ppm=drift):
        m = inst.message
        key = (m.name, inst.k % m.counter_period)
        if key not in frames:
            frames[key] = m.frame(inst.k)
        names[len(queued)] = m.name
        queued.append(QueuedFrame(m.node, inst.time_ns, frames[key]))
    for r in rig:
        period = drifted(r.cycle_ns, drift.get(r.node, 0))
        for t in range(0, until_ns, period):
            names[len(queued)] = r.name
            queued.append(QueuedFrame(r.node, t, r.frame))
    return SimulatedRun(simulate(queued, bitrate), names)


def nodes_of(restbus: Restbus, rig: Sequence[RigMessage] = ()) -> list[str]:
    return sorted({m.node for m in restbus.messages} | {r.node for r in rig})
