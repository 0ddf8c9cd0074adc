"""The experiment registry, the run context and the runners (``run_experiment``, ``run_all``).

An *experiment* is a function ``run(ctx) -> Report`` registered with the
:func:`experiment` decorator under a unique name, the thesis section it
reproduces and a one-line description.  The runner gives it an
:class:`ExperimentContext` (output directory, seed, clock mode, quick flag,
progress bars, seeded random streams), writes the :class:`~workbench.experiments.report.Report`
it returns (``report.md``, figures, ``results.json``) and times it.  An
exception inside an experiment never escapes :func:`run_all`: it becomes an
``error`` outcome with its traceback in ``error.txt`` and a row in ``index.md``.

Experiments are found by importing every module below ``workbench.experiments``
(except the framework's own modules and names starting with ``_``): a new
experiment is a new module anywhere in the package, e.g.
``workbench/experiments/onrig/identification_lag.py``; no list needs editing.  A
module that fails to import is listed as *broken* (``--list`` shows it,
``all`` reports it) instead of hiding the others.
"""

from __future__ import annotations

import importlib
import pkgutil
import time
import traceback
import zlib
from collections.abc import Callable, Iterable, Iterator, Sized
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from difflib import get_close_matches
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from workbench.extras import missing_extra
from workbench.progress import activity
from workbench.service_warnings import counted_warnings

if TYPE_CHECKING:
    from workbench.experiments.report import Report

__all__ = [
    "ClockMode",
    "Experiment",
    "ExperimentContext",
    "ExperimentError",
    "RunOutcome",
    "UnknownExperimentError",
    "broken_modules",
    "discover",
    "experiment",
    "get_experiment",
    "list_experiments",
    "run_all",
    "run_experiment",
]

ClockMode = Literal["cosim", "lockstep", "realtime"]
T = TypeVar("T")

ALL = "all"
"""The pseudo-experiment that runs every registered one."""

_FRAMEWORK_MODULES = frozenset({"framework", "report", "cli", "__main__"})


class ExperimentError(Exception):
    """An experiment cannot run as asked (bad arguments, a missing prerequisite)."""


