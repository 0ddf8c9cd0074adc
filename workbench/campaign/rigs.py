"""The experiments' fan-out: independent :class:`~workbench.rig_spec.RigSpec` runs on the campaign engine.

:func:`map_rigs` makes every run one task of
:func:`workbench.campaign.engine.current_engine` (the local cluster, or the
scheduler ``ralf-hil experiment --scheduler`` named), which runs
``HilRig.from_spec(spec).run()`` on a worker and sends the
:class:`~workbench.hil.RunRecord` back. The records are written below the
experiment's output directory by the worker; when the worker is on another
machine (no shared file system) the client writes them again from the record,
so the experiment finds its files either way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from workbench.campaign.engine import Engine, current_engine
from workbench.experiments.framework import ExperimentContext, run_layout
from workbench.hil import HilRig, RigRunError, RunRecord
from workbench.rig_spec import RigSpec

__all__ = ["RigRunError", "in_context", "map_rigs", "run_rigs", "run_spec"]


def in_context(ctx: ExperimentContext, spec: RigSpec, in_process: bool) -> RigSpec:
    """The spec as the experiment runs it: its clock (``ctx.mode``), its layout (one process
    if ``in_process``, else three; a co-simulation either way), its files under
    ``ctx.out_dir/records`` and, with ``--record``, its recording."""
    one_process = in_process and ctx.mode != "cosim"
    return replace(
        spec,
        clock=ctx.mode,
        processes=ctx.mode != "cosim" and not in_process,
        outputs=Path(ctx.out_dir).resolve() / "records",
        mcap=ctx.record and not one_process,
        meta={"experiment": ctx.experiment.name if ctx.experiment else "exp", **spec.meta},
    )


def run_spec(spec: RigSpec) -> RunRecord:
    """Worker side: the spec's rig, run (and closed)."""
    with HilRig.from_spec(spec) as rig:
        return rig.run()


def _materialise(rec: RunRecord) -> None:
    """Write the record's files where it says they are, if this machine does not have them."""
    from controller.record import save_record

    if rec.record_path is not None and not Path(str(rec.record_path) + ".npz").exists():
        rec.record_path.parent.mkdir(parents=True, exist_ok=True)
        save_record(rec.record_path, rec.columns, rec.config, rec.metadata)
    if rec.truth_path is not None and not rec.truth_path.exists() and rec.truth_columns:
        rec.truth_path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(rec.truth_path, **rec.truth_columns)  # type: ignore[arg-type]  # numpy stubs type **kwds as allow_pickle
    if rec.record_path is not None and rec.tf is not None:
        tf_path = Path(str(rec.record_path) + ".tf.npz")
        if not tf_path.exists():
            np.savez_compressed(tf_path, **rec.tf)  # type: ignore[arg-type]


def map_rigs(
    ctx: ExperimentContext,
    specs: Sequence[RigSpec],
    *,
    in_process: bool = False,
    description: str = "rig runs",
    engine: Engine | None = None,
) -> list[RunRecord]:
    """Run independent rigs on the engine (each a task, as many at once as it has slots), each
    as the experiment runs it (:func:`in_context`); records in the order of ``specs``. If runs fail
    or end with a fault the others still finish, then a :class:`RigRunError` names every failure
    (with the first one's text)."""
    if not specs:
        return []
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"run names must be unique: {names}")
    eng = engine or current_engine()
    total = sum(s.expected_sim_s() for s in specs)
    ctx.log(f"{len(specs)} run(s), {total:.0f} s simulated, " + run_layout(ctx.mode, in_process) + f", {ctx.mode}, on {eng.describe()}")
    if ctx.record and in_process and ctx.mode != "cosim":
        ctx.log("the runs run in one process (--quick): not recorded (co-simulated and three-process runs are)")
    placed = [in_context(ctx, s, in_process) for s in specs]
    outcomes = eng.map(run_spec, placed, keys=[f"rig-{n}" for n in names], description=description, console=ctx.console, show_progress=ctx.show_progress)
    failed = [(specs[o.index].name, str(o.error)) for o in outcomes if not o.ok]
    failed += [
        (o.value.name, f"run {o.value.name!r} ({o.value.layout}) ended with a fault: {o.value.error}")
        for o in outcomes
        if o.ok and o.value is not None and o.value.error
    ]
    if failed:
        first = failed[0][1]
        raise RigRunError(f"{len(failed)} of {len(specs)} run(s) failed ({', '.join(n for n, _ in failed)}); first: {first}")
    records = [o.value for o in outcomes if o.value is not None]
    for r in records:
        _materialise(r)
    return records


def run_rigs(
    ctx: ExperimentContext,
    specs: Sequence[RigSpec],
    *,
    in_process: bool = False,
    description: str = "rig runs",
) -> list[RunRecord]:
    """Run independent rigs on the campaign engine (:func:`map_rigs`: one Dask
    task per run, as many at once as the engine has workers); records in the order of ``specs``.

    If a run fails the others still finish, then a :class:`RigRunError` names the failures.
    """
    return map_rigs(ctx, specs, in_process=in_process, description=description)
