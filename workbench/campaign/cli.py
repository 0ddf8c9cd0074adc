"""``ralf-hil sweep SPEC [--out DIR] [--scheduler tcp://HOST:8786 | --workers N] [--no-resume] [--dry-run]``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rich.console import Console

DEFAULT_OUT_ROOT = Path("sweep-results")
LARGE_SWEEP = 10_000
"""A sweep of more runs than this runs (or is listed by --dry-run) only with --yes."""


def add_engine_arguments(p: argparse.ArgumentParser) -> None:
    """``--scheduler`` / ``--workers``: where the runs go (shared with ``ralf-hil experiment``)."""
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://HOST:8786 (default: an embedded local cluster)")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="worker processes of the local cluster (default: one per core)")


def open_engine(args: argparse.Namespace) -> Any:
    from workbench.campaign.engine import Engine

    if args.scheduler:
        return Engine.connect(args.scheduler)
    return Engine.local(args.workers)


def register(subparsers: Any) -> None:
    """Add ``sweep`` to ``ralf-hil``."""
    p = subparsers.add_parser(
        "sweep",
        help="run a campaign of rigs (a grid or list of settings, seeds, run modes) on Dask",
        description="Run every point of a YAML or TOML sweep spec as one deterministic rig run on Dask distributed; "
        "writes runs.jsonl, results.parquet and results.csv (one row per run). See docs/campaigns.md.",
    )
    p.add_argument("spec", metavar="SPEC", help="the sweep spec (.yaml, .yml or .toml)")
    p.add_argument("--out", default=None, metavar="DIR", help=f"output directory (default: {DEFAULT_OUT_ROOT}/<spec name>)")
    add_engine_arguments(p)
    p.add_argument("--no-resume", action="store_true", help="run every point again (default: skip the points DIR's journal has as ok)")
    p.add_argument("--dry-run", action="store_true", help="list the resolved runs and exit")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--yes", action="store_true", help=f"run (or, with --dry-run, list) a sweep of more than {LARGE_SWEEP} runs")
    p.add_argument(
        "--junit", default=None, metavar="FILE", help="also write the runs as JUnit XML (one test case per run, its settings and metrics as properties) for CI"
    )
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from workbench.campaign.engine import EngineError
    from workbench.campaign.spec import SpecError, expand, load_spec, planned_runs
    from workbench.campaign.sweep import run_sweep
    from workbench.output_paths import junit_clash

    err = Console(stderr=True, soft_wrap=True)  # a refusal is one line, however long
    try:
        spec = load_spec(args.spec)
        planned = planned_runs(spec)
        if planned > LARGE_SWEEP and not args.yes:
            if args.dry_run:
                print(f"{planned} run(s) planned, more than {LARGE_SWEEP}: not listed (add --yes to resolve and list them)")
                return 0
            err.print(f"ralf-hil sweep: {planned} runs planned, more than {LARGE_SWEEP}: add --yes to run them", highlight=False, markup=False)
            return 2
        points = expand(spec)
    except FileNotFoundError:
        err.print(f"ralf-hil sweep: {args.spec}: no such file", highlight=False, markup=False)
        return 2
    except (OSError, SpecError) as exc:
        err.print(f"ralf-hil sweep: {exc}", highlight=False, markup=False)
        return 2
    if args.dry_run:
        out = Console(width=max(Console().width, 120) if not sys.stdout.isatty() else None)
        for p in points:
            out.print(f"{p.index:4d} {p.key} {p.mode:9s} {p.axes}", highlight=False)
        out.print(f"{len(points)} run(s)")
        return 0
    out_dir = Path(args.out) if args.out else DEFAULT_OUT_ROOT / spec.name
    clash = junit_clash(args.junit, out_dir, "sweep")
    if clash:
        err.print(f"ralf-hil sweep: {clash}", highlight=False, markup=False)
        return 2
    try:
        engine = open_engine(args)
    except EngineError as exc:
        err.print(f"ralf-hil sweep: {exc}", highlight=False, markup=False)
        return 2
    with engine:
        res = run_sweep(spec, out_dir, engine, resume=not args.no_resume, console=err, show_progress=not args.no_progress)
    if args.junit:
        from workbench.junit import sweep_suite, write_junit

        err.print(f"JUnit XML: {write_junit(args.junit, [sweep_suite(spec.name, res.rows, res.wall_s)])}", highlight=False)
    err.print(
        f"{res.ran} run(s) in {res.wall_s:.1f} s ({res.runs_per_hour:.0f} runs/h), {res.skipped} skipped, {res.failed} failed; table: {res.parquet}, {res.csv}",
        highlight=False,
    )
    return 1 if res.failed else 0
