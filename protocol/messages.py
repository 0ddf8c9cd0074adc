"""Control messages exchanged over zenoh, as pydantic v2 models in JSON
(and :class:`TfSnapshot`, typed arrays in the binary layout of
:mod:`protocol.tf_codec`).

Every message that crosses a process carries a sequence number, the
simulated time and the sender's wall-clock time (docs/design.md, "Time"),
so receivers can detect gaps, duplicates and reordering and measure
latencies.  Decoding validates everything; a bad payload raises
:class:`~protocol.errors.ProtocolError` with the reason.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Annotated, Any, Final, Literal, TypeVar

import numpy as np
import numpy.typing as npt
import pydantic_core
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from protocol.channel_faults import ChannelFault
from protocol.errors import ProtocolError

# Every numeric field is bounded (a peer's 1e300 is refused at decoding, not
# discovered by whatever arithmetic it reaches), every text and collection
# has a maximum length.
MAX_ABS = 1e15
"""Bound of physical quantities (seconds, inches, radians, magnitudes)."""
MAX_LATENCY_S = 10.0
"""Bound of an emulated DSP latency: the same cap as the ``emulated_latency_s`` setting."""
MAX_BINS = 65536 // 2 + 1
"""Frequency bins of the largest FFT width (65536)."""
NonNegFloat = Annotated[float, Field(ge=0.0, le=MAX_ABS, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(ge=-MAX_ABS, le=MAX_ABS, allow_inf_nan=False)]
LatencyS = Annotated[float, Field(ge=0.0, le=MAX_LATENCY_S, allow_inf_nan=False)]
Seq = Annotated[int, Field(ge=0, lt=2**63)]
Count = Annotated[int, Field(ge=0, lt=2**63)]
Hz = Annotated[float, Field(ge=0.0, le=1e5, allow_inf_nan=False)]
ShortText = Annotated[str, Field(max_length=64)]
LongText = Annotated[str, Field(max_length=2000)]
RequestId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+$")]


class Message(BaseModel):
    """Base of every control message: strict, immutable, finite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seq: Seq = Field(description="Sender's sequence number for this message type, from 0")
    sim_time_s: NonNegFloat = Field(description="Simulated time the message refers to")
    wall_time_s: NonNegFloat = Field(default_factory=time.time, description="Sender's wall clock at sending (Unix s)")


class BlockFlag(Message):
    """The DSP's batch memory block state (thesis §3.2.3, Fig. 3.5 steps 1 and 4).

    ``empty`` invites the next batch; ``full`` acknowledges a batch being
    processed. ``next_batch_seq`` is the batch sequence number the DSP
    expects next. After a batch the :class:`Interrupt` is the empty flag
    (batch ``k``'s interrupt: empty, ``k + 1`` expected) and no flag follows
    it; flags go at start, after a config change, as a re-announce and after
    an internal error. A receiver takes a flag an older board sends after
    every interrupt as an echo of it.
    """

    state: Literal["empty", "full"]
    next_batch_seq: Seq
    fft_width: Annotated[int, Field(ge=16, le=65536)]
    batch_size: Annotated[int, Field(ge=1, le=65536)]
    emulated_latency_s: LatencyS = Field(0.0, description="When the interrupt for the next batch is due, in simulated time after it is sent")
    config_seq: Seq | None = Field(
        None, description="seq of the last ConfigChange the board applied (None: none yet); a CPU starts its run once its reset is applied"
    )

    @model_validator(mode="after")
    def _power_of_two(self) -> BlockFlag:
        if self.fft_width & (self.fft_width - 1):
            raise ValueError(f"fft_width must be a power of two, got {self.fft_width}")
        return self


