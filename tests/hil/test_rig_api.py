"""The one rig API: :class:`workbench.hil.HilRig` in its three layouts, its files, its
:class:`~workbench.rig_spec.RigSpec` and the :class:`~workbench.hil.RunRecord` every run returns. The three-process runs use CAN over
``udp_multicast``: run this file inside ``.ci/loopback-netns``."""

from __future__ import annotations

import pickle
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from controller.record import load_record
from workbench.hil import HilRig, RigSettingError, RigSpec, RunRecord
from workbench.laps import lap_seconds

SHORT = {"duration_s": 2.0, "batch_size": 20, "tf_download_samples": 200}
DSP = {"batch_size": 20}
CONTROLLER_COLUMNS = ("t_s", "defl1_in", "defl2_in", "u1_v", "u2_v", "f_id_hz")


def _files_of(where: Path, name: str) -> None:
    """The files a run with outputs leaves, as the controller and plant wrote them."""
    for ending in (".npz", ".json", ".timing.npz", ".tf.npz", ".truth.npz"):
        assert (where / f"{name}{ending}").is_file(), ending


def _same_as_files(rec: RunRecord) -> None:
    """The record carries what its files hold (read back by the controller's own loader and numpy)."""
    assert rec.record_path is not None and rec.truth_path is not None
    disk = load_record(rec.record_path)
    assert list(disk.columns) == list(rec.columns)
    for name in CONTROLLER_COLUMNS:
        assert np.array_equal(disk[name], rec.columns[name], equal_nan=True)
    assert disk.metadata == rec.metadata and disk.config == rec.config
    with np.load(rec.truth_path) as truth:
        assert set(truth.files) == set(rec.truth_columns)
        assert np.array_equal(truth["modal_frequencies_hz"], rec.truth_columns["modal_frequencies_hz"])
    assert len(rec.truth) == len(rec.truth_columns["sim_time_s"])


def test_cosim_with_outputs_writes_the_experiments_files(tmp_path: Path) -> None:
    rec = HilRig(clock="cosim", name="short", label="a short run", outputs=tmp_path, controller=dict(SHORT), dsp_settings=dict(DSP)).run()
    _files_of(tmp_path, "short")
    assert not (tmp_path / "short.mcap").exists() and rec.recording is None  # not asked for
    _same_as_files(rec)
    assert rec.layout == "cosim" and rec.name == "short" and rec.label == "a short run" and rec.error is None
    assert rec.ticks == len(rec.columns["t_s"]) == 400 and rec.columns["t_s"][-1] == pytest.approx(1.995)
    assert rec.tf is not None and rec.tf["Htot_mag"].shape[0] >= 1
    assert rec.exit_codes == {"controller": 0, "plant": 0, "dsp": 0}
    facts = rec.run_facts()
    assert set(facts) == {"name", "label", "settings", "rig", "mode", "sim_time_s", "wall_time_s", "counters", "exit_codes", "record"}
    assert facts["rig"] == "co-simulation (workbench.cosim)" and facts["record"] == "short" and facts["sim_time_s"] == pytest.approx(2.0)
    assert facts["settings"]["controller"] == SHORT and facts["counters"]["batches_sent"] >= 19
    assert rec.verdict is not None and rec.verdict.level in ("PASS", "DEGRADED")
    # the truth at controller times: the plant samples a tick after the controller's time
    t = rec.t_s[:50]
    expected = np.interp(t + rec.sample_period_s, rec.truth_columns["sim_time_s"], rec.truth_columns["modal_frequencies_hz"][:, 0])
    assert np.array_equal(rec.true_mode_hz(t), expected)


def test_cosim_recorded_with_outputs_reads_its_messages_back(tmp_path: Path) -> None:
    rec = HilRig(clock="cosim", name="rec", outputs=tmp_path, mcap=True, controller=dict(SHORT), dsp_settings=dict(DSP)).run()
    assert rec.recording == tmp_path / "rec.mcap" and rec.recording.is_file()
    assert rec.interrupts and len(rec.truth) == len(rec.truth_columns["sim_time_s"])
    assert rec.recording_counts is not None


