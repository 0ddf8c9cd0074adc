"""The plant's CAN face: a CANopen (CiA 301) slave with the CiA 401 analog
I/O profile, emulating the rig's A/D (AVME 9325) and D/A (AVME 947X) boards.

:class:`CanopenNode` is a pure state machine: frames and the current time go
in (:meth:`~CanopenNode.handle`, :meth:`~CanopenNode.poll`), frames to send
come out, and the plant is reached only through the
:class:`NodeApplication` callbacks. No sockets, threads or clocks inside, so
it is deterministic and tested frame by frame.
:func:`plant_emulator.canopen_node.runner.run_node` is the thin I/O loop
around it for a python-can bus.

Behaviour (node id ``n``, see :mod:`protocol.can_map` for the frames):

* **NMT**: boot-up (heartbeat 0x00) at construction and after RESET_NODE /
  RESET_COMMUNICATION, then PRE-OPERATIONAL; START -> OPERATIONAL, STOP ->
  STOPPED, ENTER_PRE_OPERATIONAL. Commands to node ``n`` or broadcast 0.
  PDOs only in OPERATIONAL; SDO and EMCY in PRE-OPERATIONAL and
  OPERATIONAL; in STOPPED only NMT and heartbeat (EMCYs due then are
  counted as suppressed; the error register is still kept). Leaving
  OPERATIONAL drives both valves to 0 V (``on_outputs(zeros)``: the CiA 401
  output error mode) and ends a watchdog trip. RESET_NODE restores every
  object to its configured value (calling the resolution/sample-period
  hooks if they change), RESET_COMMUNICATION only 0x1000-0x1FFF.
* **Heartbeat** producer, period 0x1017 (ms, 0 = off), first beat one
  period after boot-up; late beats are not bunched up.
* **SYNC** consumer: SYNC with counter (DLC 1, counter 1..0x1019) and SYNC
  without counter (DLC 0, e.g. ``canopen``'s ``network.sync.start``) are
  both accepted with the default 0x1019 = 240 (CiA 301 allows both);
  0x1019 = 0 accepts only SYNC without counter. ``on_sync`` gets counter 0
  for a SYNC without counter. Gaps are counted with
  :func:`protocol.can_map.sync_gap`. What one producer cannot send (a
  repeated counter, a jump back by half the range or more, SYNC with and
  without counter mixed within one OPERATIONAL session) is a second SYNC
  producer: counted in ``sync_conflicts`` and EMCY SYNC_CONFLICT, reset
  after :data:`CONFLICT_CLEAR_PERIODS` clean SYNCs. On each SYNC in
  OPERATIONAL: ``app.on_sync(counter)`` ->
  codes at the ADC resolution (0x2001) -> TPDO1 with 0x6401 (INT16,
  left-justified: ``code << (16 - bits)``; above 16 bits the 16 most
  significant bits, ``code >> (bits - 16)``). Above 16 bits TPDO2 and TPDO3
  carry 0x6402 (INT32, ``code << (32 - bits)``) **as well**, so a 12-bit
  consumer of TPDO1 keeps working unchanged while a wide consumer reads
  TPDO2/3; their COB-IDs (0x1801/0x1802 sub 1) are marked valid only then.
* **RPDO1** (0x6411 sub 1-2) is transmission type 255, asynchronous:
  applied on receipt rather than at the next SYNC, because the MVME wrote
  its D/A as soon as it had computed the command, so the plant sees the
  valve change at the instant the controller produced it (a synchronous
  RPDO would add a whole sample of dead time the real rig did not have).
  Words are converted with DAC12 (the 4 padding bits discarded) and clipped,
  in codes, to the valve voltage limit 0x2002 (default 10 V); entering the
  clipped condition sends EMCY OUTPUT_CLIPPED once, leaving it the reset
  EMCY. An SDO write of 0x6411 applies the outputs the same way (only in
  OPERATIONAL). Wrong-length RPDOs raise EMCY PDO_LENGTH (once per run of
  bad frames; cleared by the next good one). While RPDO1 is declared cyclic
  (its event timer 0x1400 sub 5 > 0, see the watchdog), more RPDO1 frames
  in one SYNC period than SYNCs in it (1 + the SYNCs the counter says were
  lost) is a second RPDO producer: ``rpdo_conflicts`` and EMCY
  RPDO_CONFLICT, reset after :data:`CONFLICT_CLEAR_PERIODS` clean periods;
  event-driven masters (event timer 0) may send as many as they like.
* **Watchdog**: armed by the first SYNC received in OPERATIONAL; when no SYNC
  arrives for 0x2003 periods of 0x2000 (default 5 x 5 ms) the node calls
  ``app.on_watchdog(True)`` (the app drives the valves to zero and holds),
  sends EMCY SYNC_TIMEOUT (0x8130, vendor byte 1 = 0) and holds further RPDOs
  (counted, not applied); the next SYNC calls ``app.on_watchdog(False)``,
  sends the reset EMCY and resumes (outputs stay at zero until the next
  RPDO). RPDO1 deadline monitoring (CiA 301: the RPDO event timer, 0x1400
  sub 5 in ms, 0 = off by default; the controller sets it to the watchdog
  time, and it is written only outside OPERATIONAL): no RPDO1 for that long
  after the first one trips the watchdog the same way even while SYNC keeps
  coming (EMCY RPDO_TIMEOUT 0x8250, vendor byte 1 = 1, counted in ``rpdo_timeouts``), so somebody
  else's SYNC stream cannot keep the valves open for a controller that
  froze; the next RPDO1 releases it (that frame
  is held, the following one applies). 0x2003 = 0 disables the watchdog in
  :class:`NodeConfig` only: an SDO write of 0 is refused (abort 0x08000022,
  counted in ``watchdog_disable_refused``); lockstep runs use a long time.
* **EMCY**: one frame when a fault appears (codes of
  :class:`protocol.can_map.EmcyCode`, the error register 0x1001 updated,
  the code also pushed onto 0x1003), and code 0x0000 when it clears, with
  the remaining error register and the cleared code in vendor bytes 0-1.
  The application may raise its own faults (e.g. JOINT_LIMIT) with
  :meth:`CanopenNode.set_fault`.
* **Malformed or misplaced frames** (wrong DLC, unknown COB-ID with our node
  id, RPDO before START, bad NMT command, SYNC counter out of range, RTR)
  are counted per kind in ``counters.malformed``, logged once per kind at
  WARNING, and ignored. An SDO request in STOPPED is well formed: it is
  not answered (CiA 301) and counted in ``counters.rx['sdo_stopped']``.
  Frames of other nodes are counted in ``counters.rx`` and ignored.
* **Frames on our own COB-IDs** (EMCY, TPDO1-3, SDO reply, heartbeat): on
  a bus that hands a sender its frames back (:meth:`CanopenNode.expect_echoes`,
  python-can's udp_multicast) the ones matching what we sent, in order,
  are echoes (``rx['own_cob_id']``); every other one is another node
  transmitting with our identifiers: counted per kind in
  ``counters.impersonated``, logged at most every :data:`LOG_INTERVAL_S`,
  and reported by EMCY CAN_ID_COLLISION (0x8150) carrying the frame's
  COB-ID, DLC and first two data bytes, at most every
  :data:`COLLISION_EMCY_INTERVAL_S`, reset after :data:`COLLISION_CLEAR_S`
  without one. So a master that receives a heartbeat STOPPED, an EMCY or a
  TPDO1 on our identifiers can tell it from ours.
* **SDO writes of communication objects** (0x1000-0x1FFF) that succeed are
  counted per index in ``counters.comm_writes`` and logged: the master
  compares them with the writes it made itself.

The node is not tied to a thread, but its public methods take an internal
re-entrant lock, so an application may call :meth:`CanopenNode.set_fault`
from another thread or from inside a callback.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, Final, Protocol

import can
import numpy as np
import numpy.typing as npt

from plant_emulator.canopen_node.config import NodeConfig
from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.frames import Frame
from plant_emulator.canopen_node.objects import PDO_NO_RTR, PDO_NOT_VALID, object_table
from plant_emulator.canopen_node.od import (
    ObjectDictionary,
    SdoAbort,
    SdoAbortCode,
    Value,
)
from plant_emulator.canopen_node.sdo_server import SdoServer
from protocol.can_map import (
    ADC_RESOLUTIONS,
    DAC12,
    DEFAULT_NODE_ID,
    FULL_SCALE_V,
    N_ANALOG_INPUTS,
    N_ANALOG_OUTPUTS,
    OD_ADC_RESOLUTION,
    OD_ANALOG_INPUT_16,
    OD_ANALOG_INPUT_32,
    OD_ANALOG_OUTPUT_16,
    OD_DIAGNOSTICS,
    OD_RPDO1_COMM,
    OD_RPDO_EVENT_TIMER_SUB,
    OD_SAMPLE_PERIOD,
    OD_VALVE_LIMIT,
    OD_WATCHDOG_PERIODS,
    SYNC_COUNTER_OVERFLOW,
    TPDO2_BASE,
    TPDO3_BASE,
    EmcyCode,
    NmtCommand,
    NmtState,
    cob_ids,
    encode_analog_inputs_16,
    encode_analog_inputs_32,
    encode_collision_evidence,
    encode_emcy,
    encode_heartbeat,
)

log = logging.getLogger(__name__)

CONFLICT_CLEAR_PERIODS: Final[int] = 10
"""Clean SYNC periods after which a SYNC or RPDO conflict EMCY is reset."""
COLLISION_EMCY_INTERVAL_S: Final[float] = 0.1
"""EMCY CAN_ID_COLLISION is sent for the first frame on our own COB-IDs that we did not send and then
at most once per this interval, each with that frame's evidence (further ones only counted)."""
COLLISION_CLEAR_S: Final[float] = 1.0
"""CAN_ID_COLLISION is reset (EMCY 0x0000) at the first SYNC this long after the last such frame."""
ECHO_MEMORY: Final[int] = 64
"""Frames sent and not yet seen again, per COB-ID, on a bus that hands them back (udp_multicast)."""
LOG_INTERVAL_S: Final[float] = 10.0
"""Impersonated frames and SDO writes of communication objects are logged at most once per this interval per kind."""
TIME_COB_ID: Final[int] = 0x100
LSS_FIRST_COB_ID: Final[int] = 0x780
"""0x780.. (LSS 0x7E4/0x7E5 and friends) never belong to a node id."""


