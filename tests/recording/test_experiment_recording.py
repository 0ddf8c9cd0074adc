"""``ralf-hil experiment NAME --record``: each rig run of an experiment (co-simulated or
three-process) is recorded into ``records/<run>.mcap`` beside its npz records."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from workbench.campaign.rigs import in_context
from workbench.experiments.framework import ExperimentContext
from workbench.hil import HilRig, RigSpec
from workbench.recording.reader import Recording


@pytest.mark.timeout(180)
def test_an_experiments_three_process_run_is_recorded(tmp_path: Path) -> None:
    ctx = ExperimentContext(out_dir=tmp_path, mode="lockstep", quick=True, show_progress=False, record=True)
    spec = RigSpec("rec", controller={"duration_s": 2.0, "batch_size": 20}, dsp={"batch_size": 20, "fft_width": 256})
    res = HilRig.from_spec(in_context(ctx, spec, False)).run()
    rec = Recording.load(tmp_path / "records" / "rec.mcap")
    syncs = [f for f in rec.can_frames() if f["frame"] == "sync"]
    assert len(syncs) >= len(res.t_s) == 400  # every tick's SYNC (lockstep may re-send one)
    truth = rec.truth()
    assert truth["sim_time_s"][-1] > 1.9
    # the recorded truth is the plant's, as its own npz record holds it
    n = min(len(truth["sim_time_s"]), len(res.truth_columns["sim_time_s"]))
    assert (truth["modal_frequencies_hz"][:n] == res.truth_columns["modal_frequencies_hz"][:n]).all()
    assert rec.metadata["ralf.run"]["run"] == "rec"
    assert rec.settings("dsp")["fft_width"] == 256


def test_a_cosimulated_run_is_recorded_too(tmp_path: Path) -> None:
    ctx = ExperimentContext(out_dir=tmp_path, mode="cosim", quick=True, show_progress=False, record=True)
    spec = RigSpec("co", controller={"duration_s": 0.5, "batch_size": 20}, dsp={"batch_size": 20, "fft_width": 256})
    res = HilRig.from_spec(in_context(ctx, spec, True)).run()
    assert len(res.t_s) == 100
    rec = Recording.load(tmp_path / "records" / "co.mcap")
    syncs = [f for f in rec.can_frames() if f["frame"] == "sync"]
    assert len(syncs) == len(res.t_s)  # one SYNC per tick: a co-simulation never re-sends
    assert rec.metadata["ralf.run"]["run"] == "co" and rec.metadata["ralf.run"]["clock"] == "cosim"


def test_the_spec_sent_to_the_worker_carries_the_recording(tmp_path: Path) -> None:
    """--record asks every co-simulated and three-process run for its MCAP; a one-process run (--quick on the rig) is not recorded."""
    spec = RigSpec("x", controller={"duration_s": 0.5})
    for mode, in_process, recorded in (("cosim", True, True), ("lockstep", False, True), ("lockstep", True, False)):
        ctx = ExperimentContext(out_dir=tmp_path, mode=mode, quick=True, show_progress=False, record=True)  # type: ignore[arg-type]
        placed = in_context(ctx, spec, in_process)
        assert placed.mcap is recorded and placed.outputs == tmp_path.resolve() / "records"
        assert HilRig.from_spec(placed).mcap is recorded


def test_service_kit_imports_no_rig_module() -> None:
    code = "import sys, service_kit.runtime, controller.service, dsp_service.service, plant_emulator.service; print(sorted(m for m in sys.modules if m == 'workbench' or m.startswith('workbench.')))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "[]"
