"""The recorder: one MCAP file per run, written from its own thread.

Its API is three calls any source can make from any thread; each only
enqueues (never blocks, never raises on bad input), so a caller in a
real-time path pays a tuple and a queue put:

* :meth:`Recorder.on_can_frame` -- a CAN frame (id, data, wall time;
  direction and simulated time are derived from the COB-ID and the SYNCs
  unless given);
* :meth:`Recorder.on_message` -- a zenoh sample (key, payload bytes);
* :meth:`Recorder.on_liveliness` -- a liveliness token appearing or vanishing.

:class:`~workbench.recording.tap.Tap` feeds it from a zenoh subscriber on
``ralf/<rig>/**`` and a python-can listener; a one-thread co-simulation can
call the same three methods directly. The writer thread validates each JSON
payload against its key's pydantic model (a payload that fails goes to
``/_undecodable``, counted), decodes batches and TF snapshots into typed
arrays, and writes
the MCAP records; run metadata goes in with :meth:`Recorder.add_metadata`.
When the queue is full (the writer cannot keep up) items are dropped and
counted, never waited for. Optionally the CAN side is also written in
python-can's ``.blf``/``.asc``/``.log`` formats (``can_log=``).
"""

from __future__ import annotations

import base64
import json
import logging
import os
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Protocol

import can
from mcap.writer import CompressionType, Writer

from protocol.batch_codec import decode_batch
from protocol.can_map import DEFAULT_NODE_ID
from protocol.errors import ProtocolError
from protocol.messages import decode
from protocol.tf_codec import decode_tf
from service_kit.counters import Counters
from workbench.recording import schemas

log = logging.getLogger(__name__)

DEFAULT_QUEUE_LIMIT = 200_000
"""Items waiting for the writer before new ones are dropped (about 1 min of a 200 Hz rig)."""


WRITER_NICENESS = 10
"""The writer thread's nice increment: it runs beside a real-time rig on the
same cores, and whatever it does can wait; the loop's processes cannot."""


