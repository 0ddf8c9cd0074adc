"""``ralf-hil experiment``: reproduce the thesis's figures and experiments as Markdown reports.

Framework (see ``docs/experiments.md``):

* :func:`experiment` registers ``run(ctx) -> Report`` under a name, the
  thesis section and a one-line description (``needs_rig=True`` for
  experiments that start the rig);
* :class:`ExperimentContext` gives it the output directory, seed
  (:meth:`~ExperimentContext.rng` for named, reproducible streams), clock mode,
  ``quick`` flag and rich progress bars (:meth:`~ExperimentContext.progress`);
* :class:`Report` collects Markdown, PNG figures, ``results.json`` numbers,
  pass/fail checks and the comparison with the thesis;
* :func:`run_experiment` / :func:`run_all` run and write them (``all`` also
  writes ``index.md``; one experiment's failure never stops the others).

Every module below this package is imported to find experiments; the
offline ones (no rig needed) are in :mod:`workbench.experiments.offline`.
"""

from workbench.experiments.cli import register
from workbench.experiments.framework import (
    ALL,
    ClockMode,
    Experiment,
    ExperimentContext,
    ExperimentError,
    RunOutcome,
    UnknownExperimentError,
    broken_modules,
    discover,
    experiment,
    get_experiment,
    list_experiments,
    run_all,
    run_experiment,
)
from workbench.experiments.report import Check, Report, fmt, new_figure

__all__ = [
    "ALL",
    "Check",
    "ClockMode",
    "Experiment",
    "ExperimentContext",
    "ExperimentError",
    "Report",
    "RunOutcome",
    "UnknownExperimentError",
    "broken_modules",
    "discover",
    "experiment",
    "fmt",
    "get_experiment",
    "list_experiments",
    "new_figure",
    "register",
    "run_all",
    "run_experiment",
]
