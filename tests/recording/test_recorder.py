"""The recorder on its own: fed directly (as a one-thread co-simulation
would), read back with the mcap library, checked with jsonschema, cantools
and python-can's own readers."""

from __future__ import annotations

import json
from pathlib import Path

import can
import cantools
import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from protocol import can_map
from protocol.batch_codec import SampleBatch, encode_batch
from protocol.keys import Keys
from protocol.messages import GroundTruth, Health, Interrupt, PoleParameters, encode
from workbench.recording import schemas
from workbench.recording.reader import Recording
from workbench.recording.recorder import Recorder

DBC = Path(__file__).resolve().parents[2] / "protocol" / "ralf.dbc"
KEYS = Keys("unit")
N_RECORDS = 12 + 11 + 6
"""12 frames, 11 of them decoded by the DBC (not the SYNC without counter), 6 zenoh records."""


def _frames() -> list[tuple[int, bytes]]:
    """A start-up and three ticks, as the controller and the plant send them."""
    out = [
        (0x701, can_map.encode_heartbeat(can_map.NmtState.PRE_OPERATIONAL)),
        (0x000, can_map.encode_nmt(can_map.NmtCommand.START, 1)),
    ]
    for tick in range(3):
        out.append((0x080, can_map.encode_sync(tick + 1)))
        out.append((0x181, can_map.encode_analog_inputs_16(np.array([100, -200, 300 + tick, -400]) << 4)))
        out.append((0x201, can_map.volts_to_output_frame([0.5 * tick, -1.0])[0]))
    out.append((0x080, b""))  # a SYNC without counter (CiA 301 allows it)
    return out


def _batch(seq: int = 0, n: int = 30) -> SampleBatch:
    rng = np.random.default_rng(seq)
    return SampleBatch(
        seq=seq,
        first_tick=seq * n,
        sample_rate_hz=200.0,
        sim_time_s=seq * n / 200.0,
        wall_time_s=1.7e9 + seq,
        inputs=rng.standard_normal((2, n)),
        outputs=rng.standard_normal((2, n)) * 1e-3,
    )


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, Path]:
    path = tmp_path / "unit.mcap"
    blf = tmp_path / "unit.blf"
    rec = Recorder(path, can_log=blf)
    rec.add_metadata("ralf.run", {"rig_id": "unit", "seed": 7})
    for i, (cob, data) in enumerate(_frames()):
        rec.on_can_frame(cob, data, wall_time_s=1000.0 + i * 0.001)
    rec.on_message(KEYS.batch, encode_batch(_batch(0)), wall_time_s=1001.0)
    irq = Interrupt(seq=0, sim_time_s=0.15, batch_seq=0, poles=(PoleParameters(frequency_hz=4.4, damping_ratio=0.09),), confidence=0.5, compute_time_s=1e-3)
    rec.on_message(KEYS.interrupt, encode(irq), wall_time_s=1001.1)
    truth = GroundTruth(
        seq=0,
        sim_time_s=0.1,
        modal_frequencies_hz=(4.4, 9.1),
        damping_ratios=(0.09, 0.09),
        deflections_in=(0.1, -0.2),
        theta_rad=(1.0, 0.5),
        tip_in=(40.0, 30.0),
        payload_attached=False,
    )
    rec.on_message(KEYS.truth, encode(truth), wall_time_s=1001.2)
    rec.on_message(KEYS.health("dsp"), encode(Health(seq=0, sim_time_s=0.0, service="dsp")), wall_time_s=1001.3)
    rec.on_message(KEYS.interrupt, b'{"seq": "not a number"}', wall_time_s=1001.4)
    rec.on_liveliness(KEYS.alive("dsp"), True, wall_time_s=1000.5)
    stats = rec.close()
    assert stats.dropped == 0
    assert stats.undecodable == 1
    return path, blf


