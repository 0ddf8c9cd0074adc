"""An experiment's rig runs on the campaign engine: :func:`workbench.campaign.rigs.map_rigs` sends
:class:`~workbench.rig_spec.RigSpec` s to Dask workers, each runs its :class:`~workbench.hil.HilRig`,
and the :class:`~workbench.hil.RunRecord` s come back in order with their files in place."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from controller.record import load_record
from workbench.campaign.engine import Engine
from workbench.campaign.rigs import _materialise, map_rigs
from workbench.experiments.framework import ExperimentContext
from workbench.hil import HilRig, RigRunError, RigSpec, RunRecord


def _ctx(out: Path) -> ExperimentContext:
    return ExperimentContext(out_dir=out, quick=True, show_progress=False, console=Console(stderr=True, quiet=True))


@pytest.mark.timeout(300)
def test_map_rigs_on_a_local_engine_returns_run_records(tmp_path: Path) -> None:
    specs = [RigSpec(f"seed{s}", controller={"duration_s": 0.5}, plant={"seed": s}, label=f"seed {s}") for s in (1, 2)]
    with Engine.local(1) as engine:
        records = map_rigs(_ctx(tmp_path), specs, engine=engine)
    assert [type(r) for r in records] == [RunRecord, RunRecord] and [r.name for r in records] == ["seed1", "seed2"]
    for r, spec in zip(records, specs):
        assert r.layout == "cosim" and r.label == spec.label and r.settings["plant"] == {"seed": spec.plant["seed"]}
        assert r.record_path == tmp_path.resolve() / "records" / spec.name
        assert np.array_equal(load_record(r.record_path)["defl1_in"], r.columns["defl1_in"], equal_nan=True)
        assert (tmp_path / "records" / f"{spec.name}.truth.npz").is_file()
    # the same run here, in this process, gives the same record: the worker ran the spec as given
    here = HilRig.from_spec(RigSpec("here", controller={"duration_s": 0.5}, plant={"seed": 1}, outputs=tmp_path)).run()
    assert np.array_equal(here.columns["defl1_in"], records[0].columns["defl1_in"], equal_nan=True)
    assert not np.array_equal(records[0].columns["defl1_in"], records[1].columns["defl1_in"], equal_nan=True)  # another seed


@pytest.mark.timeout(300)
def test_map_rigs_names_the_run_that_failed_and_finishes_the_others(tmp_path: Path) -> None:
    (tmp_path / "map.yaml").write_text("{}\n")
    # an FMU mapping without inputs: refused as the run starts
    bad_plant = {"model": f"fmu:{tmp_path / 'missing.fmu'}", "fmu_mapping": str(tmp_path / "map.yaml")}
    specs = [RigSpec("bad", controller={"duration_s": 0.3}, plant=bad_plant), RigSpec("good", controller={"duration_s": 0.3})]
    with Engine.local(1) as engine, pytest.raises(RigRunError) as err:
        map_rigs(_ctx(tmp_path / "out"), specs, engine=engine)
    assert "1 of 2 run(s) failed (bad)" in str(err.value) and "map.yaml" in str(err.value)
    assert (tmp_path / "out" / "records" / "good.npz").is_file()  # the other run finished


def test_materialise_writes_the_files_a_remote_worker_kept(tmp_path: Path) -> None:
    rec = HilRig(clock="cosim", name="m", outputs=tmp_path / "worker", controller={"duration_s": 0.5, "tf_download_samples": 50}).run()
    moved = tmp_path / "client"
    rec.record_path, rec.truth_path = moved / "m", moved / "m.truth.npz"  # where the client expects them
    _materialise(rec)
    back = load_record(moved / "m")
    assert back.metadata == rec.metadata and np.array_equal(back["t_s"], rec.columns["t_s"])
    with np.load(moved / "m.truth.npz") as truth:
        assert np.array_equal(truth["theta_rad"], rec.truth_columns["theta_rad"])
    assert rec.tf is not None and (moved / "m.tf.npz").is_file()