class PoleParameters(BaseModel):
    """One identified vibration mode: the parameters the OATF is built from."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frequency_hz: Annotated[float, Field(gt=0.0, le=1e5, allow_inf_nan=False)]
    damping_ratio: Annotated[float, Field(ge=0.0, le=1e3, allow_inf_nan=False)]
    magnitude: NonNegFloat = 0.0
    source: ShortText = Field(default="tot", description="Transfer function the peak was found on: tot, 11, 12, 21, 22, or arx (the parametric model)")
    confidence: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = Field(
        None, description="This pole's confidence (interrupt version 2); None: the interrupt's confidence applies"
    )


INTERRUPT_VERSION: Final = 2
"""Version 1: poles without confidence (the first pole was the one used). Version 2: every confident
pole, first mode first, each with its own ``confidence``; decoders read version 1 payloads too."""


class Interrupt(Message):
    """The DSP's interrupt after processing a batch (Fig. 3.5 step 4).

    The board releases the block before it raises the interrupt, so the
    interrupt also flags the block empty, expecting batch ``batch_seq + 1``
    (one message per batch, no separate :class:`BlockFlag`).
    ``poles``: every confident pole, the first mode first (version 2).
    """

    version: Literal[1, 2] = INTERRUPT_VERSION
    batch_seq: Seq
    poles: tuple[PoleParameters, ...] = Field((), max_length=16)
    confidence: Annotated[float, Field(ge=0.0, le=1.0)]
    compute_time_s: NonNegFloat = Field(description="Measured wall time of the identification step")
    emulated_latency_s: LatencyS = Field(default=0.0, description="C40 compute latency emulated on top")
    samples_in_history: Annotated[int, Field(ge=0, lt=2**63)] = 0
    valid_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    deadline_missed: bool = False

    @model_validator(mode="after")
    def _pole_confidence_versioned(self) -> Interrupt:
        if self.version == 1 and any(p.confidence is not None for p in self.poles):
            raise ValueError("a version-1 interrupt carries no per-pole confidence")
        return self


class ConfigChange(Message):
    """Run-time change of the DSP's configuration (thesis §3.2.3).

    Changing ``fft_width`` zeroes the history (as on the C40); changing
    ``batch_size`` keeps it.
    """

    fft_width: Annotated[int, Field(ge=32, le=65536)] | None = None
    batch_size: Annotated[int, Field(ge=1, le=4096)] | None = None
    alpha: Annotated[float, Field(gt=0.0, lt=1.0)] | None = None
    emulated_latency_s: LatencyS | None = None
    reset: bool = Field(False, description="A new CPU run: the DSP restarts sequence numbers and history")
    request_id: RequestId | None = Field(None, description="Set by a tool that waits for the DSP's ConfigAck; forwarded unchanged by the controller")

    @model_validator(mode="after")
    def _power_of_two(self) -> ConfigChange:
        if self.fft_width is not None and self.fft_width & (self.fft_width - 1):
            raise ValueError(f"fft_width must be a power of two, got {self.fft_width}")
        return self


class ConfigAck(Message):
    """The DSP's answer to a :class:`ConfigChange` (on ``dsp/config_ack``):
    applied or refused, with the configuration it runs with afterwards.
    ``seq`` is the change's own sequence number."""

    request_id: RequestId | None = None
    accepted: bool
    reason: LongText = ""
    fft_width: Annotated[int, Field(ge=16, le=65536)]
    batch_size: Annotated[int, Field(ge=1, le=65536)]
    alpha: Annotated[float, Field(gt=0.0, le=1.0)]
    emulated_latency_s: LatencyS

    @classmethod
    def answering(
        cls, change: ConfigChange, accepted: bool, reason: str, fft_width: int, batch_size: int, alpha: float, emulated_latency_s: float
    ) -> ConfigAck:
        """The acknowledgement of ``change`` (reason cut to the field's length)."""
        return cls(
            seq=change.seq,
            sim_time_s=change.sim_time_s,
            request_id=change.request_id,
            accepted=accepted,
            reason=reason[:2000],
            fft_width=fft_width,
            batch_size=batch_size,
            alpha=alpha,
            emulated_latency_s=emulated_latency_s,
        )


TfName = Literal["H11", "H12", "H21", "H22", "Htot"]
TF_NAMES: Final[tuple[TfName, ...]] = ("H11", "H12", "H21", "H22", "Htot")
"""The estimates a :class:`TfSnapshot` may carry, in their wire order (:mod:`protocol.tf_codec`)."""


