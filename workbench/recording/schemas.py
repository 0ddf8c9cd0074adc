"""What a recording holds: its topics, their JSON schemas, and the two
small pure rules a tap needs (the direction of a CAN frame, the simulated
time of a CAN frame).

Topics (``<rig>`` the rig id; every zenoh key becomes the topic ``/`` + key)::

    /can                              every CAN frame                 ralf.CanFrame
    /can/decoded/<message>            its signals by ralf.dbc         ralf.dbc.<message>
    /ralf/<rig>/dsp/batch             sample batches, typed arrays    ralf.SampleBatch
    /ralf/<rig>/dsp/flag              block flags                     ralf.BlockFlag
    /ralf/<rig>/dsp/interrupt         the DSP's answers               ralf.Interrupt
    /ralf/<rig>/dsp/config            configuration changes           ralf.ConfigChange
    /ralf/<rig>/plant/truth           the plant's ground truth        ralf.GroundTruth
    /ralf/<rig>/plant/channels        channel truth (channel faults)  ralf.ChannelTruth
    /ralf/<rig>/plant/scenario        scenario commands               ralf.ScenarioCommand
    /ralf/<rig>/plant/events          plant events                    ralf.PlantEvent
    /ralf/<rig>/controller/status     controller status               ralf.ControllerStatus
    /ralf/<rig>/controller/tf         TF downloads, typed arrays      ralf.TfSnapshot
    /ralf/<rig>/controller/command    run-time commands               ralf.ConfigChange
    /ralf/<rig>/controller/test_command  commands with test knobs     ralf.ConfigChange
    /ralf/<rig>/health/<service>      health                          ralf.Health
    /ralf/<rig>/alive                 liveliness changes              ralf.Liveliness
    /_undecodable                     payloads that failed to decode  ralf.RawPayload

Every message is JSON (MCAP message encoding ``json``) with a JSON schema
(schema encoding ``jsonschema``): the pydantic models' own schemas for the
control messages, so a recorded message validates against its channel's
schema, and Foxglove and the ``mcap`` tools show every field. The two binary
payloads, sample batches and TF snapshots, are recorded decoded, their
float64 arrays as JSON arrays of numbers (:data:`BATCH_SCHEMA`, :data:`TF_SCHEMA`).
"""

from __future__ import annotations

from typing import Any, Final, Literal

from pydantic import BaseModel

from protocol import can_map
from protocol.messages import TF_NAMES, Health
from protocol.rig_description import RIG, json_models

CAN_TOPIC: Final[str] = "/can"
CAN_DECODED_PREFIX: Final[str] = "/can/decoded"
"""``/can/decoded/<DBC message>``: each frame's signals decoded with ``protocol/ralf.dbc`` (volts, counters)."""
UNDECODABLE_TOPIC: Final[str] = "/_undecodable"
PROFILE: Final[str] = ""
"""No ROS profile: plain JSON channels."""

Direction = Literal["controller->plant", "plant->controller"]
TO_PLANT: Final[Direction] = "controller->plant"
TO_CONTROLLER: Final[Direction] = "plant->controller"

MODELS_BY_SUFFIX: Final[dict[str, type[BaseModel]]] = {
    **json_models(),
    **{c.suffix: c.payload for c in RIG.channels if c.kind == "queryable" and isinstance(c.payload, type)},
}
"""The JSON messages of the contract, by key below ``ralf/<rig>/`` (health/* apart; a JSON
queryable's answer, ``controller/params``, too: never recorded, a tap hears no answers)."""

BATCH_SUFFIX: Final[str] = "dsp/batch"
TF_SUFFIXES: Final[tuple[str, ...]] = ("controller/tf", "dsp/tf")


def topic_for_key(key: str) -> str:
    """The MCAP topic of a zenoh key."""
    return "/" + key.lstrip("/")


