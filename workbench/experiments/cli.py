"""``ralf-hil experiment NAME|all [--out DIR] [--seed S] [--mode cosim|lockstep|realtime] [--quick]`` and ``--list``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from workbench.experiments.framework import (
    ALL,
    ExperimentError,
    UnknownExperimentError,
    broken_modules,
    get_experiment,
    list_experiments,
    run_all,
    run_experiment,
)

DEFAULT_OUT_ROOT = Path("experiment-results")
"""Default output: ``experiment-results/<NAME>`` (``experiment-results/all`` for ``all``)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", metavar="NAME", help=f"experiment to run, or {ALL!r} for every one (see --list)")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.add_argument("--out", default=None, metavar="DIR", help=f"output directory (default: {DEFAULT_OUT_ROOT}/NAME)")
    p.add_argument("--seed", type=int, default=0, help="base seed of every random stream (default 0)")
    p.add_argument(
        "--mode",
        choices=("cosim", "lockstep", "realtime"),
        default="cosim",
        help="how experiments that start the rig run it: cosim (default: plant, controller and DSP in one thread, "
        "bit-identical to lockstep), lockstep or realtime (the three-process rig); offline experiments ignore it",
    )
    p.add_argument("--quick", action="store_true", help="short runs (fewer points, draws, a shorter trajectory)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run the experiments' rigs on this Dask scheduler, e.g. tcp://HOST:8786 (default: a local cluster, started when an experiment needs it)",
    )
    p.add_argument("--workers", type=int, default=None, metavar="N", help="worker processes of the local cluster (default: one per core)")
    p.add_argument(
        "--record",
        action="store_true",
        help="also record every rig run (co-simulated or three-process) into DIR/records/<run>.mcap (ralf-hil replay/plot read them)",
    )
    p.add_argument(
        "--junit", default=None, metavar="FILE", help="also write the checks as JUnit XML (a test suite per experiment, a test case per check) for CI"
    )


def register(subparsers: Any) -> None:
    """Add ``experiment`` to ``ralf-hil``."""
    p = subparsers.add_parser(
        "experiment",
        help="reproduce the thesis's figures and experiments into a Markdown report",
        description="Run one experiment (or all) and write report.md, PNG figures and results.json. Use --list to see them.",
    )
    add_arguments(p)
    p.set_defaults(func=cmd_experiment)


def print_list(console: Console) -> None:
    table = Table(title="ralf-hil experiments", show_header=True)
    table.add_column("name", no_wrap=True)
    table.add_column("thesis")
    table.add_column("rig", justify="center")
    table.add_column("description")
    for exp in list_experiments():
        table.add_row(exp.name, exp.section, "yes" if exp.needs_rig else "–", exp.description)
    table.add_row(ALL, "", "", "every experiment above, into DIR/<name>/ with DIR/index.md")
    console.print(table)
    for mod, err in sorted(broken_modules().items()):
        console.print(f"[red]broken experiment module {mod}: {err}[/red]")


def cmd_experiment(args: argparse.Namespace) -> int:
    from workbench.campaign.engine import engine_scope

    with engine_scope(getattr(args, "scheduler", None), getattr(args, "workers", None)):
        return _cmd_experiment(args)


def _cmd_experiment(args: argparse.Namespace) -> int:
    from workbench.output_paths import junit_clash

    out_console = Console(width=max(Console().width, 120) if not sys.stdout.isatty() else None)
    err_console = Console(stderr=True, soft_wrap=True)  # a refusal is one line, however long
    if args.list:
        print_list(out_console)
        return 0
    if not args.name:
        err_console.print("ralf-hil experiment: give an experiment NAME, 'all', or --list")
        return 2
    show = not args.no_progress
    clash = junit_clash(args.junit, Path(args.out) if args.out else DEFAULT_OUT_ROOT / args.name, "experiment all" if args.name == ALL else "experiment")
    if clash:
        err_console.print(f"ralf-hil experiment: {clash}", highlight=False, markup=False)
        return 2
    if args.name == ALL:
        out = Path(args.out) if args.out else DEFAULT_OUT_ROOT / ALL
        outcomes, index = run_all(out, seed=args.seed, mode=args.mode, quick=args.quick, console=err_console, show_progress=show, record=args.record)
        err_console.print(f"index: {index}")
        _write_junit(args, outcomes, err_console)
        ok = sum(o.ok for o in outcomes)
        err_console.print(f"{ok} of {len(outcomes)} experiments ok" + ("" if outcomes else ": none ran, nothing to pass"), highlight=False)
        return 0 if outcomes and ok == len(outcomes) and not broken_modules() else 1
    try:
        get_experiment(args.name)
    except UnknownExperimentError as exc:
        err_console.print(f"ralf-hil experiment: {exc}", highlight=False, markup=False)
        return 2
    out = Path(args.out) if args.out else DEFAULT_OUT_ROOT / args.name
    try:
        outcome = run_experiment(args.name, out, seed=args.seed, mode=args.mode, quick=args.quick, console=err_console, show_progress=show, record=args.record)
    except ExperimentError as exc:
        err_console.print(f"ralf-hil experiment: {exc}", highlight=False, markup=False)
        return 2
    _write_junit(args, [outcome], err_console)
    if outcome.missing_extra:
        err_console.print(f"ralf-hil experiment {args.name}: {outcome.error}", highlight=False, markup=False)
        return 2
    if outcome.status == "error":
        err_console.print(f"[red]{args.name} failed: {outcome.error}[/red] (traceback in {out / 'error.txt'})")
        return 1
    msg = f"{args.name}: {outcome.status}, checks {outcome.checks_passed}/{outcome.checks_total}, {outcome.runtime_s:.1f} s; report: {outcome.report_path}"
    if outcome.warnings:
        msg += f"; the rig's warnings, in the report: {outcome.warnings}"
    err_console.print(msg if outcome.ok else f"[red]{msg}[/red]", highlight=False)
    return 0 if outcome.ok else 1


def _write_junit(args: argparse.Namespace, outcomes: list[Any], console: Console) -> None:
    if getattr(args, "junit", None):
        from workbench.junit import experiment_suite, write_junit

        console.print(f"JUnit XML: {write_junit(args.junit, [experiment_suite(o) for o in outcomes])}", highlight=False)