def _yield_to_the_loop() -> None:
    """Lower this thread's scheduling priority (Linux: niceness is per thread);
    best effort, the recording is the same either way."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + WRITER_NICENESS))
    except (AttributeError, OSError):  # not Linux, or not permitted
        pass


def _ns(t_s: float) -> int:
    return max(0, int(round(t_s * 1e9)))


@dataclass
class RecorderStats(Counters):
    can_frames: int = 0
    messages: int = 0
    liveliness: int = 0
    undecodable: int = 0
    dropped: int = 0
    """Items the full queue refused (the writer fell behind)."""
    can_socket_drops: int = 0
    """CAN frames the kernel dropped before the tap read them (a full socket buffer; Linux, loop-free bus)."""


CHUNK_BYTES = 64 * 1024
"""Records per chunk (uncompressed bytes): a chunk reaches the file about every
second of a real-time run, so a recording cut by a signal (no summary, its last
chunk half written) still reads up to a second or so before the cut
(:func:`workbench.recording.reader.read_up_to_cut`). The mcap library's default,
1 MiB, held the first minute of a run in memory."""


class Mirror(Protocol):
    """Another consumer of the records (topic, schema title, JSON schema, JSON bytes, log time in s),
    called from the writer thread: it must not block. ``accept`` says first whether it wants a
    record of ``topic`` arriving at ``log_s`` (without a file, a record nobody wants is not built)."""

    def accept(self, topic: str, log_s: float) -> bool: ...

    def on_record(self, topic: str, title: str, schema: Mapping[str, Any], data: bytes, log_s: float) -> None: ...


class Recorder:
    """Write everything a run carries into one MCAP file (see the module doc)."""

    def __init__(
        self,
        path: str | Path | None,
        *,
        sample_rate_hz: float = 200.0,
        node_id: int = DEFAULT_NODE_ID,
        can_log: str | Path | None = None,
        queue_limit: int = DEFAULT_QUEUE_LIMIT,
        compression: CompressionType = CompressionType.ZSTD,
        autostart: bool = True,
        decode_can: bool = True,
        mirror: Mirror | None = None,
    ) -> None:
        self.node_id = node_id
        self.stats = RecorderStats()
        self.clock = schemas.SyncClock(1.0 / sample_rate_hz)
        self.mirror = mirror
        """Also gets every record the file gets (the live view, :mod:`workbench.live`); ``path=None``: only it does."""
        self.path = Path(path) if path is not None else None
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "wb")
            self._writer = Writer(self._file, compression=compression, chunk_size=CHUNK_BYTES)
            self._writer.start(profile=schemas.PROFILE, library="ralf-hil recorder (mcap-python)")
            self._file.flush()  # the header on disk now: a started recording is a file a user (or a test) can see
        self._channels: dict[tuple[str, str], int] = {}
        self._schemas: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._can_log: can.Listener | None = can.Logger(str(can_log)) if can_log else None
        self._dbc = schemas.load_dbc() if decode_can else None
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue(maxsize=queue_limit)
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="mcap-recorder", daemon=True)
        if autostart:
            self._thread.start()

    def start(self) -> None:
        """Start the writer thread (done by the constructor unless ``autostart=False``)."""
        if not self._thread.is_alive() and not self._closed:
            self._thread.start()

    # -- the API (any thread) -----------------------------------------------------------
    def on_can_frame(
        self,
        arbitration_id: int,
        data: bytes | bytearray,
        *,
        wall_time_s: float | None = None,
        is_extended_id: bool = False,
        direction: str | None = None,
        sim_time_s: float | None = None,
        tick: int | None = None,
    ) -> None:
        """A CAN frame. ``direction`` defaults to the COB-ID's (:func:`~workbench.recording.schemas.direction_of`),
        the simulated time to the SYNC clock's (give both when the caller knows them)."""
        self._put(
            ("can", int(arbitration_id), bytes(data), time.time() if wall_time_s is None else wall_time_s, bool(is_extended_id), direction, sim_time_s, tick)
        )

    def on_message(self, key: str, payload: bytes | bytearray | memoryview, *, wall_time_s: float | None = None, encoding: str = "") -> None:
        """A zenoh sample on ``key`` (its payload bytes, as they travelled)."""
        self._put(("msg", str(key), bytes(payload), time.time() if wall_time_s is None else wall_time_s, str(encoding)))

    def on_record(self, topic: str, schema: Mapping[str, Any], record: Mapping[str, Any], *, wall_time_s: float | None = None) -> None:
        """A JSON record of the rig's own (not a zenoh sample) on ``topic`` with ``schema``."""
        self._put(("rec", str(topic), schema, dict(record), time.time() if wall_time_s is None else wall_time_s))

    def on_liveliness(self, key: str, alive: bool, *, wall_time_s: float | None = None) -> None:
        """A liveliness token ``ralf/<rig>/alive/<service>`` appeared (True) or vanished."""
        self._put(("alive", str(key), bool(alive), time.time() if wall_time_s is None else wall_time_s))

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """An MCAP metadata record; non-string values are written as JSON."""
        self._put(("meta", name, {str(k): v if isinstance(v, str) else json.dumps(v, default=str) for k, v in values.items()}))

    def close(self, timeout_s: float = 30.0) -> RecorderStats:
        """Write what is queued, the recorder's own counters, and finish the file (summary, index)."""
        if self._closed:
            return self.stats
        if not self._thread.is_alive():
            self._thread.start()
        self._closed = True
        self._queue.put(None)
        self._thread.join(timeout=timeout_s)
        if self._thread.is_alive():
            log.error("recorder: the writer did not finish within %.0f s; %s may be incomplete", timeout_s, self.path)
            return self.stats
        if self._writer is not None and self._file is not None:
            self._writer.add_metadata("ralf.recorder", {k: str(v) for k, v in self.stats.as_dict().items()})
            self._writer.finish()
            self._file.close()
        if self._can_log is not None:
            self._can_log.stop()
        return self.stats

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _skipped(self, topic: str, wall: float) -> bool:
        """Without a file, a record the mirror does not want (decimated) is not built at all."""
        return self._writer is None and self.mirror is not None and not self.mirror.accept(topic, wall)

    # -- the writer thread --------------------------------------------------------------
    def _put(self, item: tuple[Any, ...]) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.stats.dropped += 1

    def _run(self) -> None:
        _yield_to_the_loop()
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self._write(item)
            except Exception:  # a bad item must not end the recording
                self.stats.undecodable += 1
                log.exception("recorder: could not write a %s item", item[0])

    def _write(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "can":
            self._write_can(*item[1:])
        elif kind == "msg":
            self._write_message(*item[1:])
        elif kind == "rec":
            _, topic, schema, record, wall = item
            self._emit(topic, schema, record, wall)
        elif kind == "alive":
            _, key, alive, wall = item
            rig_root = key.rsplit("/", 2)[0]
            self._emit(
                schemas.topic_for_key(rig_root + "/alive"),
                schemas.LIVELINESS_SCHEMA,
                {"service": key.rsplit("/", 1)[-1], "alive": alive, "wall_time_s": wall},
                wall,
            )
            self.stats.liveliness += 1
        elif kind == "meta" and self._writer is not None:
            self._writer.add_metadata(item[1], item[2])

    def _write_can(self, cob: int, data: bytes, wall: float, extended: bool, direction: str | None, sim_time: float | None, tick: int | None) -> None:
        clock_tick = self.clock.on_frame(cob) if not extended else self.clock.tick
        if tick is None:
            tick = clock_tick
        if sim_time is None:
            sim_time = self.clock.sim_time(tick)
        name = schemas.frame_name(cob, self.node_id) if not extended else "other"
        record = {
            "arbitration_id": cob,
            "is_extended_id": extended,
            "dlc": len(data),
            "data": list(data),
            "frame": name,
            "direction": direction or (schemas.direction_of(cob, self.node_id) if not extended else "unknown"),
            "wall_time_s": wall,
            "sim_time_s": sim_time,
            "tick": tick,
        }
        if not self._skipped(schemas.CAN_TOPIC, wall):
            self._emit(schemas.CAN_TOPIC, schemas.CAN_SCHEMA, record, wall)
        self.stats.can_frames += 1
        if self._dbc is not None and not extended:
            self._write_decoded(cob, data, wall, sim_time, tick)
        if self._can_log is not None:
            self._can_log.on_message_received(
                can.Message(timestamp=wall, arbitration_id=cob, data=data, is_extended_id=extended, is_rx=record["direction"] != schemas.TO_PLANT)
            )

    def _write_decoded(self, cob: int, data: bytes, wall: float, sim_time: float | None, tick: int | None) -> None:
        """The frame's signals by the shipped DBC, one topic per DBC message (plottable as they are)."""
        assert self._dbc is not None
        try:
            message = self._dbc.get_message_by_frame_id(cob)
            if self._skipped(f"{schemas.CAN_DECODED_PREFIX}/{message.name}", wall):
                return
            signals = message.decode(data, decode_choices=False)
        except Exception:  # not in the DBC (another node id), or a frame it does not describe (SYNC without counter)
            return
        record = {"tick": tick, "sim_time_s": sim_time, "wall_time_s": wall, **{k: float(v) if isinstance(v, float) else int(v) for k, v in signals.items()}}
        self._emit(f"{schemas.CAN_DECODED_PREFIX}/{message.name}", schemas.decoded_schema(message), record, wall)

    def _write_message(self, key: str, payload: bytes, wall: float, encoding: str) -> None:
        topic = schemas.topic_for_key(key)
        if self._skipped(topic, wall):
            return
        try:
            if schemas.is_batch_key(key):
                b = decode_batch(payload)
                record = {
                    "seq": b.seq,
                    "first_tick": b.first_tick,
                    "n_samples": b.n_samples,
                    "dropped_before": b.dropped_before,
                    "sample_rate_hz": b.sample_rate_hz,
                    "sim_time_s": b.sim_time_s,
                    "wall_time_s": b.wall_time_s,
                    "inputs": b.inputs.tolist(),
                    "outputs": b.outputs.tolist(),
                }
                self._emit(topic, schemas.BATCH_SCHEMA, record, wall, publish_s=b.wall_time_s, metadata={"zenoh_key": key, "zenoh_encoding": encoding})
            elif schemas.is_tf_key(key):
                snap = decode_tf(payload)
                self._emit(topic, schemas.TF_SCHEMA, snap.as_json(), wall, publish_s=snap.wall_time_s, metadata={"zenoh_key": key, "zenoh_encoding": encoding})
            else:
                model = schemas.model_for_key(key)
                if model is None:
                    raise ProtocolError(f"no message model for key {key!r}")
                message = decode(model, payload)
                sent = getattr(message, "wall_time_s", wall)
                # The payload as it travelled (it validated): bit-for-bit the sender's JSON.
                self._emit_raw(
                    topic, model.__name__, schemas.schema_of(model), payload, wall, publish_s=sent, metadata={"zenoh_key": key, "zenoh_encoding": encoding}
                )
        except ProtocolError as exc:
            self.stats.undecodable += 1
            raw = {
                "key": key,
                "encoding": encoding,
                "size": len(payload),
                "data_base64": base64.b64encode(payload).decode(),
                "error": str(exc),
                "wall_time_s": wall,
            }
            self._emit(schemas.UNDECODABLE_TOPIC, schemas.RAW_SCHEMA, raw, wall)
            return
        self.stats.messages += 1

    def _emit(
        self,
        topic: str,
        schema: Mapping[str, Any],
        record: Mapping[str, Any],
        log_s: float,
        publish_s: float | None = None,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        data = json.dumps(record, separators=(",", ":"), allow_nan=False).encode()
        self._emit_raw(topic, str(schema["title"]), schema, data, log_s, publish_s, metadata)

    def _emit_raw(
        self,
        topic: str,
        schema_name: str,
        schema: Mapping[str, Any],
        data: bytes,
        log_s: float,
        publish_s: float | None = None,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        title = str(schema.get("title", schema_name))
        if self.mirror is not None and (self._writer is None or self.mirror.accept(topic, log_s)):  # without a file: accepted before it was built
            self.mirror.on_record(topic, title, schema, data, log_s)
        if self._writer is None:
            return
        channel = self._channels.get((topic, title))
        if channel is None:
            schema_id = self._schemas.get(title)
            if schema_id is None:
                schema_id = self._writer.register_schema(name=title, encoding="jsonschema", data=json.dumps(schema).encode())
                self._schemas[title] = schema_id
            # The channel keeps the zenoh key and encoding of its first sample.
            channel = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id, metadata=dict(metadata or {}))
            self._channels[(topic, title)] = channel
        seq = self._sequence.get(channel, 0)
        self._sequence[channel] = seq + 1
        self._writer.add_message(
            channel_id=channel, log_time=_ns(log_s), data=data, publish_time=_ns(publish_s if publish_s is not None else log_s), sequence=seq
        )