def model_for_key(key: str) -> type[BaseModel] | None:
    """The pydantic model of a ``ralf/<rig>/...`` key, or None (batches, unknown keys)."""
    parts = key.strip("/").split("/")
    if len(parts) < 4 or parts[0] != "ralf":
        return None
    suffix = "/".join(parts[2:])
    if parts[2] == "health" and len(parts) == 4:
        return Health
    return MODELS_BY_SUFFIX.get(suffix)


def is_batch_key(key: str) -> bool:
    parts = key.strip("/").split("/")
    return len(parts) == 4 and parts[0] == "ralf" and "/".join(parts[2:]) == BATCH_SUFFIX


def is_tf_key(key: str) -> bool:
    """A key that carries TF snapshots (:mod:`protocol.tf_codec`): ``controller/tf`` (and ``dsp/tf`` replies)."""
    parts = key.strip("/").split("/")
    return len(parts) == 4 and parts[0] == "ralf" and "/".join(parts[2:]) in TF_SUFFIXES


def schema_of(model: type[BaseModel]) -> dict[str, Any]:
    """The JSON schema of a message model: pydantic's, titled ``ralf.<Model>``,
    with its ``$ref``s inlined (one self-contained object per channel, which
    viewers that do not follow references can read)."""
    schema = model.model_json_schema(mode="serialization")
    defs = schema.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                return inline({**defs[ref.removeprefix("#/$defs/")], **{k: v for k, v in node.items() if k != "$ref"}})
            return {k: inline(v) for k, v in node.items()}
        if isinstance(node, list):
            return [inline(v) for v in node]
        return node

    out: dict[str, Any] = inline(schema)
    out["title"] = f"ralf.{model.__name__}"
    return out


_NUMBER_ROWS: Final[dict[str, Any]] = {
    "type": "array",
    "description": "channel-major float64 samples: one array per channel, n_samples long",
    "items": {"type": "array", "items": {"type": "number"}},
}

BATCH_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.SampleBatch",
    "description": "A sample batch (protocol.batch_codec), decoded: the samples as typed float64 arrays",
    "type": "object",
    "properties": {
        "seq": {"type": "integer", "minimum": 0},
        "first_tick": {"type": "integer", "minimum": 0},
        "n_samples": {"type": "integer", "minimum": 1},
        "dropped_before": {"type": "integer", "minimum": 0},
        "sample_rate_hz": {"type": "number", "exclusiveMinimum": 0},
        "sim_time_s": {"type": "number", "minimum": 0},
        "wall_time_s": {"type": "number"},
        "inputs": {**_NUMBER_ROWS, "description": "the D/A commands (V), one array per valve"},
        "outputs": {**_NUMBER_ROWS, "description": "the measured tip deflections (in), one array per link"},
    },
    "required": ["seq", "first_tick", "n_samples", "dropped_before", "sample_rate_hz", "sim_time_s", "wall_time_s", "inputs", "outputs"],
    "additionalProperties": False,
}

_FLOATS: Final[dict[str, Any]] = {"type": "array", "items": {"type": "number"}}

TF_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.TfSnapshot",
    "description": "A transfer-function download (protocol.tf_codec), decoded: one float64 array per quantity, one value per frequency bin",
    "type": "object",
    "properties": {
        "seq": {"type": "integer", "minimum": 0, "description": "the DSP's snapshot number, from 0"},
        "sim_time_s": {"type": "number", "minimum": 0},
        "wall_time_s": {"type": "number", "minimum": 0, "description": "the DSP's wall clock when taken (Unix s)"},
        "batch_seq": {"type": "integer", "minimum": 0, "description": "the last batch the estimates include"},
        "freqs_hz": {**_FLOATS, "description": "the frequency grid (Hz)"},
        "valid": {"type": "array", "items": {"type": "boolean"}, "description": "where the estimates are defined"},
        "estimates": {
            "type": "object",
            "propertyNames": {"enum": list(TF_NAMES)},
            "additionalProperties": {
                "type": "object",
                "properties": {"magnitude": _FLOATS, "phase_rad": {**_FLOATS, "description": "phase (rad)"}},
                "required": ["magnitude", "phase_rad"],
                "additionalProperties": False,
            },
        },
    },
    "required": ["seq", "sim_time_s", "wall_time_s", "batch_seq", "freqs_hz", "valid", "estimates"],
    "additionalProperties": False,
}