def test_one_process_lockstep_with_outputs_equals_the_cosimulation(tmp_path: Path) -> None:
    """The one-process composition in lockstep and the co-simulation give the same record, bit for bit."""
    one = HilRig(clock="lockstep", name="one", outputs=tmp_path, controller=dict(SHORT), dsp_settings=dict(DSP))
    try:
        rec = one.run()
    finally:
        one.close()
    _files_of(tmp_path, "one")
    _same_as_files(rec)
    assert rec.layout == "one process" and rec.run_facts()["rig"] == "one process (workbench.composition)"
    assert rec.interrupts and rec.truth  # live on the test port
    co = HilRig(clock="cosim", name="co", outputs=tmp_path, controller=dict(SHORT), dsp_settings=dict(DSP)).run()
    for name in CONTROLLER_COLUMNS:
        assert np.array_equal(rec.columns[name], co.columns[name], equal_nan=True), name


@pytest.mark.rig
@pytest.mark.timeout(180)
def test_three_processes_lockstep_with_outputs(tmp_path: Path) -> None:
    progress: list[float] = []
    rig = HilRig(
        clock="lockstep", processes=True, name="three", outputs=tmp_path, mcap=True, controller=dict(SHORT), dsp_settings=dict(DSP), on_progress=progress.append
    )
    rec = rig.run()
    assert rec.error is None, rec.error
    _files_of(tmp_path, "three")
    _same_as_files(rec)
    assert (tmp_path / "logs" / "three" / "controller.log").is_file() and (tmp_path / "three.mcap").is_file()
    assert rec.layout == "three processes" and rec.exit_codes == {"controller": 0, "plant": 0, "dsp": 0}
    assert rec.ticks == 400 and rec.interrupts and rec.status is not None
    assert sum(progress) == pytest.approx(2.0)
    co = HilRig(clock="cosim", name="co", outputs=tmp_path, controller=dict(SHORT), dsp_settings=dict(DSP)).run()
    for name in CONTROLLER_COLUMNS:  # the co-simulation is bit-identical to the three-process rig in lockstep
        assert np.array_equal(rec.columns[name], co.columns[name], equal_nan=True), name


@pytest.mark.rig
@pytest.mark.timeout(120)
def test_three_processes_a_failing_service_is_the_records_error_with_its_log(tmp_path: Path) -> None:
    missing = tmp_path / "missing.fmu"  # with a mapping without inputs: the plant service refuses it at its start
    (tmp_path / "map.yaml").write_text("{}\n")
    rec = HilRig(
        clock="lockstep",
        processes=True,
        name="bad",
        outputs=tmp_path,
        controller={"duration_s": 1.0},
        plant_settings={"model": f"fmu:{missing}", "fmu_mapping": str(tmp_path / "map.yaml")},
    ).run()
    assert rec.error is not None and "exit codes" in rec.error and "--- plant" in rec.error
    assert any(code != 0 for code in rec.exit_codes.values())
    assert rec.verdict is not None and rec.verdict.level in ("FAIL", "INVALID")


def test_a_spec_pickles_and_makes_its_rig(tmp_path: Path) -> None:
    spec = RigSpec("s", controller={"repeats": 1, "tip_speed_in_s": 5.0}, clock="lockstep", processes=True, outputs=tmp_path, mcap=True, label="x")
    back = pickle.loads(pickle.dumps(spec))
    assert back == spec
    assert spec.expected_sim_s() == lap_seconds(5.0)
    assert replace(spec, duration_s=3.0).expected_sim_s() == 3.0
    rig = HilRig.from_spec(back)
    assert (rig.clock, rig.processes, rig.name, rig.outputs, rig.mcap, rig.label) == ("lockstep", True, "s", tmp_path, True, "x")
    with pytest.raises(ValueError, match="repeats"):
        RigSpec("none").expected_sim_s()


def test_a_record_pickles_whole(tmp_path: Path) -> None:
    rec = HilRig(clock="cosim", name="p", outputs=tmp_path, controller={"duration_s": 0.5}).run()
    back = pickle.loads(pickle.dumps(rec))
    assert back.name == "p" and back.truth == rec.truth and back.verdict == rec.verdict
    assert all(np.array_equal(back.columns[k], rec.columns[k], equal_nan=True) for k in rec.columns)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"clock": "cosim", "processes": True}, "processes=True goes with"),
        ({"clock": "cosim", "mcap": True}, "give outputs"),
        ({"clock": "lockstep", "mcap": "x.mcap"}, "one-process run is not recorded"),
        ({"clock": "cosim", "name": "a/b"}, "file stem"),
    ],
)
def test_a_rig_refuses_what_it_cannot_do(kwargs: dict, words: str) -> None:
    with pytest.raises(RigSettingError, match=words):
        HilRig(**kwargs)


def test_a_run_without_length_is_refused_before_it_starts() -> None:
    with pytest.raises(RigSettingError, match="duration_s"):
        HilRig(clock="cosim").run()