class NodeApplication(Protocol):
    """What the node needs from the plant (implemented by the plant service)."""

    def on_sync(self, counter: int) -> tuple[Sequence[int] | npt.NDArray[np.int64], Sequence[bool] | npt.NDArray[np.bool_]]:
        """Advance the plant to this SYNC and sample it: (codes at the current
        ADC resolution, saturated flags), four each: int64 and bool arrays, or
        lists of ints and bools (the plant's own, taken as they are).
        ``counter`` is the SYNC counter (1..240), or 0 for SYNCs without counter."""
        ...

    def on_outputs(self, volts: npt.NDArray[np.float64]) -> None:
        """New valve voltages (2,), after D/A quantization and clipping."""
        ...

    def on_watchdog(self, tripped: bool) -> None:
        """SYNC lost (True: drive the valves to zero and hold) or back (False)."""
        ...


class ConfigurableApplication(NodeApplication, Protocol):
    """Optional hooks, looked up with ``getattr``: an application without
    ``on_adc_bits`` refuses resolution changes by SDO (abort 0x08000020);
    one without ``on_sample_period`` just has the value stored. Either may
    raise to refuse a value (abort 0x08000020, the old value stays)."""

    def on_adc_bits(self, bits: int) -> None:
        """Switch the A/D to ``bits`` (12, 16, 20): later ``on_sync`` codes use it."""
        ...

    def on_sample_period(self, period_s: float) -> None: ...


def error_register_bits(code: int) -> int:
    """CiA 301 error register (0x1001) bits for an active EMCY code, besides
    the generic bit 0: current (bit 1), voltage (2), temperature (3),
    communication (4), manufacturer specific (7)."""
    if code >> 8 == 0xFF:
        return 0x80
    return {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}.get(code >> 12, 0x00)


def node_can_filters(node_id: int = DEFAULT_NODE_ID) -> list[can.typechecking.CanFilter]:
    """python-can filters for a node's bus: NMT, SYNC and every COB-ID with the
    node's id (so misaddressed frames are still counted; udp_multicast echoes
    of our own frames pass and are counted as ``own_cob_id``)."""
    return [
        {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},
        {"can_id": 0x080, "can_mask": 0x7FF, "extended": False},
        {"can_id": node_id, "can_mask": 0x07F, "extended": False},
    ]


_ZERO_OUTPUTS: Final = np.zeros(N_ANALOG_OUTPUTS)
_ZERO_VOLTS: Final[tuple[float, float]] = (0.0, 0.0)
_IN16_KEYS: Final = tuple((OD_ANALOG_INPUT_16, sub) for sub in range(1, N_ANALOG_INPUTS + 1))
_IN32_KEYS: Final = tuple((OD_ANALOG_INPUT_32, sub) for sub in range(1, N_ANALOG_INPUTS + 1))
_OUT16_KEYS: Final = tuple((OD_ANALOG_OUTPUT_16, sub) for sub in range(1, N_ANALOG_OUTPUTS + 1))
"""The process-data entries written on every sample and RPDO."""
_INPUT_SATURATED: Final = int(EmcyCode.INPUT_SATURATED)
_OUTPUT_CLIPPED: Final = int(EmcyCode.OUTPUT_CLIPPED)
_PDO_LENGTH: Final = int(EmcyCode.PDO_LENGTH)
_SYNC_CONFLICT: Final = int(EmcyCode.SYNC_CONFLICT)
_OPERATIONAL: Final = NmtState.OPERATIONAL
_STOPPED: Final = NmtState.STOPPED
"""The states the SYNC, RPDO and timer paths test on every frame, as module names (no enum class lookup each time)."""
_RPDO_CONFLICT: Final = int(EmcyCode.RPDO_CONFLICT)
_DAC_LSB: Final = DAC12.lsb_v
_DAC_CODE_MIN: Final = DAC12.code_min
_DAC_CODE_MAX: Final = DAC12.code_max
_DAC_SHIFT: Final = DAC12.shift(16)
"""DAC12's constants, read once (its properties compute them on every access)."""
_RPDO1: Final = struct.Struct("<2h")
"""RPDO1 payload: two left-justified INT16 words (as protocol.can_map.decode_analog_outputs, length already checked)."""


def _dac_bounds(limit_v: float) -> tuple[int, int]:
    """The lowest and highest D/A code a valve voltage limit allows."""
    limit_code = int(math.floor(limit_v / _DAC_LSB + 1e-9))
    return max(-limit_code, _DAC_CODE_MIN), min(limit_code, _DAC_CODE_MAX)


