"""The experiments' fan-out: independent :class:`~workbench.experiments.onrig.runner.RigRun` on the campaign engine.

:func:`map_rigs` replaces the experiments' former thread pool: every run
becomes one task of :func:`workbench.campaign.engine.current_engine` (the local
cluster, or the scheduler ``ralf-hil experiment --scheduler`` named), which
runs :func:`workbench.experiments.onrig.runner.run_rig` on a worker and sends the
loaded :class:`~workbench.experiments.onrig.runner.RigResult` back. The records
are written below the experiment's output directory by the worker; when
the worker is on another machine (no shared file system) the client writes
them again from the result, so the experiment finds its files either way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console

from workbench.campaign.engine import Engine, current_engine
from workbench.experiments.framework import ClockMode, Experiment, ExperimentContext, run_layout
from workbench.experiments.onrig.runner import RigResult, RigRun, RigRunError, run_rig

__all__ = ["RigJob", "map_rigs", "run_rigs"]


@dataclass(frozen=True)
class RigJob:
    """What a worker needs to run one rig for an experiment (the context rebuilt there)."""

    out_dir: str
    mode: ClockMode
    experiment: Experiment | None
    spec: RigRun
    in_process: bool
    record: bool = False
    """Record a three-process run into ``out_dir/records/<run>.mcap`` (written where the worker runs)."""


def run_rig_job(job: RigJob) -> RigResult:
    """Worker side: :func:`run_rig` in a quiet context on the experiment's output directory."""
    ctx = ExperimentContext(
        out_dir=Path(job.out_dir),
        mode=job.mode,
        show_progress=False,
        console=Console(stderr=True, quiet=True),
        experiment=job.experiment,
        record=job.record,
    )
    return run_rig(ctx, job.spec, in_process=job.in_process)


def _materialise(res: RigResult) -> None:
    """Write the result's files where it says they are, if this machine does not have them."""
    from controller.record import save_record

    if not Path(str(res.record_path) + ".npz").exists():
        res.record_path.parent.mkdir(parents=True, exist_ok=True)
        save_record(res.record_path, res.record.columns, res.record.config, res.record.metadata)
    if not res.truth_path.exists():
        res.truth_path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(res.truth_path, **res.truth)  # type: ignore[arg-type]  # numpy stubs type **kwds as allow_pickle
    tf_path = Path(str(res.record_path) + ".tf.npz")
    if res.tf is not None and not tf_path.exists():
        np.savez_compressed(tf_path, **res.tf)  # type: ignore[arg-type]


def map_rigs(
    ctx: ExperimentContext,
    specs: Sequence[RigRun],
    *,
    in_process: bool = False,
    description: str = "rig runs",
    engine: Engine | None = None,
) -> list[RigResult]:
    """Run independent rigs on the engine (each a task, as many at once as it has slots); results in
    the order of ``specs``. If runs fail the others still finish, then a :class:`RigRunError` names
    every failure (with the first one's text)."""
    if not specs:
        return []
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"run names must be unique: {names}")
    eng = engine or current_engine()
    total = sum(s.expected_sim_s() for s in specs)
    ctx.log(f"{len(specs)} run(s), {total:.0f} s simulated, " + run_layout(ctx.mode, in_process) + f", {ctx.mode}, on {eng.describe()}")
    jobs = [RigJob(str(ctx.out_dir.resolve()), ctx.mode, ctx.experiment, s, in_process, ctx.record) for s in specs]
    outcomes = eng.map(run_rig_job, jobs, keys=[f"rig-{n}" for n in names], description=description, console=ctx.console, show_progress=ctx.show_progress)
    failed = [(specs[o.index].name, o.error) for o in outcomes if not o.ok]
    if failed:
        first = failed[0][1]
        raise RigRunError(f"{len(failed)} of {len(specs)} run(s) failed ({', '.join(n for n, _ in failed)}); first: {first}")
    results = [o.value for o in outcomes]
    for r in results:
        assert r is not None
        _materialise(r)
    return [r for r in results if r is not None]


def run_rigs(
    ctx: ExperimentContext,
    specs: Sequence[RigRun],
    *,
    in_process: bool = False,
    description: str = "rig runs",
) -> list[RigResult]:
    """Run independent rigs on the campaign engine (:func:`map_rigs`: one Dask
    task per run, as many at once as the engine has workers); results in the order of ``specs``.

    If a run fails the others still finish, then a :class:`RigRunError` names the failures.
    """
    return map_rigs(ctx, specs, in_process=in_process, description=description)