def test_mcap_reader_reads_every_channel_with_its_schema(recording: tuple[Path, Path]) -> None:
    path, _ = recording
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = {ch.topic for ch in summary.channels.values()}
        assert {
            "/can",
            "/ralf/unit/dsp/batch",
            "/ralf/unit/dsp/interrupt",
            "/ralf/unit/plant/truth",
            "/ralf/unit/health/dsp",
            "/ralf/unit/alive",
            "/_undecodable",
        } <= topics
        seen = 0
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "json"
            assert schema is not None and schema.encoding == "jsonschema"
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            seen += 1
        assert seen == summary.statistics.message_count == N_RECORDS
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert meta["ralf.run"]["seed"] == "7"
    assert meta["ralf.recorder"]["can_frames"] == str(len(_frames()))


def test_a_wrong_message_fails_its_channel_schema(recording: tuple[Path, Path]) -> None:
    """The schemas are not vacuous: a truth record with a missing field does not validate."""
    path, _ = recording
    rec = Recording.load(path)
    truth = rec.data("plant/truth")[0]
    schema = schemas.schema_of(GroundTruth)
    jsonschema.validate(truth, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({k: v for k, v in truth.items() if k != "theta_rad"}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**rec.can_frames()[0], "direction": "sideways"}, schemas.CAN_SCHEMA)


def test_batches_round_trip_bit_for_bit(recording: tuple[Path, Path]) -> None:
    rec = Recording.load(recording[0])
    (b,) = rec.data("dsp/batch")
    original = _batch(0)
    assert np.array_equal(np.asarray(b["inputs"]), original.inputs)
    assert np.array_equal(np.asarray(b["outputs"]), original.outputs)
    assert b["sim_time_s"] == original.sim_time_s and b["first_tick"] == 0 and b["n_samples"] == 30


def test_can_direction_names_and_sim_time(recording: tuple[Path, Path]) -> None:
    frames = Recording.load(recording[0]).can_frames()
    by = [(f["frame"], f["direction"], f["tick"]) for f in frames]
    assert by[:2] == [("heartbeat", "plant->controller", None), ("nmt", "controller->plant", None)]
    assert by[2:5] == [("sync", "controller->plant", 0), ("tpdo1", "plant->controller", 0), ("rpdo1", "controller->plant", 0)]
    assert [f["sim_time_s"] for f in frames if f["frame"] == "sync"] == [0.0, 0.005, 0.010, 0.015]  # the counter-less SYNC counts too
    assert {f["frame"]: f["direction"] for f in frames} == {
        "heartbeat": "plant->controller",
        "nmt": "controller->plant",
        "sync": "controller->plant",
        "tpdo1": "plant->controller",
        "rpdo1": "controller->plant",
    }


def test_directions_of_every_canopen_frame() -> None:
    ids = can_map.cob_ids(1)
    to_plant = {n for n, cob in ids.items() if schemas.direction_of(cob) == schemas.TO_PLANT}
    assert to_plant == {"nmt", "sync", "rpdo1", "sdo_rx"}
    assert {n for n, cob in ids.items() if schemas.direction_of(cob) == schemas.TO_CONTROLLER} == {"emcy", "tpdo1", "tpdo2", "tpdo3", "sdo_tx", "heartbeat"}
    assert schemas.direction_of(0x123) == "unknown"


def test_cantools_decodes_the_recorded_frames(recording: tuple[Path, Path]) -> None:
    db = cantools.database.load_file(str(DBC))
    frames = [f for f in Recording.load(recording[0]).can_frames() if f["dlc"]]
    tpdo_volts = []
    for f in frames:
        decoded = db.decode_message(f["arbitration_id"], bytes(f["data"]))
        if f["frame"] == "tpdo1":
            tpdo_volts.append(decoded["AI3"])
    # AI3 carried the 12-bit code 300 + tick, left-justified: volts = code * 20 V / 4096
    assert tpdo_volts == pytest.approx([(300 + t) * 20.0 / 4096 for t in range(3)])


