"""``ralf-hil experiment NAME --record``: the runner records each
three-process rig run into ``records/<run>.mcap`` beside its npz records."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.experiments.framework import ExperimentContext
from rig.experiments.onrig.runner import RigRun, run_rig
from rig.recording.reader import Recording


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
