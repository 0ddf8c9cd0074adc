"""The XCP slave's protocol layer: a state machine over a :class:`MemoryLayout`.

Pure and deterministic: :meth:`Slave.handle` takes a command packet and
returns the response packet (or None: dropped), :meth:`Slave.on_snapshot`
takes one sample of the image and returns the DAQ packets (DTOs) it
triggers. The transports (:mod:`.udp`, :mod:`.tcp`) move bytes, the clock
is the rig's (each snapshot carries its timestamp).

What it serves (docs/xcp.md):

* standard: CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO,
  GET_ID (0: the module's name, 1: the A2L file's stem, 2: its path; read
  back by UPLOAD from the MTA GET_ID sets);
* memory: SET_MTA, UPLOAD, SHORT_UPLOAD, DOWNLOAD, SHORT_DOWNLOAD (address
  extension 0; byte granularity; INTEL byte order);
* dynamic DAQ: FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY,
  SET_DAQ_PTR, WRITE_DAQ, SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST,
  START_STOP_SYNCH, GET_DAQ_CLOCK, GET_DAQ_PROCESSOR_INFO,
  GET_DAQ_RESOLUTION_INFO, GET_DAQ_EVENT_INFO. Identification field:
  absolute ODT number; timestamps (4 bytes) selectable per list; prescaler
  supported; no STIM, no PID_OFF.

Anything else answers ERR_CMD_UNKNOWN; a command cut short ERR_CMD_SYNTAX;
before CONNECT every command but CONNECT is dropped (counted).
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Final

from service_kit.counters import Counters
from service_kit.xcp.memory import MemoryLayout, Variable, Write, WriteRefused
from service_kit.xcp.packets import Cmd, Err, error, ok
from service_kit.xcp.partial import PartialWrites

__all__ = ["DaqList", "EventChannel", "Slave", "SlaveCounters", "SlaveInfo", "Snapshot"]

log = logging.getLogger(__name__)

MAX_CTO: Final = 255
"""The largest command or response packet."""
MAX_DTO: Final = 1024
"""The largest DAQ packet."""
MAX_DAQ: Final = 16
"""DAQ lists a master may allocate."""
MAX_ODT_ENTRY_SIZE: Final = 255
"""Bytes one ODT entry may read."""
MAX_ODT_ENTRIES: Final = 1024
"""ODT entries a master may allocate over all lists (the slave's DAQ memory)."""
MAX_PID: Final = 0xFB
"""ODT numbers (PIDs of DTOs) run from 0 to this (0xFC..0xFF are the slave's response PIDs)."""
TIMESTAMP_BYTES: Final = 4
ID_ADDRESS: Final = 0xFF00_0000
"""Where GET_ID and GET_DAQ_EVENT_INFO leave their text for UPLOAD (outside the map)."""

MODE_TIMESTAMP: Final = 0x10
MODE_PID_OFF: Final = 0x20
MODE_STIM: Final = 0x02


@dataclass(frozen=True)
class EventChannel:
    """A DAQ event channel: its name, cycle and XCP time unit (6 = 1 ms, 3 = 1 µs; cycle 0 = sporadic)."""

    name: str
    cycle: int
    unit: int
    priority: int = 0


@dataclass(frozen=True)
class SlaveInfo:
    """What the slave says about itself."""

    identification: str
    """GET_ID 0 (ASCII text): the A2L MODULE's name."""
    a2l_path: str
    """GET_ID 2 (the A2L file with path); GET_ID 1 is its stem."""
    events: tuple[EventChannel, ...]
    timestamp_unit: int = 3
    """DAQ_TIMESTAMP_UNIT code of one timestamp tick (3 = 1 µs)."""
    max_cto: int = MAX_CTO
    """The largest command or response packet (8 on CAN)."""
    max_dto: int = MAX_DTO
    """The largest DAQ packet (8 on CAN: an ODT carries at most 7 data bytes after its PID)."""
    partial_writes: bool = False
    """Hold a parameter's first bytes until its last arrive (:mod:`.partial`; on CAN, where
    a DOWNLOAD carries at most 6 bytes). Off: a write over part of a parameter is refused."""

    @property
    def max_odt_entry_size(self) -> int:
        return min(MAX_ODT_ENTRY_SIZE, self.max_dto - 1)


@dataclass(frozen=True)
class Snapshot:
    """One sample of the image handed over by the loop."""

    events: int
    """Bit ``i`` set: event channel ``i`` occurred with this sample."""
    timestamp: int
    """The sample's time in timestamp ticks (:attr:`SlaveInfo.timestamp_unit`), mod 2^32."""
    image: bytes
    """The whole map (:meth:`MemoryLayout.pack`)."""


@dataclass
class SlaveCounters(Counters):
    commands: int = 0
    negative_responses: int = 0
    unknown_commands: int = 0
    malformed: int = 0
    """frames or packets that could not be read (a length of 0 or too long, cut short, empty)"""
    dropped_unconnected: int = 0
    """commands before CONNECT, dropped as the protocol says"""
    calibration_writes: int = 0
    writes_refused: int = 0
    dtos_sent: int = 0
    daq_overloads: int = 0
    """DAQ packets that could not be sent (XCP's overload condition)"""
    snapshots_dropped: int = 0
    """samples the loop could not hand over (the queue was full): their DAQ packets never existed"""
    internal_errors: int = 0
    masters_refused: int = 0
    """TCP connections refused while another master was connected"""
    sessions_lost: int = 0
    """sessions that ended without DISCONNECT (a TCP connection closed or broken mid-session)"""
    partial_writes_held: int = 0
    """writes whose last bytes were a parameter's first ones, held for the next write (CAN)"""
    partial_writes_dropped: int = 0
    """held first bytes dropped: the next write went elsewhere, or the session ended"""


@dataclass
class DaqList:
    """A dynamic DAQ list: its ODTs (each a list of ``[address, size]`` entries) and mode."""

    odts: list[list[list[int]]] = field(default_factory=list)
    mode: int = 0
    event: int = 0
    prescaler: int = 1
    priority: int = 0
    first_pid: int = 0
    selected: bool = False
    running: bool = False
    phase: int = 0
    """Events seen since the list started, for its prescaler."""


class _Syntax(Exception):
    """A command too short for its fields."""


def _unpack(fmt: str, body: bytes) -> tuple[int, ...]:
    s = struct.Struct("<" + fmt)
    if len(body) < s.size:
        raise _Syntax
    return s.unpack_from(body)


class Slave:
    """One master's session: connection, MTA, DAQ lists, over the shared map."""

    def __init__(
        self,
        layout: MemoryLayout,
        info: SlaveInfo,
        calibrate: Callable[[list[Write]], None],
        initial_image: bytes | None = None,
        counters: SlaveCounters | None = None,
    ) -> None:
        self.layout = layout
        self.info = info
        self._calibrate = calibrate
        """Takes an accepted write (its parameters and values); may raise :class:`WriteRefused`."""
        self.image = bytearray(initial_image if initial_image is not None else bytes(layout.size))
        self.counters = counters or SlaveCounters()
        self.connected = False
        self.mta = 0
        self._text = b""
        """The text GET_ID or GET_DAQ_EVENT_INFO left at :data:`ID_ADDRESS`."""
        self.daq: list[DaqList] = []
        self._ptr: tuple[int, int, int] | None = None
        self.clock = 0
        """The latest snapshot's timestamp (GET_DAQ_CLOCK)."""
        self._partial = PartialWrites(layout) if info.partial_writes else None
        self._handlers: dict[int, Callable[[bytes], bytes]] = {
            Cmd.CONNECT: self._connect,
            Cmd.DISCONNECT: self._disconnect,
            Cmd.GET_STATUS: self._get_status,
            Cmd.SYNCH: lambda body: error(Err.ERR_CMD_SYNCH),
            Cmd.GET_COMM_MODE_INFO: lambda body: ok(bytes((0, 0, 0, 0, 0, 0, 0x10))),
            Cmd.GET_ID: self._get_id,
            Cmd.SET_MTA: self._set_mta,
            Cmd.UPLOAD: self._upload,
            Cmd.SHORT_UPLOAD: self._short_upload,
            Cmd.DOWNLOAD: self._download,
            Cmd.SHORT_DOWNLOAD: self._short_download,
            Cmd.FREE_DAQ: self._free_daq,
            Cmd.ALLOC_DAQ: self._alloc_daq,
            Cmd.ALLOC_ODT: self._alloc_odt,
            Cmd.ALLOC_ODT_ENTRY: self._alloc_odt_entry,
            Cmd.SET_DAQ_PTR: self._set_daq_ptr,
            Cmd.WRITE_DAQ: self._write_daq,
            Cmd.SET_DAQ_LIST_MODE: self._set_daq_list_mode,
            Cmd.START_STOP_DAQ_LIST: self._start_stop_daq_list,
            Cmd.START_STOP_SYNCH: self._start_stop_synch,
            Cmd.GET_DAQ_CLOCK: lambda body: ok(b"\x00\x00\x00", struct.pack("<I", self.clock)),
            Cmd.GET_DAQ_PROCESSOR_INFO: self._processor_info,
            Cmd.GET_DAQ_RESOLUTION_INFO: self._resolution_info,
            Cmd.GET_DAQ_EVENT_INFO: self._event_info,
        }

    # -- commands ---------------------------------------------------------------------
    def handle(self, packet: bytes) -> bytes | None:
        """The response to one command packet (None: dropped, counted)."""
        if not packet:
            self.counters.malformed += 1
            return None
        pid, body = packet[0], packet[1:]
        if not self.connected and pid != Cmd.CONNECT:
            self.counters.dropped_unconnected += 1
            return None
        self.counters.commands += 1
        handler = self._handlers.get(pid)
        if handler is None:
            self.counters.unknown_commands += 1
            return self._refuse(Err.ERR_CMD_UNKNOWN)
        try:
            return self._count(handler(body))
        except _Syntax:
            self.counters.malformed += 1
            return self._refuse(Err.ERR_CMD_SYNTAX)
        except WriteRefused as exc:
            self.counters.writes_refused += 1
            log.info("XCP write refused: %s", exc)
            return self._refuse(exc.code)
        except Exception:  # a slave answers, whatever the master sent
            self.counters.internal_errors += 1
            log.warning("XCP command 0x%02X failed", pid, exc_info=True)
            return self._refuse(Err.ERR_GENERIC)

    def _refuse(self, code: Err) -> bytes:
        self.counters.negative_responses += 1
        return error(code)

    def _count(self, response: bytes) -> bytes:
        if response[0] == 0xFE:
            self.counters.negative_responses += 1
        return response

    def _connect(self, body: bytes) -> bytes:
        self.connected = True
        resource = 0x01 | 0x04  # CAL/PAG, DAQ
        comm_mode_basic = 0x80  # GET_COMM_MODE_INFO available; INTEL; byte granularity; no slave block mode
        return ok(bytes((resource, comm_mode_basic, self.info.max_cto)), struct.pack("<H", self.info.max_dto), b"\x01\x01")

    def _disconnect(self, body: bytes) -> bytes:
        self.reset()
        return ok()

    def reset(self) -> None:
        """The session's end (DISCONNECT, or its transport's connection lost): DAQ lists freed."""
        self.connected = False
        self.daq = []
        self._ptr = None
        if self._partial is not None:
            self._partial.drop()
            self.counters.partial_writes_dropped = self._partial.dropped

    def _get_status(self, body: bytes) -> bytes:
        running = any(d.running for d in self.daq)
        return ok(bytes((0x40 if running else 0x00, 0x00, 0x00)), struct.pack("<H", 0))

    def _get_id(self, body: bytes) -> bytes:
        (kind,) = _unpack("B", body)
        path = self.info.a2l_path
        texts = {0: self.info.identification, 1: os.path.splitext(os.path.basename(path))[0], 2: path}
        if kind not in texts:
            return error(Err.ERR_OUT_OF_RANGE)
        self._text = texts[kind].encode()
        self.mta = ID_ADDRESS
        return ok(b"\x00\x00\x00", struct.pack("<I", len(self._text)))

    # -- memory ---------------------------------------------------------------------------
    def _read(self, address: int, n: int) -> bytes:
        if ID_ADDRESS <= address and address + n <= ID_ADDRESS + len(self._text):
            return self._text[address - ID_ADDRESS : address - ID_ADDRESS + n]
        if not self.layout.readable(address, n):
            raise WriteRefused(Err.ERR_ACCESS_DENIED, f"read of {n} bytes at 0x{address:X} is outside the map")
        start = address - self.layout.base
        return bytes(self.image[start : start + n])

    def _write(self, address: int, data: bytes) -> None:
        partial = self._partial
        if partial is not None:
            try:
                split = partial.split(address, data)
            finally:
                self.counters.partial_writes_dropped = partial.dropped
            if split.held:
                self.counters.partial_writes_held += 1
            if not split.whole:
                return
            address, data = split.address, split.whole
        changes = self.layout.check_write(address, data)
        try:
            self._calibrate(changes)  # may refuse (WriteRefused)
        except WriteRefused:
            if partial is not None and partial.variable is not None:  # the whole part refused: its tail goes too
                partial.drop()
                self.counters.partial_writes_dropped = partial.dropped
            raise
        start = address - self.layout.base
        self.image[start : start + len(data)] = data
        self.counters.calibration_writes += 1

    def _set_mta(self, body: bytes) -> bytes:
        _, _, ext, address = _unpack("BBBI", body)
        if ext != 0:
            return error(Err.ERR_OUT_OF_RANGE)
        self.mta = address
        return ok()

    def _upload(self, body: bytes) -> bytes:
        (n,) = _unpack("B", body)
        if not 1 <= n <= self.info.max_cto - 1:
            return error(Err.ERR_OUT_OF_RANGE)
        data = self._read(self.mta, n)
        self.mta += n
        return ok(data)

    def _short_upload(self, body: bytes) -> bytes:
        n, _, ext, address = _unpack("BBBI", body)
        if not 1 <= n <= self.info.max_cto - 1 or ext != 0:
            return error(Err.ERR_OUT_OF_RANGE)
        data = self._read(address, n)
        self.mta = address + n
        return ok(data)

    def _download(self, body: bytes) -> bytes:
        (n,) = _unpack("B", body)
        data = body[1 : 1 + n]
        if n == 0 or len(data) < n:
            raise _Syntax
        self._write(self.mta, data)
        self.mta += n
        return ok()

    def _short_download(self, body: bytes) -> bytes:
        n, _, ext, address = _unpack("BBBI", body)
        data = body[7 : 7 + n]
        if n == 0 or len(data) < n:
            raise _Syntax
        if ext != 0:
            return error(Err.ERR_OUT_OF_RANGE)
        self._write(address, data)
        self.mta = address + n
        return ok()

    # -- DAQ configuration -----------------------------------------------------------------
    def _stopped(self) -> bool:
        return not any(d.running for d in self.daq)

    def _free_daq(self, body: bytes) -> bytes:
        self.daq = []
        self._ptr = None
        return ok()

    def _alloc_daq(self, body: bytes) -> bytes:
        _, count = _unpack("BH", body)
        if self.daq:
            return error(Err.ERR_SEQUENCE)
        if count > MAX_DAQ:
            return error(Err.ERR_MEMORY_OVERFLOW)
        self.daq = [DaqList() for _ in range(count)]
        return ok()

    def _alloc_odt(self, body: bytes) -> bytes:
        _, daq, count = _unpack("BHB", body)
        if not self.daq:  # ALLOC_ODT before ALLOC_DAQ
            return error(Err.ERR_SEQUENCE)
        if daq >= len(self.daq):
            return error(Err.ERR_OUT_OF_RANGE)
        if self.daq[daq].odts:
            return error(Err.ERR_SEQUENCE)
        used = sum(len(d.odts) for d in self.daq)
        if used + count > MAX_PID + 1:
            return error(Err.ERR_MEMORY_OVERFLOW)
        self.daq[daq].odts = [[] for _ in range(count)]
        pid = 0
        for d in self.daq:  # absolute ODT numbers, list after list
            d.first_pid = pid
            pid += len(d.odts)
        return ok()

    def _alloc_odt_entry(self, body: bytes) -> bytes:
        _, daq, odt, count = _unpack("BHBB", body)
        if not self.daq or (daq < len(self.daq) and not self.daq[daq].odts):  # before ALLOC_DAQ / ALLOC_ODT
            return error(Err.ERR_SEQUENCE)
        if daq >= len(self.daq) or odt >= len(self.daq[daq].odts):
            return error(Err.ERR_OUT_OF_RANGE)
        used = sum(len(o) for d in self.daq for o in d.odts) - len(self.daq[daq].odts[odt])
        if used + count > MAX_ODT_ENTRIES:
            return error(Err.ERR_MEMORY_OVERFLOW)
        self.daq[daq].odts[odt] = [[0, 0] for _ in range(count)]
        return ok()

    def _set_daq_ptr(self, body: bytes) -> bytes:
        _, daq, odt, entry = _unpack("BHBB", body)
        if daq >= len(self.daq) or odt >= len(self.daq[daq].odts) or entry >= len(self.daq[daq].odts[odt]):
            return error(Err.ERR_OUT_OF_RANGE)
        if self.daq[daq].running:
            return error(Err.ERR_DAQ_ACTIVE)
        self._ptr = (daq, odt, entry)
        return ok()

    def _write_daq(self, body: bytes) -> bytes:
        bit_offset, size, ext, address = _unpack("BBBI", body)
        if self._ptr is None:
            return error(Err.ERR_SEQUENCE)
        daq, odt, entry = self._ptr
        entries = self.daq[daq].odts[odt]
        if entry >= len(entries):
            return error(Err.ERR_OUT_OF_RANGE)
        if bit_offset != 0xFF or ext != 0 or not 1 <= size <= self.info.max_odt_entry_size:
            return error(Err.ERR_OUT_OF_RANGE)
        if not self.layout.readable(address, size):
            return error(Err.ERR_ACCESS_DENIED)
        entries[entry] = [address - self.layout.base, size]
        self._ptr = (daq, odt, entry + 1)
        return ok()

    def _set_daq_list_mode(self, body: bytes) -> bytes:
        mode, daq, event, prescaler, priority = _unpack("BHHBB", body)
        if daq >= len(self.daq) or event >= len(self.info.events) or prescaler == 0 or mode & (MODE_STIM | MODE_PID_OFF):
            return error(Err.ERR_OUT_OF_RANGE)
        d = self.daq[daq]
        if d.running:
            return error(Err.ERR_DAQ_ACTIVE)
        d.mode, d.event, d.prescaler, d.priority = mode, event, prescaler, priority
        return ok()

    def _fits(self, d: DaqList) -> bool:
        """Each ODT's DTO (PID, the timestamp in the first, the entries) fits in MAX_DTO."""
        max_dto = self.info.max_dto
        for j, odt in enumerate(d.odts):
            ts = TIMESTAMP_BYTES if j == 0 and d.mode & MODE_TIMESTAMP else 0
            if 1 + ts + sum(size for _, size in odt) > max_dto:
                return False
        return True

    def _start_stop_daq_list(self, body: bytes) -> bytes:
        mode, daq = _unpack("BH", body)
        if not self.daq and mode:  # no list allocated yet
            return error(Err.ERR_SEQUENCE)
        if daq >= len(self.daq) or mode > 2:
            return error(Err.ERR_OUT_OF_RANGE)
        d = self.daq[daq]
        if mode and not (d.odts and self._fits(d)):
            return error(Err.ERR_DAQ_CONFIG)
        if mode == 0:
            d.running = False
        elif mode == 1:
            d.running, d.phase = True, 0
        else:
            d.selected = True
        return ok(bytes((d.first_pid,)))

    def _start_stop_synch(self, body: bytes) -> bytes:
        (mode,) = _unpack("B", body)
        if mode > 2:
            return error(Err.ERR_OUT_OF_RANGE)
        for d in self.daq:
            if mode == 0:
                d.running = d.selected = False
            elif d.selected:
                d.running, d.selected = mode == 1, False
                d.phase = 0
        return ok()

    def _processor_info(self, body: bytes) -> bytes:
        properties = 0x01 | 0x02 | 0x10  # dynamic, prescaler, timestamps
        return ok(bytes((properties,)), struct.pack("<HHBB", MAX_DAQ, len(self.info.events), 0, 0x00))

    def _resolution_info(self, body: bytes) -> bytes:
        timestamp_mode = (self.info.timestamp_unit << 4) | 0x04  # size 4 bytes, not fixed
        return ok(bytes((1, self.info.max_odt_entry_size, 1, 0, timestamp_mode)), struct.pack("<H", 1))

    def _event_info(self, body: bytes) -> bytes:
        _, event = _unpack("BH", body)
        if event >= len(self.info.events):
            return error(Err.ERR_OUT_OF_RANGE)
        channel = self.info.events[event]
        self._text = channel.name.encode()
        self.mta = ID_ADDRESS
        return ok(bytes((0x04, 0xFF, len(self._text), channel.cycle, channel.unit, channel.priority)))

    # -- DAQ ----------------------------------------------------------------------------
    def on_snapshot(self, snapshot: Snapshot) -> list[bytes]:
        """Take one sample of the image; the DTOs of every running list whose event occurred."""
        self.image[:] = snapshot.image
        self.clock = snapshot.timestamp
        out: list[bytes] = []
        image = self.image
        for d in self.daq:
            if not d.running or not (snapshot.events >> d.event) & 1:
                continue
            d.phase += 1
            if (d.phase - 1) % d.prescaler:
                continue
            for j, odt in enumerate(d.odts):
                parts = [bytes((d.first_pid + j,))]
                if j == 0 and d.mode & MODE_TIMESTAMP:
                    parts.append(struct.pack("<I", snapshot.timestamp))
                parts.extend(bytes(image[start : start + size]) for start, size in odt if size)
                out.append(b"".join(parts))
        return out

    def values(self, variables: Sequence[Variable]) -> list[float]:
        """The physical values of ``variables`` in the current image (for logs and tests)."""
        base = self.layout.base
        return [v.to_physical(struct.unpack_from("<" + v.code, self.image, v.address - base)[0]) for v in variables]