class CanopenNode:
    """The CANopen slave state machine. See the module docstring."""

    def __init__(self, app: NodeApplication, cfg: NodeConfig | None = None) -> None:
        self.app = app
        self.cfg = cfg if cfg is not None else NodeConfig()
        self.node_id = self.cfg.node_id
        self.ids = cob_ids(self.node_id)
        self.counters = NodeCounters()
        self.od = ObjectDictionary.from_table(object_table(self.cfg), self.node_id)
        self.od.quiet = frozenset({OD_ANALOG_INPUT_16, OD_ANALOG_INPUT_32, OD_ANALOG_OUTPUT_16})
        self._conf_generation = -1
        self._quiet_until = -math.inf
        """No timer is due before this simulated time (see :meth:`poll_frames`)..."""
        self._quiet_generation = -1
        """...unless the object dictionary changed since (its ``generation``)."""
        self._conf: tuple[int, float, float, float, float, float, int, int, int] = (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0)
        self.sdo = SdoServer(self.od)
        self.counters.sdo = self.sdo.counters
        self.state = NmtState.BOOT_UP
        self._lock = threading.RLock()
        self._outbox: list[Frame] = []
        self._now = 0.0
        self._logged: set[str] = set()
        self._faults: dict[int, bytes] = {}
        self._error_history: list[int] = []
        self._tripped = False
        self._wd_last: float | None = None
        self._rpdo_last: float | None = None
        """last RPDO1 in OPERATIONAL: the watchdog's second input (armed by the first RPDO)"""
        self._trip_cause = "sync"
        self._trip_code = 0
        """the EMCY code of the current trip (SYNC_TIMEOUT or RPDO_TIMEOUT), 0 when none"""
        self._echo_memory: dict[int, deque[bytes]] | None = None
        """frames sent and not yet seen again, per COB-ID, while the bus echoes (expect_echoes)"""
        self._collision_last: float | None = None
        self._collision_emcy_at = -math.inf
        self._logged_at: dict[str, float] = {}
        self._rpdos_in_period = 0
        self._sync_conflict_clean = 0
        self._rpdo_conflict_clean = 0
        self._last_sync_counter: int | None = None
        self._hb_next: float | None = None
        self._outputs_v = _ZERO_VOLTS
        """valve voltages as last given to the application (floats)"""
        self._own_kind = {self.ids[k]: k for k in ("emcy", "tpdo1", "tpdo2", "tpdo3", "sdo_tx", "heartbeat")}
        self._own_ids = frozenset(self._own_kind)
        self._sync_id, self._rpdo1_id, self._nmt_id = self.ids["sync"], self.ids["rpdo1"], self.ids["nmt"]
        self._tpdo1_id, self._hb_id = self.ids["tpdo1"], self.ids["heartbeat"]
        # The process data (0x6401, 0x6402, 0x6411) lives in these lists, which the
        # object dictionary serves through getters: written on every sample and
        # RPDO, read only by SDO uploads (no dictionary write per tick).
        self._process_defaults = {key: self.od.get(*key) for key in _IN16_KEYS + _IN32_KEYS + _OUT16_KEYS}
        self._in16: list[int] = [int(self._process_defaults[k]) for k in _IN16_KEYS]
        self._in32: list[int] = [int(self._process_defaults[k]) for k in _IN32_KEYS]
        self._out16: list[int] = [int(self._process_defaults[k]) for k in _OUT16_KEYS]
        self._on_output_values: Callable[[float, float], None] | None = getattr(app, "on_output_values", None)
        """The application's optional float form of ``on_outputs`` (two plain floats, no array per RPDO)."""
        self._install_hooks()
        self._boot()

    # --- public API ------------------------------------------------------------------

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        """Process one received frame; returns the frames to transmit."""
        with self._lock:
            self._now = now
            self._quiet_until = -math.inf  # the frame may restart a timer: the next poll runs them
            try:
                self._dispatch(msg, now)
            except Exception:  # noqa: BLE001 - nothing on the bus may kill the node
                self.counters.internal_errors += 1
                log.exception("node %d: internal error handling %s", self.node_id, msg)
            self._start_timers(now)
            return self._drain()

    def poll(self, now: float) -> list[can.Message]:
        """Run the timers (heartbeat producer, SYNC watchdog); returns frames to transmit.
        Call it at least every few milliseconds, or at :meth:`next_deadline`."""
        return [f.to_message() for f in self.poll_frames(now)]

    def poll_frames(self, now: float) -> list[Frame]:
        """:meth:`poll`, the frames as the node made them (see :class:`Frame`)."""
        with self._lock:
            self._now = now
            if self.quick_poll and now < self._quiet_until and not self._outbox and self.od.generation == self._quiet_generation:
                return []  # no timer due before _quiet_until (worked out by the last _timers)
            self._timers(now)
            out, self._outbox = self._outbox, []
            return out

    quick_poll = True
    """Let :meth:`poll_frames` return at once before the earliest time a timer
    can be due (False: run the timers on every poll; tests compare the two)."""

    def exchange(self, cob_id: int, data: bytes | bytearray, now: float) -> list[Frame]:
        """:meth:`handle` of a standard data frame followed by :meth:`poll` at the
        same ``now``, in one call and without python-can objects (the
        co-simulation's direct wire): the same state changes, the same frames
        in the same order."""
        with self._lock:
            self._now = now
            data = bytes(data)
            try:
                if cob_id == self._sync_id:  # the two frames of every tick first (_dispatch_data's order otherwise)
                    self._on_sync(cob_id, data, now)
                elif cob_id == self._rpdo1_id:
                    self._on_rpdo(cob_id, data, now)
                else:
                    self._dispatch_data(cob_id, data, now)
            except Exception:  # noqa: BLE001 - nothing on the bus may kill the node
                self.counters.internal_errors += 1
                log.exception("node %d: internal error handling frame 0x%03X [%s]", self.node_id, cob_id, data.hex(" "))
            self._timers(now)
            out, self._outbox = self._outbox, []
            return out

    @property
    def own_cob_ids(self) -> frozenset[int]:
        """The COB-IDs this node transmits on (EMCY, TPDO1-3, SDO reply, heartbeat):
        a standard data frame with one of them received is our own frame back."""
        return self._own_ids

    def expect_echoes(self, on: bool) -> None:
        """Whether the bus hands the node its own frames back (python-can's
        udp_multicast does): then frames on :attr:`own_cob_ids` matching the
        ones sent, in order, are echoes; without echoes (virtual, SocketCAN,
        the rig's loop-free udp_multicast) every such frame is another node's."""
        with self._lock:
            self._echo_memory = {cob_id: deque(maxlen=ECHO_MEMORY) for cob_id in self._own_ids} if on else None
            if self._echo_memory is not None:
                for f in self._outbox:  # made before the bus was known (the boot-up), not sent yet
                    if f.arbitration_id in self._echo_memory:
                        self._echo_memory[f.arbitration_id].append(f.data)

    def own_cob_frame(self, cob_id: int, data: bytes | bytearray, now: float) -> list[Frame]:
        """What :meth:`handle` does with a standard data frame of :attr:`own_cob_ids`
        (an echo of ours, or another node's frame on our identifiers), without
        :meth:`poll`'s timers, for a runner that recognised the COB-ID; returns
        the frames to send (an EMCY CAN_ID_COLLISION)."""
        with self._lock:
            self._now = now
            self._own_cob(cob_id, bytes(data), now)
            out, self._outbox = self._outbox, []
            return out

    def count_own_echo(self) -> None:
        """Counts one echo of our own frames in ``rx['own_cob_id']``, nothing else."""
        with self._lock:
            self.counters.rx["own_cob_id"] += 1

    def next_deadline(self) -> float | None:
        """The earliest time :meth:`poll` has something to do (None: nothing scheduled)."""
        with self._lock:
            if self.quick_poll and not self._outbox and self._quiet_until != -math.inf and self.od.generation == self._quiet_generation:
                # what the last _timers worked out: the heartbeat and watchdog deadlines (nothing changed since)
                quiet = self._quiet_until
                return None if quiet == math.inf else quiet
            times = [t for t in (self._hb_next, self._watchdog_deadline()) if t is not None]
            if self._outbox:
                times.append(self._now)
            return min(times) if times else None

    def set_fault(self, code: EmcyCode | int, active: bool, vendor: bytes = b"") -> None:
        """Raise or clear an application fault (e.g. ``EmcyCode.JOINT_LIMIT``):
        EMCY on entry and the reset EMCY on exit; the frames go out with the
        next :meth:`handle`/:meth:`poll` result."""
        if not 0 <= int(code) <= 0xFFFF or int(code) == 0:
            raise ValueError(f"EMCY code must be 0x0001..0xFFFF, got {code}")
        with self._lock:
            self._set_fault(int(code), active, vendor[:5])

    @property
    def watchdog_tripped(self) -> bool:
        return self._tripped

    @property
    def outputs_v(self) -> npt.NDArray[np.float64]:
        """Valve voltages as last given to the application."""
        return np.array(self._outputs_v, dtype=np.float64)

    def _config(self) -> tuple[int, float, float, float, float, float, int, int, int]:
        """The configuration read every tick (A/D bits, valve limit, sample period,
        heartbeat period, RPDO1 timer, watchdog timeout, SYNC overflow, and the
        D/A codes the valve limit allows, lowest and highest), read from the
        object dictionary again whenever it changed (its ``generation``)."""
        od = self.od
        if od.generation != self._conf_generation:
            period = int(od.get(OD_SAMPLE_PERIOD)) * 1e-6
            limit = float(od.get(OD_VALVE_LIMIT))
            code_lo, code_hi = _dac_bounds(limit)
            self._conf = (
                int(od.get(OD_ADC_RESOLUTION)),
                limit,
                period,
                int(od.get(0x1017)) * 1e-3,
                int(od.get(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB)) * 1e-3,
                int(od.get(OD_WATCHDOG_PERIODS)) * period,
                int(od.get(0x1019)),
                code_lo,
                code_hi,
            )
            self._conf_generation = od.generation
        return self._conf

    @property
    def adc_bits(self) -> int:
        return self._config()[0]

    @property
    def valve_limit_v(self) -> float:
        return self._config()[1]

    @property
    def sample_period_s(self) -> float:
        return self._config()[2]

    @property
    def heartbeat_period_s(self) -> float:
        return self._config()[3]

    @property
    def rpdo_timeout_s(self) -> float:
        """0x1400 sub 5, the RPDO1 event timer: deadline monitoring of RPDO1 (0 = off)."""
        return self._config()[4]

    @property
    def watchdog_timeout_s(self) -> float:
        """0 when the watchdog is disabled."""
        return self._config()[5]

    @property
    def error_register(self) -> int:
        reg = 0
        for code in self._faults:
            reg |= 0x01 | error_register_bits(code)
        return reg

    @property
    def active_faults(self) -> tuple[int, ...]:
        return tuple(self._faults)

    # --- object dictionary hooks -------------------------------------------------------

    def _install_hooks(self) -> None:
        od = self.od
        for i in range(N_ANALOG_INPUTS):
            od.getter(OD_ANALOG_INPUT_16, i + 1, self._process_value("_in16", i))
            od.getter(OD_ANALOG_INPUT_32, i + 1, self._process_value("_in32", i))
        for i in range(N_ANALOG_OUTPUTS):
            od.getter(OD_ANALOG_OUTPUT_16, i + 1, self._process_value("_out16", i))
        od.getter(0x1001, 0, lambda: self.error_register)
        diag: Sequence[Callable[[], Value]] = (
            lambda: self.counters.sync_received,
            lambda: self.counters.syncs_missed,
            lambda: self.counters.watchdog_trips,
            lambda: self.counters.clipped_outputs,
            lambda: self.counters.malformed_total,
            lambda: sum(self.counters.sdo.aborts.values()),
            lambda: self.counters.impersonated_total,
        )
        for sub, fn in enumerate(diag, start=1):
            od.getter(OD_DIAGNOSTICS, sub, fn)
        od.on_write(0x1003, 0, self._write_error_history)
        od.on_write(0x1017, 0, self._write_heartbeat)
        od.on_write(0x1019, 0, self._write_sync_overflow)
        od.on_write(OD_SAMPLE_PERIOD, 0, self._write_sample_period)
        od.on_write(OD_ADC_RESOLUTION, 0, self._write_adc_resolution)
        od.on_write(OD_VALVE_LIMIT, 0, self._write_valve_limit)
        od.on_write(OD_WATCHDOG_PERIODS, 0, self._write_watchdog_periods)
        od.on_write(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, self._write_rpdo_timer)
        for sub in range(1, N_ANALOG_OUTPUTS + 1):
            od.on_write(OD_ANALOG_OUTPUT_16, sub, self._output_writer(sub))

    def _process_value(self, words: str, i: int) -> Callable[[], Value]:
        """The getter of one process-data entry: word ``i`` of the node's list ``words``."""

        def get() -> Value:
            value: int = getattr(self, words)[i]
            return value

        return get

    def _write_error_history(self, value: Value) -> None:
        if value != 0:
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, "only 0 may be written (clears the history)")
        self._error_history.clear()
        for sub in range(1, 9):
            self.od.set(0x1003, sub, 0)

    def _write_heartbeat(self, value: Value) -> None:
        self._hb_next = None  # restart with the new period (one period from now)

    def _write_sync_overflow(self, value: Value) -> None:
        if value not in (0, SYNC_COUNTER_OVERFLOW):
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, f"0x1019 must be 0 or {SYNC_COUNTER_OVERFLOW}")
        self._last_sync_counter = None

    def _write_sample_period(self, value: Value) -> None:
        hook = getattr(self.app, "on_sample_period", None)
        if hook is not None:
            try:
                hook(int(value) * 1e-6)
            except Exception as e:  # noqa: BLE001 - the app refuses: abort, keep the old value
                raise SdoAbort(SdoAbortCode.CANNOT_STORE, f"application refused the sample period: {e}") from e

    def _write_adc_resolution(self, value: Value) -> None:
        if value not in ADC_RESOLUTIONS:
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, f"ADC resolution must be one of {ADC_RESOLUTIONS}")
        bits = int(value)
        if bits == self.adc_bits:
            return
        hook = getattr(self.app, "on_adc_bits", None)
        if hook is None:
            raise SdoAbort(SdoAbortCode.CANNOT_STORE, "the application cannot change the ADC resolution")
        try:
            hook(bits)
        except Exception as e:  # noqa: BLE001
            raise SdoAbort(SdoAbortCode.CANNOT_STORE, f"application refused {bits} bits: {e}") from e
        self._update_tpdo_valid(bits)
        log.info("node %d: ADC resolution %d bits", self.node_id, bits)

    def _write_watchdog_periods(self, value: Value) -> None:
        if int(value) == 0:
            self.counters.watchdog_disable_refused += 1
            log.warning("node %d: SDO write 0x2003 = 0 (watchdog off) refused; only the node's configuration disables it", self.node_id)
            raise SdoAbort(SdoAbortCode.CANNOT_STORE_DEVICE_STATE, "the SYNC watchdog cannot be disabled over the bus (use a longer time)")

    def _write_rpdo_timer(self, value: Value) -> None:
        if self.state is NmtState.OPERATIONAL:
            raise SdoAbort(SdoAbortCode.CANNOT_STORE_DEVICE_STATE, "the RPDO1 event timer is set in PRE-OPERATIONAL (before NMT START)")

    def _write_valve_limit(self, value: Value) -> None:
        v = float(value)
        if v <= 0:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_LOW, "the valve voltage limit must be positive")
        if v > FULL_SCALE_V:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH, f"the D/A spans ±{FULL_SCALE_V} V")
        if self.state is NmtState.OPERATIONAL and not self._tripped:
            words = self._output_words()
            wanted = DAC12.to_volts(DAC12.from_left_justified(words))
            if np.any(np.abs(wanted) > v) or int(EmcyCode.OUTPUT_CLIPPED) in self._faults:
                self._apply_outputs(words, limit_v=v)  # re-clip (or release) what the valves get now

    def _output_writer(self, sub: int) -> Callable[[Value], None]:
        def write(value: Value) -> None:
            if self.state is not NmtState.OPERATIONAL or self._tripped:
                raise SdoAbort(
                    SdoAbortCode.CANNOT_STORE_DEVICE_STATE,
                    "outputs are written only in OPERATIONAL with SYNC present",
                )
            words = self._output_words()
            words[sub - 1] = int(value)
            self._apply_outputs(words)

        return write

    def _update_tpdo_valid(self, bits: int) -> None:
        valid = bits > 16
        for index, base in ((0x1801, TPDO2_BASE), (0x1802, TPDO3_BASE)):
            self.od.set(index, 1, PDO_NO_RTR | (0 if valid else PDO_NOT_VALID) | (base + self.node_id))

    # --- dispatch ---------------------------------------------------------------------------

    def _dispatch(self, msg: can.Message, now: float) -> None:
        if msg.is_error_frame:
            self.counters.rx["error_frame"] += 1
            return
        if msg.is_extended_id:
            self.counters.rx["extended"] += 1
            return
        cob_id = msg.arbitration_id
        if msg.is_remote_frame:
            ours = cob_id < LSS_FIRST_COB_ID and (cob_id & 0x7F) == self.node_id
            if ours or cob_id in (self.ids["nmt"], self.ids["sync"]):
                self._malformed("rtr", cob_id, bytes(msg.data), "remote frames (node guarding, PDO requests) are not supported")
            else:
                self.counters.rx["foreign"] += 1
            return
        self._dispatch_data(cob_id, bytes(msg.data), now)

    def _dispatch_data(self, cob_id: int, data: bytes, now: float) -> None:
        """A standard data frame, by COB-ID."""
        if cob_id == self._sync_id:
            self._on_sync(cob_id, data, now)
            return
        ours = cob_id < LSS_FIRST_COB_ID and (cob_id & 0x7F) == self.node_id
        if cob_id == self._rpdo1_id:
            self._on_rpdo(cob_id, data, now)
        elif cob_id == self._nmt_id:
            self._on_nmt(cob_id, data)
        elif cob_id == TIME_COB_ID:
            self.counters.rx["time"] += 1
        elif not ours:
            self.counters.rx["foreign"] += 1
        elif cob_id == self.ids["sdo_rx"]:
            self._on_sdo(cob_id, data)
        elif cob_id in self._own_ids:
            self._own_cob(cob_id, data, now)
        else:
            self._malformed("unknown_cob_id", cob_id, data, "no such object on this node")

    def _own_cob(self, cob_id: int, data: bytes, now: float) -> None:
        """A frame on one of our own COB-IDs: our echo, or another node impersonating us."""
        memory = self._echo_memory
        if memory is not None:
            sent = memory[cob_id]
            for i, d in enumerate(sent):
                if d == data:  # echoes come back in send order: the ones before were lost
                    for _ in range(i + 1):
                        sent.popleft()
                    self.counters.rx["own_cob_id"] += 1
                    return
        kind = self._own_kind[cob_id]
        self.counters.impersonated[kind] += 1
        self._collision_last = now
        self._log_limited(
            f"impersonated:{kind}",
            now,
            "node %d: a %s frame id 0x%03X [%s] this node did not send: another node uses its COB-IDs (%d such frames so far)",
            self.node_id,
            kind,
            cob_id,
            data.hex(" "),
            sum(dict.copy(self.counters.impersonated).values()),
        )
        if now - self._collision_emcy_at >= COLLISION_EMCY_INTERVAL_S:
            self._collision_emcy_at = now
            vendor = encode_collision_evidence(cob_id, data)
            code = int(EmcyCode.CAN_ID_COLLISION)
            self._faults[code] = vendor
            self._record_error(code, vendor)
            self._emcy(code, vendor)  # each with its frame's evidence (rate-bounded), not once per episode

    def _check_collision_clear(self, now: float) -> None:
        last = self._collision_last
        if last is not None and now - last >= COLLISION_CLEAR_S:
            self._collision_last = None
            self._set_fault(EmcyCode.CAN_ID_COLLISION, False)

    def _log_limited(self, key: str, now: float, fmt: str, *args: object, level: int = logging.WARNING) -> None:
        last = self._logged_at.get(key)
        if last is None or now - last >= LOG_INTERVAL_S:
            self._logged_at[key] = now
            log.log(level, fmt, *args)

    def _on_nmt(self, cob_id: int, data: bytes) -> None:
        self.counters.rx["nmt"] += 1
        if len(data) != 2:
            self._malformed("nmt_dlc", cob_id, data, f"NMT takes 2 bytes, got {len(data)}")
            return
        try:
            command = NmtCommand(data[0])
        except ValueError:
            self._malformed("nmt_command", cob_id, data, f"unknown NMT command 0x{data[0]:02X}")
            return
        target = data[1]
        if target > 127:
            self._malformed("nmt_node_id", cob_id, data, f"NMT node id {target} outside 0..127")
            return
        if target not in (0, self.node_id):
            self.counters.rx["nmt_other_node"] += 1
            return
        if command is NmtCommand.START:
            self._enter(NmtState.OPERATIONAL)
        elif command is NmtCommand.STOP:
            self._enter(NmtState.STOPPED)
        elif command is NmtCommand.ENTER_PRE_OPERATIONAL:
            self._enter(NmtState.PRE_OPERATIONAL)
        elif command is NmtCommand.RESET_NODE:
            self._reset(application=True)
        elif command is NmtCommand.RESET_COMMUNICATION:
            self._reset(application=False)

    def _on_sync(self, cob_id: int, data: bytes, now: float) -> None:
        self.counters.rx["sync"] += 1
        if self.state is _STOPPED:
            self.counters.rx["sync_stopped"] += 1
            return
        conf = self._config()
        overflow = conf[6]
        missed = 0
        conflict = ""
        if not data:
            counter = 0  # SYNC without counter: accepted whatever 0x1019 says (CiA 301 allows both)
            if self._last_sync_counter:
                conflict = "a SYNC without counter among SYNCs with counter"
        else:
            if overflow == 0:
                self._malformed("sync_dlc", cob_id, data, "0x1019 = 0: SYNC without counter expected (DLC 0)")
                return
            if len(data) != 1:
                self._malformed("sync_dlc", cob_id, data, f"SYNC with counter takes 1 byte, got {len(data)}")
                return
            counter = data[0]
            if not 1 <= counter <= overflow:
                self._malformed("sync_counter", cob_id, data, f"SYNC counter {counter} outside 1..{overflow}")
                return
            prev = self._last_sync_counter
            if prev == 0:
                conflict = "a SYNC with counter among SYNCs without counter"
            elif prev is not None:
                if counter == prev:
                    self.counters.sync_repeats += 1
                    conflict = f"SYNC counter {counter} repeated"
                else:
                    gap = (counter - prev - 1) % SYNC_COUNTER_OVERFLOW  # sync_gap(prev, counter), counter != prev: inline
                    if gap >= overflow // 2:
                        conflict = f"SYNC counter went back from {prev} to {counter}"
                    elif gap:
                        missed = gap
                        self.counters.sync_gaps += 1
                        self.counters.syncs_missed += gap
                        log.debug("node %d: SYNC gap %d -> %d (%d missed)", self.node_id, prev, counter, gap)
            self._last_sync_counter = counter
        if not data:
            self._last_sync_counter = 0
        self.counters.sync_received += 1
        if conflict or _SYNC_CONFLICT in self._faults:
            self._check_sync_conflict(conflict)
        if self._collision_last is not None:
            self._check_collision_clear(now)
        if self.state is not _OPERATIONAL:
            return
        if conf[4] > 0:
            self._check_rpdo_conflict(missed)
        else:
            self._rpdos_in_period = 0  # RPDO1 not declared cyclic: nothing to check (as _check_rpdo_conflict)
        if self._tripped and self._trip_cause == "sync":
            self._recover(now)
        self._wd_last = now
        self._sample(counter)

    def _check_sync_conflict(self, conflict: str) -> None:
        """A second SYNC producer shows in the counters (repeats, jumps back,
        mixed forms): EMCY SYNC_CONFLICT until CONFLICT_CLEAR_PERIODS clean SYNCs."""
        if conflict:
            self.counters.sync_conflicts += 1
            self._sync_conflict_clean = 0
            if int(EmcyCode.SYNC_CONFLICT) not in self._faults:
                log.warning("node %d: %s: a second SYNC producer on the bus?", self.node_id, conflict)
            self._set_fault(EmcyCode.SYNC_CONFLICT, True, bytes([self._last_sync_counter or 0]))
        elif _SYNC_CONFLICT in self._faults:
            self._sync_conflict_clean += 1
            if self._sync_conflict_clean >= CONFLICT_CLEAR_PERIODS:
                self._set_fault(EmcyCode.SYNC_CONFLICT, False)

    def _check_rpdo_conflict(self, missed: int) -> None:
        """At each SYNC, while RPDO1 is declared cyclic (0x1400 sub 5 > 0): more
        RPDO1s in the period just ended than SYNCs in it (1 + the SYNCs the
        counter says were lost) means a second producer: EMCY RPDO_CONFLICT
        until CONFLICT_CLEAR_PERIODS clean periods."""
        n, self._rpdos_in_period = self._rpdos_in_period, 0
        if self._config()[4] <= 0:
            return  # RPDO1 not declared cyclic: event-driven masters may send several per period
        if n > 1 + missed:
            self.counters.rpdo_conflicts += 1
            self._rpdo_conflict_clean = 0
            if int(EmcyCode.RPDO_CONFLICT) not in self._faults:
                log.warning("node %d: %d RPDO1 in one SYNC period: a second RPDO producer on the bus?", self.node_id, n)
            self._set_fault(EmcyCode.RPDO_CONFLICT, True, bytes([min(n, 255)]))
        elif _RPDO_CONFLICT in self._faults:
            self._rpdo_conflict_clean += 1
            if self._rpdo_conflict_clean >= CONFLICT_CLEAR_PERIODS:
                self._set_fault(EmcyCode.RPDO_CONFLICT, False)

    def _on_rpdo(self, cob_id: int, data: bytes, now: float) -> None:
        self.counters.rx["rpdo"] += 1
        if self.state is not _OPERATIONAL:
            self._malformed("rpdo_not_operational", cob_id, data, f"RPDO in {self.state.name}, PDOs need NMT START")
            return
        if len(data) != 4:
            self._malformed("rpdo_dlc", cob_id, data, f"RPDO1 takes 4 bytes, got {len(data)}")
            self._set_fault(EmcyCode.PDO_LENGTH, True, bytes([len(data) & 0xFF]))
            return
        if _PDO_LENGTH in self._faults:
            self._set_fault(_PDO_LENGTH, False)
        if self._tripped:
            self.counters.outputs_held += 1
            if self._trip_cause == "rpdo":
                self._recover(now)  # the controller is back; this frame is held, the next one applies
            return
        self._rpdo_last = now
        self._rpdos_in_period += 1  # held frames (tripped) are not counted
        w0, w1 = _RPDO1.unpack(data)
        self._apply_words(w0, w1, self._config())

    def _on_sdo(self, cob_id: int, data: bytes) -> None:
        self.counters.rx["sdo"] += 1
        if self.state is NmtState.STOPPED:
            self.counters.rx["sdo_stopped"] += 1  # well formed; CiA 301 serves no SDO in STOPPED: no answer
            return
        if len(data) != 8:
            self._malformed("sdo_dlc", cob_id, data, f"SDO requests take 8 bytes, got {len(data)}")
            return
        response = self.sdo.handle(data)
        if response is not None:
            self._emit(self.ids["sdo_tx"], response, "sdo")
            index = data[1] | data[2] << 8
            if response[0] == 0x60 and data[0] >> 5 == 1 and 0x1000 <= index <= 0x1FFF:
                self.counters.comm_writes[f"0x{index:04X}"] += 1
                self._log_limited(
                    f"comm_write:{index:04X}",
                    self._now,
                    "node %d: SDO write of communication object 0x%04X sub %d [%s]",
                    self.node_id,
                    index,
                    data[3],
                    data[4:].hex(" "),
                    level=logging.INFO,  # the master configures them at every start; it compares the counts
                )

    # --- NMT ------------------------------------------------------------------------------

    def _boot(self) -> None:
        self.state = NmtState.BOOT_UP
        self.sdo.reset()
        self._emit(self.ids["heartbeat"], encode_heartbeat(NmtState.BOOT_UP), "bootup")
        self.state = NmtState.PRE_OPERATIONAL
        self._hb_next = None
        self._last_sync_counter = None
        self._wd_last = None
        self._rpdo_last = None
        self._rpdos_in_period = 0
        log.info("node %d: boot-up, PRE-OPERATIONAL", self.node_id)

    def _enter(self, new: NmtState) -> None:
        old = self.state
        if new is old:
            return
        self.state = new
        log.info("node %d: NMT %s -> %s", self.node_id, old.name, new.name)
        if old is NmtState.OPERATIONAL:
            self._leave_operational()
        if new is NmtState.OPERATIONAL:
            self._wd_last = None  # armed by the first SYNC
            self._rpdo_last = None  # and by the first RPDO
            self._last_sync_counter = None  # a new master may count differently
            self._rpdos_in_period = 0

    def _leave_operational(self) -> None:
        self._wd_last = None
        self._rpdo_last = None
        if self._tripped:
            self._tripped = False
            self._call_app("on_watchdog", self.app.on_watchdog, False)
            self._clear_trip_fault()
        self._zero_outputs()
        self._call_app("on_outputs", self.app.on_outputs, _ZERO_OUTPUTS.copy())
        self._set_fault(EmcyCode.OUTPUT_CLIPPED, False)

    def _reset(self, application: bool) -> None:
        old_bits, old_period = self.adc_bits, int(self.od.get(OD_SAMPLE_PERIOD))
        was_operational = self.state is NmtState.OPERATIONAL
        self.state = NmtState.BOOT_UP  # no EMCY from the tear-down: the boot-up says it all
        if was_operational or self._tripped or any(self._outputs_v):
            if self._tripped:
                self._tripped = False
                self._call_app("on_watchdog", self.app.on_watchdog, False)
            self._zero_outputs()
            self._call_app("on_outputs", self.app.on_outputs, _ZERO_OUTPUTS.copy())
        self._faults.clear()
        self._trip_code = 0
        self._collision_last = None
        self._error_history.clear()
        self.od.restore_defaults(None if application else range(0x1000, 0x2000))
        if application:  # the process data too (served from the node's lists)
            d = self._process_defaults
            self._in16 = [int(d[k]) for k in _IN16_KEYS]
            self._in32 = [int(d[k]) for k in _IN32_KEYS]
            self._out16 = [int(d[k]) for k in _OUT16_KEYS]
        if application:
            bits, period = self.adc_bits, int(self.od.get(OD_SAMPLE_PERIOD))
            if bits != old_bits:
                hook = getattr(self.app, "on_adc_bits", None)
                if hook is not None:
                    self._call_app("on_adc_bits", hook, bits)
            if period != old_period:
                hook = getattr(self.app, "on_sample_period", None)
                if hook is not None:
                    self._call_app("on_sample_period", hook, period * 1e-6)
        self._update_tpdo_valid(self.adc_bits)
        log.info("node %d: NMT reset %s", self.node_id, "node" if application else "communication")
        self._boot()

    # --- process data -----------------------------------------------------------------

    def _sample(self, counter: int) -> None:
        try:
            result = self.app.on_sync(counter)
        except Exception:  # noqa: BLE001 - as _call_app: the app's bug must not take the bus down
            self._app_failed("on_sync")
            return
        if result is None:
            return
        codes: list[int]
        saturated: list[bool]
        try:
            raw_codes, raw_sat = result
            if (
                type(raw_codes) is list
                and type(raw_sat) is list
                and len(raw_codes) == N_ANALOG_INPUTS
                and len(raw_sat) == N_ANALOG_INPUTS
                and type(raw_codes[0]) is int
                and type(raw_codes[1]) is int
                and type(raw_codes[2]) is int
                and type(raw_codes[3]) is int
                and type(raw_sat[0]) is bool
                and type(raw_sat[1]) is bool
                and type(raw_sat[2]) is bool
                and type(raw_sat[3]) is bool
            ):
                codes = raw_codes  # the plant's own A/D output: four plain ints and bools already
                saturated = raw_sat
            elif (
                type(raw_codes) is np.ndarray
                and raw_codes.dtype == np.int64
                and raw_codes.shape == (N_ANALOG_INPUTS,)
                and type(raw_sat) is np.ndarray
                and raw_sat.dtype == np.bool_
                and raw_sat.shape == (N_ANALOG_INPUTS,)
            ):
                # The application's own types (the plant's A/D): plain ints and bools from here on.
                codes = raw_codes.tolist()
                saturated = raw_sat.tolist()
            else:
                arr = np.asarray(raw_codes)
                sat_arr = np.asarray(raw_sat, dtype=bool).reshape(N_ANALOG_INPUTS)
                if arr.shape != (N_ANALOG_INPUTS,):
                    raise ValueError(f"codes must have shape (4,), got {arr.shape}")
                if not np.issubdtype(arr.dtype, np.integer):
                    if not np.all(np.isfinite(arr.astype(np.float64))):
                        raise ValueError("codes must be finite")
                    arr = np.rint(arr.astype(np.float64))
                codes = arr.astype(np.int64).tolist()
                saturated = sat_arr.tolist()
        except Exception as e:  # noqa: BLE001 - a bad sample costs one TPDO, not the node
            self.counters.app_errors += 1
            self._log_once("app:on_sync_result", "node %d: on_sync returned unusable data: %s", self.node_id, e)
            return
        bits = self._config()[0]
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        c0, c1, c2, c3 = codes
        if not (lo <= c0 <= hi and lo <= c1 <= hi and lo <= c2 <= hi and lo <= c3 <= hi):
            self.counters.app_codes_clipped += 1
            self._log_once("app:codes", "node %d: on_sync codes %s outside %d-bit range, clipped", self.node_id, np.array(codes, dtype=np.int64), bits)
            c0, c1, c2, c3 = (min(hi, max(lo, c)) for c in codes)
        if bits <= 16:
            s16 = 16 - bits
            words16 = [c0 << s16, c1 << s16, c2 << s16, c3 << s16]
        else:
            s16 = bits - 16
            words16 = [c0 >> s16, c1 >> s16, c2 >> s16, c3 >> s16]
        s32 = 32 - bits
        w0, w1, w2, w3 = c0 << s32, c1 << s32, c2 << s32, c3 << s32
        self._in16 = words16
        self._in32 = words32 = [w0, w1, w2, w3]
        counters = self.counters
        counters.tx["tpdo1"] += 1  # _emit, inline
        tpdo1 = encode_analog_inputs_16(words16)
        self._outbox.append(Frame(self._tpdo1_id, tpdo1, self._now))
        if self._echo_memory is not None:
            self._echo_memory[self._tpdo1_id].append(tpdo1)
        if bits > 16:
            tpdo2, tpdo3 = encode_analog_inputs_32(words32)
            self._emit(self.ids["tpdo2"], tpdo2, "tpdo2")
            self._emit(self.ids["tpdo3"], tpdo3, "tpdo3")
        counters.samples += 1
        s0, s1, s2, s3 = saturated
        if s0 or s1 or s2 or s3:
            counters.saturated_samples += int(s0) + int(s1) + int(s2) + int(s3)
            self._set_fault(_INPUT_SATURATED, True, bytes([int(s0) | int(s1) << 1 | int(s2) << 2 | int(s3) << 3]))
        elif _INPUT_SATURATED in self._faults:
            self._set_fault(_INPUT_SATURATED, False)

    def _output_words(self) -> npt.NDArray[np.int64]:
        return np.array([int(self.od.get(OD_ANALOG_OUTPUT_16, s)) for s in range(1, N_ANALOG_OUTPUTS + 1)], dtype=np.int64)

    def _zero_outputs(self) -> None:
        self._out16 = [0, 0]
        self._outputs_v = _ZERO_VOLTS

    def _apply_outputs(self, words: npt.ArrayLike, limit_v: float | None = None) -> None:
        w = words.tolist() if isinstance(words, np.ndarray) else [int(x) for x in words]  # type: ignore[union-attr,arg-type]  # ArrayLike admits no iteration in numpy's stubs
        conf = self._config()
        if limit_v is not None:
            conf = conf[:7] + _dac_bounds(limit_v)
        self._apply_words(int(w[0]), int(w[1]), conf)

    def _apply_words(self, w0: int, w1: int, conf: tuple[int, float, float, float, float, float, int, int, int]) -> None:
        """Two RPDO1 words to the valves: D/A codes (the 4 padding bits
        dropped), clipped to the valve limit's codes (``conf``'s last two)."""
        self._out16 = [w0, w1]
        lo, hi = conf[7], conf[8]
        lsb = _DAC_LSB
        # Plain ints: the code's int -> float conversion and the product by one LSB are
        # the same IEEE operations numpy does on the int64 array.
        c0, c1 = w0 >> _DAC_SHIFT, w1 >> _DAC_SHIFT
        clip0, clip1 = c0 < lo or c0 > hi, c1 < lo or c1 > hi
        # min(hi, max(lo, c)) written out (ints: the same values)
        v0 = float(lo if c0 < lo else (hi if c0 > hi else c0)) * lsb
        v1 = float(lo if c1 < lo else (hi if c1 > hi else c1)) * lsb
        self._outputs_v = (v0, v1)
        self.counters.outputs_applied += 1
        try:
            values = self._on_output_values
            if values is not None:
                values(v0, v1)
            else:
                self.app.on_outputs(np.array((v0, v1), dtype=np.float64))
        except Exception:  # noqa: BLE001 - as _call_app
            self._app_failed("on_outputs")
        if clip0 or clip1:
            self.counters.clipped_outputs += 1
            self._set_fault(_OUTPUT_CLIPPED, True, bytes([int(clip0) | (int(clip1) << 1)]))
        elif _OUTPUT_CLIPPED in self._faults:
            self._set_fault(_OUTPUT_CLIPPED, False)

    # --- watchdog ------------------------------------------------------------------------

    def _deadlines(self) -> tuple[float | None, float | None]:
        """(SYNC watchdog, RPDO1 deadline monitoring) while armed, else None."""
        if self.state is not NmtState.OPERATIONAL or self._tripped:
            return None, None
        conf = self._config()
        sync_timeout, rpdo_timeout = conf[5], conf[4]
        sync = self._wd_last + sync_timeout if self._wd_last is not None and sync_timeout > 0 else None
        rpdo = self._rpdo_last + rpdo_timeout if self._rpdo_last is not None and rpdo_timeout > 0 else None
        return sync, rpdo

    def _watchdog_deadline(self) -> float | None:
        times = [t for t in self._deadlines() if t is not None]
        return min(times) if times else None

    def _trip(self, now: float) -> None:
        # SYNC silent, or SYNC still coming but RPDO1 stopped: someone else's
        # SYNC stream must not keep the valves open for a controller that froze.
        sync_deadline, _ = self._deadlines()
        self._trip_cause = "sync" if sync_deadline is not None and now >= sync_deadline else "rpdo"
        self._tripped = True
        self.counters.watchdog_trips += 1
        if self._trip_cause == "sync":
            assert self._wd_last is not None
            log.warning("node %d: no SYNC for %.1f ms: watchdog tripped, valves held at zero", self.node_id, (now - self._wd_last) * 1e3)
        else:
            self.counters.rpdo_timeouts += 1
            assert self._rpdo_last is not None
            log.warning("node %d: SYNC present but no RPDO1 for %.1f ms: watchdog tripped, valves held at zero", self.node_id, (now - self._rpdo_last) * 1e3)
        self._zero_outputs()
        self._call_app("on_watchdog", self.app.on_watchdog, True)
        cause = 0 if self._trip_cause == "sync" else 1
        self._trip_code = int(EmcyCode.SYNC_TIMEOUT) if cause == 0 else int(EmcyCode.RPDO_TIMEOUT)
        self._set_fault(self._trip_code, True, bytes([self._last_sync_counter or 0, cause]))
        self._set_fault(EmcyCode.OUTPUT_CLIPPED, False)

    def _recover(self, now: float) -> None:
        self._tripped = False
        self.counters.watchdog_recoveries += 1
        log.info("node %d: %s back, watchdog released", self.node_id, "SYNC" if self._trip_cause == "sync" else "RPDO1")
        self._wd_last = now
        self._rpdo_last = now if self._rpdo_last is not None else None
        self._call_app("on_watchdog", self.app.on_watchdog, False)
        self._clear_trip_fault()

    def _clear_trip_fault(self) -> None:
        if self._trip_code:
            self._set_fault(self._trip_code, False)
            self._trip_code = 0

    # --- EMCY ------------------------------------------------------------------------------

    def _set_fault(self, code: int, active: bool, vendor: bytes = b"") -> None:
        code = int(code)
        if active:
            if code in self._faults:
                return
            self._faults[code] = vendor
            self._record_error(code, vendor)
            self._emcy(code, vendor)
        else:
            if code not in self._faults:
                return
            del self._faults[code]
            self._emcy(EmcyCode.NO_ERROR, code.to_bytes(2, "little"))

    def _record_error(self, code: int, vendor: bytes) -> None:
        info = int.from_bytes(vendor[:2].ljust(2, b"\x00"), "little")
        self._error_history.insert(0, code | (info << 16))
        del self._error_history[8:]
        for sub in range(1, 9):
            self.od.set(0x1003, sub, self._error_history[sub - 1] if sub <= len(self._error_history) else 0)
        self.od.set(0x1003, 0, len(self._error_history))

    def _emcy(self, code: int, vendor: bytes) -> None:
        if self.state not in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            self.counters.emcy_suppressed += 1
            return
        self._emit(self.ids["emcy"], encode_emcy(code, self.error_register, vendor[:5]), "emcy")

    # --- plumbing -------------------------------------------------------------------------

    def _start_timers(self, now: float) -> None:
        if self._hb_next is None:
            period = self.heartbeat_period_s
            if period > 0:
                self._hb_next = now + period

    def _timers(self, now: float) -> None:
        """What :meth:`poll` does: start the heartbeat if it is not running,
        send it when due, trip the watchdog at its deadline (:meth:`_deadlines`,
        inline: this runs after every frame)."""
        conf = self._config()
        period = conf[3]
        hb_next = self._hb_next
        if hb_next is None:
            if period > 0:
                self._hb_next = now + period  # first beat one period from now
        elif period > 0 and now >= hb_next:
            self._emit(self._hb_id, encode_heartbeat(self.state), "heartbeat")
            hb_next += period
            if hb_next <= now:
                self.counters.heartbeat_late += 1
                hb_next = now + period
            self._hb_next = hb_next
        quiet = self._hb_next if period > 0 and self._hb_next is not None else math.inf
        if self.state is _OPERATIONAL and not self._tripped:
            sync_timeout, rpdo_timeout = conf[5], conf[4]
            wd_last, rpdo_last = self._wd_last, self._rpdo_last
            sync_due = wd_last + sync_timeout if wd_last is not None and sync_timeout > 0 else math.inf
            rpdo_due = rpdo_last + rpdo_timeout if rpdo_last is not None and rpdo_timeout > 0 else math.inf
            if now >= sync_due or now >= rpdo_due:
                self._trip(now)  # held from now on: no watchdog deadline until it recovers
            else:  # min(quiet, sync_due, rpdo_due), written out
                if sync_due < quiet:
                    quiet = sync_due
                if rpdo_due < quiet:
                    quiet = rpdo_due
        self._quiet_until = quiet
        self._quiet_generation = self.od.generation

    def _emit(self, cob_id: int, data: bytes, kind: str) -> None:
        self.counters.tx[kind] += 1
        self._outbox.append(Frame(cob_id, data, self._now))
        if self._echo_memory is not None:
            self._echo_memory[cob_id].append(data)

    def _drain(self) -> list[can.Message]:
        out, self._outbox = self._outbox, []
        return [f.to_message() for f in out]

    def _malformed(self, kind: str, cob_id: int, data: bytes, why: str) -> None:
        self.counters.malformed[kind] += 1
        self._log_once(
            kind,
            "node %d: ignored %s frame id 0x%03X data [%s]: %s (further ones are only counted)",
            self.node_id,
            kind,
            cob_id,
            data.hex(" "),
            why,
        )

    def _log_once(self, key: str, fmt: str, *args: object) -> None:
        if key not in self._logged:
            self._logged.add(key)
            log.warning(fmt, *args)

    def _call_app(self, name: str, fn: Callable[..., Any], *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception:  # noqa: BLE001 - the app's bug must not take the bus down
            self._app_failed(name)
            return None

    def _app_failed(self, name: str) -> None:
        """An application callback raised (called from inside its ``except``): counted, logged once."""
        self.counters.app_errors += 1
        if f"app:{name}" not in self._logged:
            self._logged.add(f"app:{name}")
            log.exception("node %d: application callback %s failed (further failures only counted)", self.node_id, name)