def _tf_array(name: str, value: object, dtype: type) -> npt.NDArray[Any]:
    """A read-only 1-D array of ``dtype`` (no copy if ``value`` is one already)."""
    arr: npt.NDArray[Any] = np.asarray(value, dtype=dtype)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if arr.flags.writeable:
        if arr is value:
            arr = arr.copy()  # the caller's array stays writable and ours does not change under us
        arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class TransferFunction:
    """Magnitude and phase (rad) of one estimate over the frequency grid, as float64 arrays."""

    magnitude: npt.NDArray[np.float64]
    phase_rad: npt.NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "magnitude", _tf_array("magnitude", self.magnitude, np.float64))
        object.__setattr__(self, "phase_rad", _tf_array("phase_rad", self.phase_rad, np.float64))
        if self.magnitude.size != self.phase_rad.size:
            raise ValueError(f"magnitude has {self.magnitude.size} bins, phase {self.phase_rad.size}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TransferFunction):
            return NotImplemented
        return np.array_equal(self.magnitude, other.magnitude) and np.array_equal(self.phase_rad, other.phase_rad)

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class TfSnapshot:
    """The DSP's current transfer-function estimates (thesis §4.2.2: the CPU
    downloads them every ``tf_download_samples`` samples, for spectrograms).

    Binary on the wire (:mod:`protocol.tf_codec`: a versioned header and
    little-endian float64 arrays, decoded straight into numpy, no Python float
    per bin). The arrays are read-only, one value per frequency bin:

    * ``freqs_hz``: the frequency grid (float64);
    * ``valid``: where the estimates are defined (bool);
    * ``estimates``: by name (``H11`` ... ``Htot``), magnitude and phase (float64).

    ``seq`` numbers the DSP's snapshots from 0, ``batch_seq`` is the last batch
    they include, ``sim_time_s`` its simulated time and ``wall_time_s`` the
    DSP's wall clock when it took the snapshot (docs/design.md, "Time").
    Construction checks shapes and names; the codec checks values
    (finite, within :data:`MAX_ABS`).
    """

    seq: int
    sim_time_s: float
    batch_seq: int
    freqs_hz: npt.NDArray[np.float64]
    valid: npt.NDArray[np.bool_]
    estimates: Mapping[TfName, TransferFunction]
    wall_time_s: float = field(default_factory=time.time)

    def __post_init__(self) -> None:
        object.__setattr__(self, "freqs_hz", _tf_array("freqs_hz", self.freqs_hz, np.float64))
        object.__setattr__(self, "valid", _tf_array("valid", self.valid, np.bool_))
        n = self.freqs_hz.size
        if n > MAX_BINS:
            raise ValueError(f"a snapshot holds at most {MAX_BINS} bins, got {n}")
        if self.valid.size != n:
            raise ValueError("valid mask length differs from the frequency grid")
        for name, tf in self.estimates.items():
            if name not in TF_NAMES:
                raise ValueError(f"unknown estimate {name!r} (known: {', '.join(TF_NAMES)})")
            if not isinstance(tf, TransferFunction):
                raise ValueError(f"{name} is not a TransferFunction")
            if tf.magnitude.size != n:
                raise ValueError(f"{name} length differs from the frequency grid")
        object.__setattr__(self, "estimates", MappingProxyType(dict(self.estimates)))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TfSnapshot):
            return NotImplemented
        return (
            (self.seq, self.sim_time_s, self.wall_time_s, self.batch_seq) == (other.seq, other.sim_time_s, other.wall_time_s, other.batch_seq)
            and np.array_equal(self.freqs_hz, other.freqs_hz)
            and np.array_equal(self.valid, other.valid)
            and dict(self.estimates) == dict(other.estimates)
        )

    __hash__ = None  # type: ignore[assignment]

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Complex arrays by name, plus ``freqs_hz`` and ``valid``."""
        out: dict[str, np.ndarray] = {"freqs_hz": self.freqs_hz, "valid": self.valid}
        for name, tf in self.estimates.items():
            out[name] = tf.magnitude * np.exp(1j * tf.phase_rad)
        return out

    def as_json(self) -> dict[str, Any]:
        """The snapshot as plain JSON values (lists of floats): how a recording stores it."""
        return {
            "seq": self.seq,
            "sim_time_s": self.sim_time_s,
            "wall_time_s": self.wall_time_s,
            "batch_seq": self.batch_seq,
            "freqs_hz": self.freqs_hz.tolist(),
            "valid": self.valid.tolist(),
            "estimates": {name: {"magnitude": tf.magnitude.tolist(), "phase_rad": tf.phase_rad.tolist()} for name, tf in self.estimates.items()},
        }


class LatencyStats(BaseModel):
    """Percentiles of one measured latency, in seconds."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    count: Count
    p50: NonNegFloat
    p99: NonNegFloat
    p999: NonNegFloat
    max: NonNegFloat


