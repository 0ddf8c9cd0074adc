"""A co-simulation recorded to MCAP and exported to MF4, read back with readers
nobody here wrote: asammdf for the channels, python-can's MF4 reader for the
CAN bus logging, asammdf's own DBC decoding against the recorded decoded
frames."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can.io.mf4  # noqa: F401 -- before asammdf (workbench/recording/mf4.py says why)
import numpy as np
import pytest

asammdf = pytest.importorskip("asammdf")

from workbench.cli import main  # noqa: E402
from workbench.cosim import run_cosim  # noqa: E402
from workbench.recording import mf4_channels  # noqa: E402
from workbench.recording.reader import Recording  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONTROLLER = {"duration_s": 4.0, "tf_download_samples": 200, "batch_size": 20}
DSP = {"fft_width": 256, "emulated_latency_s": 0.05}


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("mf4")
    mcap = tmp / "run.mcap"
    run_cosim(controller=CONTROLLER, dsp=DSP, common={"rig_id": "mf4rig"}, record=str(mcap))
    out = tmp / "run.mf4"
    assert main(["export", "--mf4", str(out), str(mcap)]) == 0
    rec = Recording.load(mcap)
    mdf = asammdf.MDF(out)
    yield {"rec": rec, "mdf": mdf, "out": out, "mcap": mcap}
    mdf.close()


def _get(mdf: Any, name: str) -> Any:
    return mdf.get(name, ignore_invalidation_bits=True)


def _topic(rec: Recording, suffix: str) -> list[dict[str, Any]]:
    rows = rec.data(suffix)
    assert rows, suffix
    return rows


def test_every_message_topic_is_a_group_with_one_sample_per_message(exported: dict[str, Any]) -> None:
    rec, mdf = exported["rec"], exported["mdf"]
    counts = rec.topics()
    checked = 0
    for topic, n in counts.items():
        schema = next(m.schema for m in rec.messages if m.topic == topic)
        if schema not in mf4_channels.FIELDS:
            continue
        seq = _get(mdf, f"{mf4_channels.group_name(topic)}.seq")
        assert len(seq.samples) == n, topic
        recorded = [m.data for m in rec.messages if m.topic == topic]
        assert seq.samples.tolist() == [r["seq"] for r in recorded], topic
        assert seq.timestamps.tolist() == [r["sim_time_s"] for r in recorded], topic
        checked += 1
    assert checked >= 8  # truth, interrupt, status, flag, config, batch, tf, health x3


def test_values_and_units_equal_the_recording(exported: dict[str, Any]) -> None:
    rec, mdf = exported["rec"], exported["mdf"]
    truth = _topic(rec, "plant/truth")
    f1 = _get(mdf, "plant.truth.modal_frequency_1")
    assert f1.unit == "Hz" and f1.samples.dtype == np.float64
    assert f1.samples.tolist() == [r["modal_frequencies_hz"][0] for r in truth]
    assert _get(mdf, "plant.truth.deflection_2").unit == "in"
    assert _get(mdf, "plant.truth.theta_1").samples.tolist() == [r["theta_rad"][0] for r in truth]
    assert _get(mdf, "plant.truth.theta_1").unit == "rad"

    interrupts = _topic(rec, "dsp/interrupt")
    compute = _get(mdf, "dsp.interrupt.compute_time")
    assert compute.unit == "s" and compute.samples.tolist() == [r["compute_time_s"] for r in interrupts]
    with_pole = [r for r in interrupts if r["poles"]]
    assert with_pole, "the run identified no mode"
    pole = _get(mdf, "dsp.interrupt.pole_1.frequency")
    assert pole.unit == "Hz"
    assert pole.samples[~pole.invalidation_bits].tolist() == [r["poles"][0]["frequency_hz"] for r in with_pole]
    assert pole.invalidation_bits.tolist() == [not r["poles"] for r in interrupts]
    assert len(mdf.get("dsp.interrupt.pole_1.frequency").samples) == len(with_pole)  # invalid samples hidden by default

    health = _topic(rec, "health/controller")
    for name, value in health[-1]["counters"].items():
        assert _get(mdf, f"health.controller.counter.{name}").samples[-1] == value, name
    assert mdf.get("health.controller.state").samples[-1] == health[-1]["state"].encode()

    batches = _topic(rec, "dsp/batch")
    out1 = _get(mdf, "dsp.batch.output_1")
    assert out1.unit == "in" and len(out1.samples) == sum(b["n_samples"] for b in batches)
    assert out1.samples.tolist() == [x for b in batches for x in b["outputs"][0]]
    assert _get(mdf, "dsp.batch.input_2").unit == "V"

    tf = _topic(rec, "controller/tf")
    n = len(tf[0]["freqs_hz"])
    mag = _get(mdf, f"controller.tf.bins_{n}.Htot.magnitude")
    rows = mag.samples[f"controller.tf.bins_{n}.Htot.magnitude"]
    assert rows.shape == (len(tf), n) and rows.tolist() == [r["estimates"]["Htot"]["magnitude"] for r in tf]

    ai = [m.data for m in rec.messages if m.topic == "/can/decoded/TPDO1_AnalogInputs16"]
    ai1 = _get(mdf, "can.TPDO1_AnalogInputs16.AI1")
    assert ai and ai1.unit == "V" and ai1.samples.tolist() == [r["AI1"] for r in ai]


def test_status_without_a_frequency_is_an_invalid_sample(exported: dict[str, Any]) -> None:
    rec, mdf = exported["rec"], exported["mdf"]
    status = _topic(rec, "controller/status")
    latest = _get(mdf, "controller.status.latest_frequency")
    nulls = [r["latest_frequency_hz"] is None for r in status]
    assert any(nulls)
    assert (latest.invalidation_bits.tolist() if latest.invalidation_bits is not None else [False] * len(status)) == nulls


def test_python_can_reads_the_can_frames_back(exported: dict[str, Any]) -> None:
    rec, mdf = exported["rec"], exported["mdf"]
    frames = [m for m in rec.messages if m.topic == "/can"]
    read = list(can.io.mf4.MF4Reader(exported["out"]))
    assert len(read) == len(frames) > 1000
    start = mdf.header.start_time.timestamp()
    assert [m.arbitration_id for m in read] == [f.data["arbitration_id"] for f in frames]
    assert [bytes(m.data) for m in read] == [bytes(f.data["data"]) for f in frames]
    assert [m.is_rx for m in read] == [f.data["direction"] != "controller->plant" for f in frames]
    assert [m.timestamp for m in read] == [start + f.data["sim_time_s"] for f in frames]
    # a co-simulation's log time is its start plus simulated time: the file's start is that start
    assert max(abs(m.timestamp - f.log_time_ns / 1e9) for m, f in zip(read, frames)) < 2e-6


def test_asammdf_decodes_the_bus_logging_with_the_dbc_like_cantools(exported: dict[str, Any]) -> None:
    rec, mdf = exported["rec"], exported["mdf"]
    decoded = mdf.extract_bus_logging(database_files={"CAN": [(str(ROOT / "protocol" / "ralf.dbc"), 0)]})
    ai2 = decoded.get("AI2")
    recorded = [m.data for m in rec.messages if m.topic == "/can/decoded/TPDO1_AnalogInputs16"]
    assert len(ai2.samples) == len(recorded) > 100
    assert np.allclose(ai2.samples, [r["AI2"] for r in recorded], rtol=0, atol=1e-12)
    assert ai2.timestamps.tolist() == [r["sim_time_s"] for r in recorded]


def test_bad_input_is_one_line_and_a_non_zero_exit(exported: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("hello")
    from mcap.writer import Writer

    empty = tmp_path / "empty.mcap"
    with open(empty, "wb") as fh:
        writer = Writer(fh)
        writer.start(profile="", library="test")
        writer.finish()
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    cases = [
        (["export", "--mf4", str(tmp_path / "o.mf4"), str(not_mcap)], "not an MCAP recording"),
        (["export", "--mf4", str(tmp_path / "o.blf"), str(exported["mcap"])], "ends in .mf4"),
        (["export", "--mf4", str(tmp_path / "o.mf4"), str(empty)], "holds no message: nothing to export"),
        (["export", "--mf4", str(tmp_path / "o.mf4"), str(tmp_path / "missing.mcap")], "no such file"),
        (["up", "--clock", "cosim", "--record", str(tmp_path / "o.mf4"), "--json", str(tmp_path / "o.mf4")], "would be written by both"),
    ]
    import os

    if os.geteuid() != 0:  # root writes anywhere
        cases.append((["export", "--mf4", str(locked / "o.mf4"), str(exported["mcap"])], "not a folder this user can write in"))
    for argv, says in cases:
        try:
            code = main(argv)
        except SystemExit as exc:  # up's refusals of clashing outputs exit here
            code = exc.code  # type: ignore[assignment]
        assert code not in (0, None), argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], (argv, err)
        assert not (tmp_path / "o.mf4").exists()


def test_every_schema_a_recording_may_hold_has_its_place() -> None:
    """Each topic the recorder writes (the rig description's, the DBC's) has channels in the
    table or a stated reason to stay out; a schema the table does not know is left out, said so."""
    from workbench.recording import schemas

    titles = {schema["title"] for _topic, schema in schemas.rig_topics("r")}
    unplaced = {t for t in titles if mf4_channels.left_out_because(t).startswith("no MF4 channels")}
    assert unplaced == set() and len(titles) > 15
    assert mf4_channels.left_out_because("ralf.Unknown") == "no MF4 channels defined for schema ralf.Unknown"
    assert mf4_channels.message_groups("/ralf/r/x", "ralf.Unknown", [{"seq": 1}], [0.0], {}) == []


def test_column_rules() -> None:
    c = mf4_channels.column("x", "", [1, None, 3])
    assert c is not None and c.values.dtype == np.int64 and c.invalid is not None and c.invalid.tolist() == [False, True, False]
    assert mf4_channels.column("x", "", [None, None]) is None
    big = mf4_channels.column("x", "", [2**63 + 5])
    assert big is not None and big.values.dtype == np.uint64 and int(big.values[0]) == 2**63 + 5
    flags = mf4_channels.column("x", "", [True, False])
    assert flags is not None and flags.values.dtype == np.uint8
    with pytest.raises(ValueError, match="not among"):
        mf4_channels.column("x", "", ["lost"], states=("empty", "full"))
    assert mf4_channels.group_name("/ralf/r/health/dsp") == "health.dsp"
    assert mf4_channels.group_name("/can/decoded/SYNC") == "can.SYNC"


def test_up_records_an_mf4_file(tmp_path: Path) -> None:
    out = tmp_path / "run.mf4"
    code = main(["up", "--clock", "cosim", "--duration", "2", "--record", str(out), "--set", "controller.tf_download_samples=200"])
    assert code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mf4"]
    frames = list(can.io.mf4.MF4Reader(out))
    assert len(frames) >= 3 * 400  # SYNC, TPDO1 and RPDO1 each of 400 ticks
    with asammdf.MDF(out) as mdf:
        assert len(mdf.get("plant.truth.seq").samples) > 0


def test_export_without_asammdf_names_the_mf4_extra(tmp_path: Path) -> None:
    import subprocess
    import sys

    from workbench.cli import MCAP_MAGIC

    mcap = tmp_path / "run.mcap"
    mcap.write_bytes(MCAP_MAGIC)
    argv = ["export", "--mf4", str(tmp_path / "o.mf4"), str(mcap)]
    code = f"import sys; sys.modules['asammdf'] = None; from workbench.cli import main; sys.exit(main({argv!r}))"
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == "ralf-hil export: needs the module 'asammdf': pip install 'ralf-hil[mf4]'"


def test_frames_before_the_first_sync_keep_their_place_on_the_time_axis(tmp_path: Path) -> None:
    """A real-time tap gives the frames before the first SYNC no simulated time: they go
    at their log time's distance before simulated time 0 (negative), in recorded order."""
    from workbench.recording.mf4 import export, time_zero
    from workbench.recording.reader import Recorded

    t0_ns = 1_800_000_000_000_000_000

    def frame(log_ns: int, cob: int, sim: float | None, direction: str) -> Recorded:
        data = {"arbitration_id": cob, "is_extended_id": False, "dlc": 1, "data": [cob & 0xFF], "direction": direction, "sim_time_s": sim}
        return Recorded("/can", "ralf.CanFrame", log_ns, log_ns, data)

    rec = Recording(tmp_path / "rt.mcap")
    rec.messages = [
        frame(t0_ns - 300_000_000, 0x000, None, "controller->plant"),  # NMT, 0.3 s before the first SYNC
        frame(t0_ns - 100_000_000, 0x701, None, "plant->controller"),
        frame(t0_ns + 1_000_000, 0x080, 0.0, "controller->plant"),  # the first SYNC, seen 1 ms late
        frame(t0_ns + 6_000_000, 0x080, 0.005, "controller->plant"),
    ]
    assert time_zero(rec) == pytest.approx(1.8e9 + 0.001, abs=1e-6)
    summary = export(rec, tmp_path / "rt.mf4")
    assert summary.can_frames == 4 and summary.channels == 0
    read = list(can.io.mf4.MF4Reader(tmp_path / "rt.mf4"))
    assert [m.arbitration_id for m in read] == [0x000, 0x701, 0x080, 0x080]
    assert [m.is_rx for m in read] == [False, True, False, False]
    expected = [1.8e9 - 0.3, 1.8e9 - 0.1, 1.8e9 + 0.001, 1.8e9 + 0.006]
    assert all(abs(m.timestamp - e) < 2e-6 for m, e in zip(read, expected)), [m.timestamp for m in read]