class UnknownExperimentError(ExperimentError, KeyError):
    """No experiment has that name."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


@dataclass(frozen=True)
class Experiment:
    """A registered experiment."""

    name: str
    """Command-line name, e.g. ``oatf-response`` (lower case, digits and dashes)."""
    section: str
    """The thesis section/figures it reproduces, e.g. ``§3.3, Figs. 3.7-3.8``."""
    description: str
    """One line for ``--list`` and the index."""
    run: Callable[[ExperimentContext], Report]
    needs_rig: bool = False
    """True if it starts the rig (plant, controller, DSP); ``--mode`` matters only then."""
    module: str = ""


_REGISTRY: dict[str, Experiment] = {}
_BROKEN: dict[str, str] = {}
_DISCOVERED = False


def experiment(
    name: str, *, section: str, description: str, needs_rig: bool = False
) -> Callable[[Callable[[ExperimentContext], Report]], Callable[[ExperimentContext], Report]]:
    """Register ``run(ctx) -> Report`` as an experiment (decorator; returns the function unchanged).

    ::

        @experiment("fwhm-error", section="App. B, Fig. B.1", description="...")
        def run(ctx: ExperimentContext) -> Report:
            rep = ctx.report("FWHM approximation error")
            ...
            return rep
    """
    if not name or name == ALL or not all(c.isalnum() or c == "-" for c in name) or name != name.lower():
        raise ValueError(f"bad experiment name {name!r}: lower-case letters, digits and dashes, not {ALL!r}")
    if "\n" in description:
        raise ValueError("the description is one line")

    def deco(func: Callable[[ExperimentContext], Report]) -> Callable[[ExperimentContext], Report]:
        old = _REGISTRY.get(name)
        if old is not None and (old.module, old.run.__qualname__) != (func.__module__, func.__qualname__):
            raise ValueError(f"experiment {name!r} is already registered by {old.module}")
        _REGISTRY[name] = Experiment(name, section, description, func, needs_rig, func.__module__)
        return func

    return deco


def discover(force: bool = False) -> None:
    """Import every experiment module below ``workbench.experiments`` (once); import errors are kept as broken."""
    global _DISCOVERED
    if _DISCOVERED and not force:
        return
    package = __name__.rpartition(".")[0]  # this module's package, found without importing it
    for info in pkgutil.walk_packages([str(Path(__file__).parent)], prefix=package + ".", onerror=lambda n: None):
        leaf = info.name.rsplit(".", 1)[-1]
        if leaf.startswith("_") or leaf in _FRAMEWORK_MODULES:
            continue
        try:
            importlib.import_module(info.name)
        except Exception as exc:  # noqa: BLE001 - a broken module must not hide the others
            _BROKEN[info.name] = f"{type(exc).__name__}: {exc}"
        else:
            _BROKEN.pop(info.name, None)
    _DISCOVERED = True


def list_experiments() -> list[Experiment]:
    """Every registered experiment, sorted by name."""
    discover()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def broken_modules() -> dict[str, str]:
    """Experiment modules that failed to import: module name -> error."""
    discover()
    return dict(_BROKEN)


def get_experiment(name: str) -> Experiment:
    """The experiment called ``name``; :class:`UnknownExperimentError` names the known ones otherwise."""
    discover()
    try:
        return _REGISTRY[name]
    except KeyError:
        known = sorted(_REGISTRY)
        close = get_close_matches(name, known + [ALL], n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UnknownExperimentError(f"unknown experiment {name!r}{hint}; known: {', '.join(known + [ALL])} (see --list)") from None


# --------------------------------------------------------------------------- context


def run_layout(mode: str, in_process: bool, *, parallel: str = "") -> str:
    """How an experiment's runs were executed, for its report: a co-simulated
    run is one thread, whatever the quick flag says about on-rig runs."""
    if mode == "cosim":
        text = "co-simulated, one thread each (workbench.cosim)"
    else:
        text = "one process each (workbench.composition)" if in_process else "three processes each (workbench.launcher)"
    return text + (f", {parallel}" if parallel else "")


@dataclass
class ExperimentContext:
    """What an experiment gets from the runner."""

    out_dir: Path
    """Where its files go (created); the report is ``out_dir / 'report.md'``."""
    seed: int = 0
    """Base seed: use :meth:`rng` for random numbers, never the global numpy state."""
    mode: ClockMode = "cosim"
    """Clock mode for experiments that start the rig: ``cosim`` (the one-thread co-simulation,
    :mod:`workbench.cosim`), ``lockstep`` or ``realtime`` (the three-process rig, ``ralf-hil up --clock``)."""
    quick: bool = False
    """Shorten what can be shortened (fewer points, draws, a shorter trajectory): seconds, not minutes."""
    console: Console = field(default_factory=lambda: Console(stderr=True))
    show_progress: bool = True
    """Draw rich progress bars (only on a terminal)."""
    experiment: Experiment | None = None
    record: bool = False
    """Record every rig run (co-simulated or three-process) into ``records/<run>.mcap`` (:mod:`workbench.recording`)."""
    step: str = ""
    """What :meth:`progress` or :meth:`progress_task` is counting now (``noise draws 3/10``), for a log's progress line."""

    def doing(self) -> str:
        """The experiment and its current step, for the progress line of a log (:mod:`workbench.progress`)."""
        name = f"experiment {self.experiment.name}" if self.experiment else "experiment"
        return f"{name}: {self.step}" if self.step else name

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)

    # -- randomness ---------------------------------------------------------------------
    def rng(self, stream: str = "") -> np.random.Generator:
        """A generator seeded by ``(seed, crc32(stream))``: independent, reproducible streams by name."""
        return np.random.default_rng([int(self.seed), zlib.crc32(stream.encode("utf-8"))])

    # -- files ----------------------------------------------------------------------------
    def path(self, name: str) -> Path:
        """A file inside :attr:`out_dir` (its parent directories created)."""
        p = self.out_dir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def report(self, title: str) -> Report:
        """A :class:`~workbench.experiments.report.Report` writing into :attr:`out_dir`."""
        from workbench.experiments.report import Report

        exp = self.experiment
        return Report(
            self.out_dir,
            title=title,
            name=exp.name if exp else "",
            section=exp.section if exp else "",
            description=exp.description if exp else "",
        )

    # -- console ----------------------------------------------------------------------------
    def log(self, message: str) -> None:
        """A line on stderr, prefixed with the experiment's name."""
        prefix = f"[{self.experiment.name}] " if self.experiment else ""
        self.console.print(f"{prefix}{message}", highlight=False)

    def _progress(self) -> Progress:
        return Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=self.console,
            transient=True,
            disable=not (self.show_progress and self.console.is_terminal),
        )

    def progress(self, items: Iterable[T], description: str = "", total: int | None = None) -> Iterator[T]:
        """Iterate ``items`` under a rich progress bar (``for x in ctx.progress(xs, "noise draws")``)."""
        if total is None and isinstance(items, Sized):
            total = len(items)
        with self._progress() as prog:
            task = prog.add_task(description or "working", total=total)
            for done, item in enumerate(items):
                self.step = f"{description or 'working'} {done}/{total if total is not None else '?'}"
                yield item
                prog.advance(task)
            self.step = ""

    @contextmanager
    def progress_task(self, description: str, total: float | None = None) -> Iterator[Callable[[float], None]]:
        """A bar advanced by hand: ``with ctx.progress_task("ticks", n) as advance: ... advance(1)``."""
        with self._progress() as prog:
            task = prog.add_task(description, total=total)
            done = [0.0]

            def advance(step: float = 1.0) -> None:
                prog.advance(task, step)
                done[0] += step
                self.step = f"{description} {done[0]:g}/{total if total is not None else '?'}"

            self.step = f"{description} 0/{total if total is not None else '?'}"
            try:
                yield advance
            finally:
                self.step = ""