CAN_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.CanFrame",
    "description": "One CAN frame as seen on the bus (CANopen, protocol/ralf.dbc)",
    "type": "object",
    "properties": {
        "arbitration_id": {"type": "integer", "minimum": 0, "maximum": 0x1FFFFFFF},
        "is_extended_id": {"type": "boolean"},
        "dlc": {"type": "integer", "minimum": 0, "maximum": 64},
        "data": {"type": "array", "items": {"type": "integer", "minimum": 0, "maximum": 255}},
        "frame": {"type": "string", "description": "CANopen frame name from the COB-ID: sync, tpdo1, rpdo1, nmt, sdo_rx, ..."},
        "direction": {"enum": [TO_PLANT, TO_CONTROLLER, "unknown"]},
        "wall_time_s": {"type": "number", "description": "receive time at the tap (Unix s)"},
        "sim_time_s": {"type": ["number", "null"], "description": "simulated time of the SYNC tick the frame belongs to (null before the first SYNC)"},
        "tick": {"type": ["integer", "null"], "description": "SYNC tick the frame belongs to"},
    },
    "required": ["arbitration_id", "is_extended_id", "dlc", "data", "frame", "direction", "wall_time_s", "sim_time_s", "tick"],
    "additionalProperties": False,
}

LIVELINESS_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.Liveliness",
    "type": "object",
    "properties": {"service": {"type": "string"}, "alive": {"type": "boolean"}, "wall_time_s": {"type": "number"}},
    "required": ["service", "alive", "wall_time_s"],
    "additionalProperties": False,
}

CAN_BUS_LOAD_TOPIC: Final = "/can/bus_load"
"""The CAN wire's bus load and latencies with ``can_bitrate`` set: the co-simulation's once at the run's end, the
wire arbiter's of ``ralf-hil up`` once a second (:mod:`service_kit.can_wire.hub_live`)."""
CAN_BUS_LOAD_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.CanBusLoad",
    "description": "The simulated wire's figures (workbench.cosim_wire.TimedCanWire.summary; times in us)",
    "type": "object",
    "properties": {
        "bitrate": {"type": "integer"},
        "busy_mean_pct": {"type": "number"},
        "busy_max_pct": {"type": "number"},
        "frames_per_s": {"type": "number"},
        "bits_per_s": {"type": "number"},
    },
    "required": ["bitrate", "busy_mean_pct", "busy_max_pct", "frames_per_s", "bits_per_s"],
}

RAW_SCHEMA: Final[dict[str, Any]] = {
    "title": "ralf.RawPayload",
    "description": "A zenoh payload that did not decode as its key's message (kept, never dropped silently)",
    "type": "object",
    "properties": {
        "key": {"type": "string"},
        "encoding": {"type": "string"},
        "size": {"type": "integer", "minimum": 0},
        "data_base64": {"type": "string"},
        "error": {"type": "string"},
        "wall_time_s": {"type": "number"},
    },
    "required": ["key", "encoding", "size", "data_base64", "error", "wall_time_s"],
    "additionalProperties": False,
}


def load_dbc() -> Any:
    """The shipped DBC (``protocol/ralf.dbc``) as a cantools database."""
    from importlib.resources import files

    import cantools

    return cantools.database.load_string(files("protocol").joinpath("ralf.dbc").read_text(), database_format="dbc")


def decoded_schema(message: Any) -> dict[str, Any]:
    """JSON schema of one DBC message's decoded signals (a cantools ``Message``)."""
    props: dict[str, Any] = {
        "tick": {"type": ["integer", "null"]},
        "sim_time_s": {"type": ["number", "null"]},
        "wall_time_s": {"type": "number"},
    }
    for sig in message.signals:
        props[sig.name] = {"type": "number", "description": f"{sig.comment or sig.name} ({sig.unit or 'raw'}), DBC {message.name}"}
    return {"title": f"ralf.dbc.{message.name}", "type": "object", "properties": props, "required": list(props), "additionalProperties": False}