class Health(Message):
    """A service's health: counters, latency percentiles and the last miss."""

    service: ShortText
    state: Literal["starting", "running", "degraded", "stopping", "failed"] = "running"
    counters: Annotated[dict[ShortText, Annotated[int, Field(ge=-(2**63), lt=2**63)]], Field(max_length=512)] = Field(default_factory=dict)
    latencies: Annotated[dict[ShortText, LatencyStats], Field(max_length=64)] = Field(default_factory=dict)
    last_miss: LongText | None = None


class ControllerStatus(Message):
    """The controller's running state, for the live status line."""

    ticks: Count
    loop_rate_hz: Hz
    batches_sent: Count
    interrupts: Count
    latest_frequency_hz: Hz | None = None
    deadline_misses: Count = 0
    overruns: Count = 0
    finished: bool = False


class GroundTruth(Message):
    """The plant's true state on the test port (never used by the controller)."""

    modal_frequencies_hz: Annotated[tuple[FiniteFloat, ...], Field(max_length=64)]
    damping_ratios: Annotated[tuple[FiniteFloat, ...], Field(max_length=64)]
    deflections_in: tuple[FiniteFloat, FiniteFloat]
    theta_rad: tuple[FiniteFloat, FiniteFloat]
    tip_in: tuple[FiniteFloat, FiniteFloat]
    payload_attached: bool
    valves_held: bool = False


Volts4 = tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat]
Volts2 = tuple[FiniteFloat, FiniteFloat]


class ChannelTruth(Message):
    """The plant's signal channels beside their faults, on the test port at the truth rate
    while the plant has channel faults (docs/fault-insertion.md; never used by the controller).

    The A/D side is the conversion of this SYNC (at ``sim_time_s``), the D/A side the last D/A
    update (at ``ao_time_s``). A side whose channels have no fault in the plant's schedule is
    not taken through the fault unit and is null here (its values are TPDO1's and RPDO1's on
    the bus), as is the D/A side before its first update."""

    ai_true_v: Volts4 | None = Field(None, description="AI1-AI4: the inputs' true voltages, sensor noise included (V)")
    ai_faulted_v: Volts4 | None = Field(None, description="AI1-AI4: the voltages after the faults, at the converter (V)")
    ai_saturated: tuple[bool, bool, bool, bool] | None = Field(None, description="AI1-AI4: the converter clipped the input (EMCY INPUT_SATURATED)")
    ao_time_s: NonNegFloat | None = Field(None, description="Simulated time of the last D/A update")
    ao_commanded_v: Volts2 | None = Field(None, description="AO1-AO2: the D/A's voltages (V)")
    ao_applied_v: Volts2 | None = Field(None, description="AO1-AO2: what the valves got, after the faults (V)")
    active_faults: Annotated[tuple[LongText, ...], Field(max_length=64)] = Field((), description="The faults acting at sim_time_s, one line each")


class ScenarioCommand(Message):
    """A scenario input on the plant's test port, applied at ``at_sim_time_s``
    (or at once if that time has passed)."""

    kind: Literal["payload", "seed", "adc_bits", "channel_fault"]
    at_sim_time_s: NonNegFloat = 0.0
    payload_attached: bool | None = None
    seed: Annotated[int, Field(ge=0, lt=2**32)] | None = None
    adc_bits: Literal[12, 16, 20] | None = None
    channel_fault: ChannelFault | None = None
    """``channel_fault``: a fault joining the plant's channel faults (docs/fault-insertion.md);
    it acts from its own ``start_s`` to its ``end_s``."""

    @model_validator(mode="after")
    def _value_present(self) -> ScenarioCommand:
        needed = {"payload": self.payload_attached, "seed": self.seed, "adc_bits": self.adc_bits, "channel_fault": self.channel_fault}[self.kind]
        if needed is None:
            raise ValueError(f"scenario command {self.kind!r} needs its value")
        return self