# --------------------------------------------------------------------------- runners


MIN_CHECKS = 1
"""Checks an experiment must make to be ``ok`` (none: ``checks failed``, 0/0)."""


@dataclass
class RunOutcome:
    """What :func:`run_experiment` did."""

    name: str
    status: Literal["ok", "checks failed", "error"]
    out_dir: Path
    runtime_s: float
    report_path: Path | None = None
    results_path: Path | None = None
    checks_passed: int = 0
    checks_total: int = 0
    error: str = ""
    section: str = ""
    description: str = ""
    missing_extra: bool = False
    """The error is an extra the install left out (``error`` names it)."""
    warnings: str = ""
    """The rig's warnings during the runs by kind (``stale ×3, deadline ×1``), counted in the report; '' when none."""

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def results(self) -> dict[str, Any]:
        """The parsed ``results.json`` (empty if none was written)."""
        import json

        if self.results_path is None or not self.results_path.exists():
            return {}
        return json.loads(self.results_path.read_text(encoding="utf-8"))


def run_experiment(
    name: str,
    out_dir: str | Path,
    *,
    seed: int = 0,
    mode: ClockMode = "cosim",
    quick: bool = False,
    console: Console | None = None,
    show_progress: bool = True,
    raise_errors: bool = False,
    record: bool = False,
) -> RunOutcome:
    """Run one experiment into ``out_dir`` and write its report.

    An unknown ``name`` raises :class:`UnknownExperimentError`.  An exception
    inside the experiment gives ``status='error'`` (traceback in
    ``out_dir/error.txt``) unless ``raise_errors``.
    """
    if mode not in ("cosim", "lockstep", "realtime"):
        raise ExperimentError(f"mode must be 'cosim', 'lockstep' or 'realtime', got {mode!r}")
    exp = get_experiment(name)
    out = Path(out_dir)
    ctx = ExperimentContext(
        out_dir=out,
        seed=seed,
        mode=mode,
        quick=quick,
        console=console or Console(stderr=True),
        show_progress=show_progress,
        experiment=exp,
        record=record,
    )
    started = time.perf_counter()
    error_file = out / "error.txt"
    if error_file.exists():
        error_file.unlink()
    try:
        with activity(ctx.doing), counted_warnings() as warned:
            report = exp.run(ctx)
        runtime = time.perf_counter() - started
        report.service_warnings = warned.as_dict()
        report.set_meta(
            experiment=exp.name,
            section=exp.section,
            description=exp.description,
            seed=seed,
            mode=mode,
            quick=quick,
            needs_rig=exp.needs_rig,
            runtime_s=round(runtime, 3),
            finished_utc=datetime.now(UTC).isoformat(timespec="seconds"),
        )
        report_path, results_path = report.write()
    except Exception as exc:
        if raise_errors:
            raise
        runtime = time.perf_counter() - started
        needs = missing_extra(exc)
        if needs is not None:  # the install left an extra out: said in one line, no traceback file
            return RunOutcome(exp.name, "error", out, runtime, error=needs, section=exp.section, description=exp.description, missing_extra=True)
        error_file.write_text(traceback.format_exc(), encoding="utf-8")
        return RunOutcome(
            exp.name,
            "error",
            out,
            runtime,
            error=f"{type(exc).__name__}: {exc}",
            section=exp.section,
            description=exp.description,
        )
    passed = sum(1 for c in report.checks if c.passed)
    # An experiment that checked nothing has not passed: at least one check.
    status: Literal["ok", "checks failed"] = "ok" if passed == len(report.checks) >= MIN_CHECKS else "checks failed"
    return RunOutcome(
        exp.name,
        status,
        out,
        runtime,
        report_path,
        results_path,
        passed,
        len(report.checks),
        section=exp.section,
        description=exp.description,
        warnings=warned.line(),
    )