def rig_topics(rig_id: str) -> list[tuple[str, dict[str, Any]]]:
    """Every topic a recording of rig ``rig_id`` may hold, with the schema its records carry
    (what the recorder emits for it): the CAN topics (one per DBC message), each published
    channel of the rig description (per service for ``health/<service>``), the liveliness
    topic and :data:`UNDECODABLE_TOPIC`. The live view creates these before its server
    serves a client (:mod:`workbench.live.view`)."""
    root = f"ralf/{rig_id}"
    topics: list[tuple[str, dict[str, Any]]] = [(CAN_TOPIC, CAN_SCHEMA)]
    topics += [(f"{CAN_DECODED_PREFIX}/{message.name}", decoded_schema(message)) for message in load_dbc().messages]
    for suffix, channel, _senders in RIG.expanded():
        if channel.kind != "publication":
            continue
        payload = channel.payload
        schema = BATCH_SCHEMA if payload == "batch" else TF_SCHEMA if payload == "tf" else schema_of(payload) if isinstance(payload, type) else None
        if schema is not None:
            topics.append((topic_for_key(f"{root}/{suffix}"), schema))
    topics += [(topic_for_key(f"{root}/alive"), LIVELINESS_SCHEMA), (UNDECODABLE_TOPIC, RAW_SCHEMA)]
    return topics


# --- CAN direction and names -------------------------------------------------------------


def frame_name(arbitration_id: int, node_id: int = can_map.DEFAULT_NODE_ID) -> str:
    """The CANopen name of a COB-ID on this rig (``other`` if not in the map)."""
    for name, cob in can_map.cob_ids(node_id).items():
        if cob == arbitration_id:
            return name
    return "other"


_TO_PLANT_FRAMES: Final[frozenset[str]] = frozenset({"nmt", "sync", "rpdo1", "sdo_rx"})
_TO_CONTROLLER_FRAMES: Final[frozenset[str]] = frozenset({"emcy", "tpdo1", "tpdo2", "tpdo3", "sdo_tx", "heartbeat"})


def direction_of(arbitration_id: int, node_id: int = can_map.DEFAULT_NODE_ID) -> Direction | Literal["unknown"]:
    """Who sent a frame, from its COB-ID (a tap sees no sender): SYNC, RPDO,
    NMT and SDO requests go controller -> plant; TPDOs, EMCY, heartbeat and
    SDO responses plant -> controller."""
    name = frame_name(arbitration_id, node_id)
    if name in _TO_PLANT_FRAMES:
        return TO_PLANT
    if name in _TO_CONTROLLER_FRAMES:
        return TO_CONTROLLER
    return "unknown"


class SyncClock:
    """Simulated time of CAN frames from the SYNCs seen.

    The controller's tick ``k`` starts with its SYNC at simulated ``k Ts``;
    every frame after it belongs to tick ``k`` until the next SYNC. The tick
    advances by one per SYNC frame, with or without a CiA 301 counter (the
    counter is no tick count: the controller's fault injection advances it
    without a frame and still sends that tick's SYNC). Exact unless a
    lockstep SYNC was re-sent after a lost frame (one tick ahead per resend)
    or the real-time loop skipped periods (it sends no SYNC for them); the
    messages' own ``sim_time_s`` stays exact.
    """

    def __init__(self, sample_period_s: float) -> None:
        if not sample_period_s > 0:
            raise ValueError("sample period must be positive")
        self.sample_period_s = sample_period_s
        self.tick: int | None = None

    def on_frame(self, arbitration_id: int) -> int | None:
        """Advance on a SYNC; the tick the frame belongs to (None before the first SYNC)."""
        if arbitration_id == can_map.SYNC_COB_ID:
            self.tick = 0 if self.tick is None else self.tick + 1
        return self.tick

    def sim_time(self, tick: int | None) -> float | None:
        return None if tick is None else tick * self.sample_period_s
