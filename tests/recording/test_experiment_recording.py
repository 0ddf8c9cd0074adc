"""``ralf-hil experiment NAME --record``: the runner records each
rig run (co-simulated or three-process) into ``records/<run>.mcap`` beside its npz records."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from workbench.experiments.framework import ExperimentContext
from workbench.experiments.onrig.runner import RigRun, run_rig
from workbench.recording.reader import Recording


@pytest.mark.timeout(180)
def test_runner_records_a_three_process_run(tmp_path: Path) -> None:
    ctx = ExperimentContext(out_dir=tmp_path, mode="lockstep", quick=True, show_progress=False, record=True)
    res = run_rig(ctx, RigRun("rec", controller={"duration_s": 2.0, "batch_size": 20}, dsp={"batch_size": 20, "fft_width": 256}))
    rec = Recording.load(tmp_path / "records" / "rec.mcap")
    syncs = [f for f in rec.can_frames() if f["frame"] == "sync"]
    assert len(syncs) >= len(res.record) == 400  # every tick's SYNC (lockstep may re-send one)
    truth = rec.truth()
    assert truth["sim_time_s"][-1] > 1.9
    # the recorded truth is the plant's, as its own npz record holds it
    n = min(len(truth["sim_time_s"]), len(res.truth["sim_time_s"]))
    assert (truth["modal_frequencies_hz"][:n] == res.truth["modal_frequencies_hz"][:n]).all()
    assert rec.metadata["ralf.run"]["run"] == "rec"
    assert rec.settings("dsp")["fft_width"] == 256


def test_a_cosimulated_run_is_recorded_too(tmp_path: Path) -> None:
    ctx = ExperimentContext(out_dir=tmp_path, mode="cosim", quick=True, show_progress=False, record=True)
    res = run_rig(ctx, RigRun("co", controller={"duration_s": 0.5, "batch_size": 20}, dsp={"batch_size": 20, "fft_width": 256}))
    assert len(res.record) == 100
    rec = Recording.load(tmp_path / "records" / "co.mcap")
    syncs = [f for f in rec.can_frames() if f["frame"] == "sync"]
    assert len(syncs) == len(res.record)  # one SYNC per tick: a co-simulation never re-sends
    assert rec.metadata["ralf.run"]["run"] == "co" and rec.metadata["ralf.run"]["clock"] == "cosim"


def test_the_campaign_job_carries_record_to_the_worker(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from workbench.campaign import rigs

    seen: list[bool] = []
    monkeypatch.setattr(rigs, "run_rig", lambda ctx, spec, in_process: seen.append(ctx.record) or "ran")
    job = rigs.RigJob(str(tmp_path), "lockstep", None, RigRun("x", controller={"duration_s": 0.5}), False, True)
    assert rigs.run_rig_job(job) == "ran" and seen == [True]


def test_service_kit_imports_no_rig_module() -> None:
    code = "import sys, service_kit.runtime, controller.service, dsp_service.service, plant_emulator.service; print(sorted(m for m in sys.modules if m == 'workbench' or m.startswith('workbench.')))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "[]"