def test_decoded_channels_carry_the_dbc_signals(recording: tuple[Path, Path]) -> None:
    rec = Recording.load(recording[0])
    tpdo = [m.data for m in rec.messages if m.topic == "/can/decoded/TPDO1_AnalogInputs16"]
    assert [d["AI3"] for d in tpdo] == pytest.approx([(300 + t) * 20.0 / 4096 for t in range(3)])
    assert [d["tick"] for d in tpdo] == [0, 1, 2]
    syncs = [m.data["SYNC_Counter"] for m in rec.messages if m.topic == "/can/decoded/SYNC"]
    assert syncs == [1, 2, 3]  # the counter-less SYNC has no signal to decode


def test_blf_side_log_reads_back_with_python_can(recording: tuple[Path, Path]) -> None:
    _, blf = recording
    read = list(can.BLFReader(str(blf)))
    assert [(m.arbitration_id, bytes(m.data)) for m in read] == [(cob, data) for cob, data in _frames()]
    assert [m.is_rx for m in read][:3] == [True, False, False]  # heartbeat from the plant; NMT, SYNC to it


def test_a_full_queue_drops_and_counts_never_blocks(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "q.mcap", queue_limit=3, autostart=False)  # a writer that has not caught up
    for i in range(10):
        rec.on_can_frame(0x080, b"\x01", wall_time_s=float(i))
    assert rec.stats.dropped == 7
    stats = rec.close()
    assert stats.can_frames == 3
    assert len(Recording.load(tmp_path / "q.mcap").can_frames()) == 3


def test_seeking_and_streaming_readers_agree_with_crcs_checked(recording: tuple[Path, Path]) -> None:
    """The summary and chunk indexes (what ``mcap info``/seeking readers use) and a plain
    front-to-back stream (what ``mcap cat`` does) give the same messages; CRCs validate."""
    from mcap.reader import NonSeekingReader, SeekingReader

    path, _ = recording
    with open(path, "rb") as f:
        seeking = [(c.topic, m.log_time, m.data) for _, c, m in SeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False)]
    with open(path, "rb") as f:
        streaming = [(c.topic, m.log_time, m.data) for _, c, m in NonSeekingReader(f, validate_crcs=True).iter_messages()]
    assert sorted(seeking) == sorted(streaming) and len(streaming) == N_RECORDS


def test_tf_snapshots_are_recorded_as_typed_arrays_and_bad_ones_kept_aside(tmp_path: Path) -> None:
    """controller/tf travels binary (protocol.tf_codec); the recording holds it
    decoded, bit for bit, validated by its schema; a malformed one goes to
    /_undecodable, counted."""
    from protocol.messages import TfSnapshot, TransferFunction
    from protocol.tf_codec import encode_tf

    rng = np.random.default_rng(3)
    snap = TfSnapshot(
        seq=2,
        sim_time_s=5.0,
        wall_time_s=1.7e9,
        batch_seq=24,
        freqs_hz=np.arange(9) * 0.5,
        valid=rng.random(9) > 0.5,
        estimates={name: TransferFunction(rng.random(9) * 1e3, rng.uniform(-np.pi, np.pi, 9)) for name in ("H11", "Htot")},
    )
    payload = encode_tf(snap)
    path = tmp_path / "tf.mcap"
    rec = Recorder(path, decode_can=False)
    rec.on_message(KEYS.tf_downloads, payload, wall_time_s=1001.0, encoding="application/octet-stream;ralf-tf-v1")
    rec.on_message(KEYS.tf_downloads, payload[:-1], wall_time_s=1001.5)
    stats = rec.close()
    assert (stats.messages, stats.undecodable) == (1, 1)
    back = Recording.load(path)
    (row,) = back.tf_downloads()
    jsonschema.validate(row, schemas.TF_SCHEMA)
    assert row == json.loads(json.dumps(snap.as_json()))
    for name, tf in snap.estimates.items():
        assert np.array_equal(np.array(row["estimates"][name]["magnitude"]).view(np.uint64), tf.magnitude.view(np.uint64))
    assert back.topics()["/_undecodable"] == 1
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**row, "estimates": {"H33": row["estimates"]["H11"]}}, schemas.TF_SCHEMA)
