"""Campaigns: parameter sweeps of deterministic rig runs on Dask distributed (``ralf-hil sweep``).

* :mod:`.engine`: :class:`Engine` (a local cluster or a scheduler's address), ``map`` with
  per-task errors, progress and timings; the process's shared engine (:func:`current_engine`);
* :mod:`.spec`: the sweep spec (grid, points, seeds, base, mode), resolved against
  :mod:`protocol.settings` and keyed by a hash of the resolved settings;
* :mod:`.modes`: the run modes (``cosim`` in one thread, the default; ``lockstep`` in one process; ``onrig`` three processes),
  one registration each;
* :mod:`.metrics`: the row of one run (the §4.2.1 costs and the run's facts);
* :mod:`.table`: the journal and the tidy table (Parquet, CSV);
* :mod:`.sweep`: :func:`run_sweep`;
* :mod:`.rigs`: :func:`map_rigs`, the experiments' fan-out of :class:`~workbench.rig_spec.RigSpec` runs (:class:`~workbench.hil.HilRig`).

See docs/campaigns.md.
"""

from workbench.campaign.cli import register
from workbench.campaign.engine import Engine, EngineError, TaskOutcome, current_engine, engine_scope, use_engine
from workbench.campaign.modes import DEFAULT_MODE, get_mode, known_modes, register_mode, run_point
from workbench.campaign.spec import RunPoint, SpecError, SweepSpec, expand, load_spec
from workbench.campaign.sweep import SweepResult, run_sweep

__all__ = [
    "DEFAULT_MODE",
    "Engine",
    "EngineError",
    "RunPoint",
    "SpecError",
    "SweepResult",
    "SweepSpec",
    "TaskOutcome",
    "current_engine",
    "engine_scope",
    "expand",
    "get_mode",
    "known_modes",
    "load_spec",
    "register",
    "register_mode",
    "run_point",
    "run_sweep",
    "use_engine",
]