class PlantEvent(Message):
    """Something that happened in the plant: a hard stop, a watchdog trip, a scenario applied."""

    kind: ShortText
    detail: LongText = ""


ParamName = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_]+\.[A-Za-z0-9_]+$")]
"""A run-time parameter's name: ``BOARD.NAME`` (``controller.kp1``; docs/calibration.md)."""


class ParamSet(Message):
    """A request to change one run-time parameter (``ralf-hil param set``), to its physical
    value in the parameter table's unit; the controller answers with a :class:`ParamAnswer`."""

    request_id: RequestId
    name: ParamName
    value: FiniteFloat


class ParamAnswer(Message):
    """The controller's answer to a :class:`ParamSet`: refused (with the reason) at once,
    or taken, with the physical value in effect from the tick at ``sim_time_s``."""

    request_id: RequestId
    name: ParamName
    accepted: bool
    reason: LongText = ""
    value: FiniteFloat | None = None


class ParamInfo(BaseModel):
    """One run-time parameter as the running controller lists it (``ralf-hil param list``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: ParamName
    unit: ShortText
    lower: FiniteFloat
    upper: FiniteFloat
    value: FiniteFloat | None = Field(None, description="The physical value in effect (None: not defined in this run, e.g. the OATF's when it is off)")
    description: LongText = ""


class ParamTable(Message):
    """The running controller's parameters (the answer to a query on ``controller/params``)."""

    params: tuple[ParamInfo, ...] = Field((), max_length=256)
    write_roles: tuple[ShortText, ...] = Field((), max_length=8, description="The roles whose changes this run takes")


class ParamChanged(Message):
    """A parameter change taken at a step boundary (``controller/param_changes``: from the
    controller's ``tick``; ``plant/param_changes``: from the plant's SYNC of index ``tick``), at
    ``sim_time_s``; ``kind`` names the path (``xcp``, ``param``: a live command, ``schedule``: the
    board's ``param_schedule``) and ``who`` the sender; ``fields`` by full name (``plant.payload``)."""

    tick: Count
    kind: Literal["xcp", "param", "schedule"]
    who: ShortText = ""
    fields: Annotated[dict[ParamName, FiniteFloat], Field(max_length=64)]


M = TypeVar("M", bound=BaseModel)


def encode(message: BaseModel) -> bytes:
    """JSON bytes of a message (``message.model_dump_json().encode()``, the same
    bytes, from the model's compiled serializer without the str round trip)."""
    return message.__pydantic_serializer__.to_json(message)


def encode_fields(fields: Mapping[str, Any]) -> bytes:
    """JSON bytes of a message given as its fields, with pydantic's own
    serializer (``pydantic_core.to_json``) and no validation: for a sender's
    hot path whose receiver validates at the boundary (:func:`decode`).

    ``fields`` must hold every field of the model, in the model's order, as
    plain Python values (``float`` subclasses serialize as floats, numpy
    integers do not serialize at all); the bytes are then those of
    ``encode(Model(**fields))`` (tested for :class:`Interrupt` against the
    model on the identifier's real output). The DSP sends its interrupt so and
    validates the model after the put (``dsp_service.service``): ~1.7 us
    instead of ~6 us (build + encode) warm, and three to five times that
    cold, on the batch -> interrupt path."""
    return pydantic_core.to_json(fields, inf_nan_mode="null")  # as the models write a NaN: valid JSON, refused by the receiver


def decode(model: type[M], payload: bytes | bytearray | memoryview) -> M:
    """Validate a JSON payload into ``model``; raises :class:`ProtocolError`.

    Decoding is strict: a wire value of the wrong JSON type (``"1"`` or
    ``true`` for a sequence number, ``1.0`` for a count) is rejected
    rather than coerced. The error names the offending field.
    """
    try:
        return model.model_validate_json(bytes(payload), strict=True)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        detail = f"{where}: {first['msg']}" if where else first["msg"]
        raise ProtocolError(f"invalid {model.__name__}: {exc.error_count()} error(s): {detail}") from exc