def run_all(
    out_dir: str | Path,
    *,
    seed: int = 0,
    mode: ClockMode = "cosim",
    quick: bool = False,
    names: Iterable[str] | None = None,
    console: Console | None = None,
    show_progress: bool = True,
    record: bool = False,
) -> tuple[list[RunOutcome], Path]:
    """Run every registered experiment (or ``names``) into ``out_dir/<name>/`` and write ``out_dir/index.md``.

    Never raises because of one experiment: failures are outcomes, and
    modules that failed to import are listed in the index.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console = console or Console(stderr=True)
    chosen = [get_experiment(n) for n in names] if names is not None else list_experiments()
    outcomes = []
    for exp in chosen:
        console.print(f"[bold]experiment {exp.name}[/bold] ({exp.section})", highlight=False)
        outcome = run_experiment(exp.name, out / exp.name, seed=seed, mode=mode, quick=quick, console=console, show_progress=show_progress, record=record)
        warned = f"; the rig's warnings, in the report: {outcome.warnings}" if outcome.warnings else ""
        console.print(f"  {outcome.status} in {outcome.runtime_s:.1f} s" + (f": {outcome.error}" if outcome.error else "") + warned, highlight=False)
        outcomes.append(outcome)
    index = write_index(out, outcomes, broken_modules(), seed=seed, mode=mode, quick=quick)
    return outcomes, index


def write_index(out_dir: Path, outcomes: list[RunOutcome], broken: dict[str, str], *, seed: int, mode: str, quick: bool) -> Path:
    """``index.md`` (and ``index.json``) linking every report, with status and runtime."""
    import json

    lines = [
        "# ralf-hil experiments",
        "",
        f"Seed {seed}, mode {mode}, {'quick' if quick else 'full'} runs. {sum(o.ok for o in outcomes)} of {len(outcomes)} experiments ok.",
        "",
        "| experiment | thesis | status | checks | runtime (s) | report |",
        "| --- | --- | --- | --- | ---: | --- |",
    ]
    for o in outcomes:
        link = f"[report]({o.name}/report.md)" if o.report_path else f"[error]({o.name}/error.txt)"
        checks = f"{o.checks_passed}/{o.checks_total}" if o.status != "error" else "–"
        status = o.status if not o.error else f"error: {_md_escape(o.error)}"
        lines.append(f"| `{o.name}` | {o.section} | {status} | {checks} | {o.runtime_s:.1f} | {link} |")
    lines.append("")
    for o in outcomes:
        lines.append(f"- **{o.name}**: {o.description}")
    if broken:
        lines += ["", "## Experiment modules that failed to import", ""]
        lines += [f"- `{mod}`: {_md_escape(err)}" for mod, err in sorted(broken.items())]
    path = out_dir / "index.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    (out_dir / "index.json").write_text(
        json.dumps(
            {
                "seed": seed,
                "mode": mode,
                "quick": quick,
                "experiments": [
                    {
                        "name": o.name,
                        "section": o.section,
                        "status": o.status,
                        "error": o.error,
                        "runtime_s": round(o.runtime_s, 3),
                        "checks_passed": o.checks_passed,
                        "checks_total": o.checks_total,
                        "report": f"{o.name}/report.md" if o.report_path else None,
                    }
                    for o in outcomes
                ],
                "broken_modules": broken,
            },
            indent=2,
        )
        + "\n",
        encoding="utf-8",
    )
    return path


def _md_escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")
