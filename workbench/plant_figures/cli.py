"""``ralf-hil plant``: the plant model's own tools.

* ``report [--out DIR]``: the figures and numbers of docs/plant-model.md
  (:mod:`workbench.plant_figures.report`), the numbers as JSON;
* ``speed-probe [--only NAME ...] [--seed S]``: the candidate mechanisms of
  the speed dependence (:mod:`workbench.plant_figures.speed_probe`), JSON;
* ``calibration [--fit]``: the calibration metrics of the structure's
  defaults, or the stiffnesses re-fitted (:mod:`plant_emulator.model.calibration`);
* ``fmu-build [SOURCE_DIR] [OUT.fmu]``: a C source FMU built with the
  machine's C compiler (:mod:`plant_emulator.fmu.build`).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any


def cmd_report(args: argparse.Namespace) -> int:
    from workbench.plant_figures.report import make_figures

    print(json.dumps(make_figures(Path(args.out)), indent=1))
    return 0


def cmd_speed_probe(args: argparse.Namespace) -> int:
    from workbench.plant_figures.speed_probe import run_probe

    try:
        out = run_probe(args.only, args.seed, say=lambda line: print(line, flush=True))
    except ValueError as exc:
        print(f"ralf-hil plant speed-probe: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=1))
    return 0


def cmd_calibration(args: argparse.Namespace) -> int:
    from plant_emulator.model.calibration import FITTED, fit, metrics
    from plant_emulator.model.modes import DEFAULT_STRUCTURE

    structure = fit() if args.fit else DEFAULT_STRUCTURE
    if args.fit:
        print(json.dumps({n: float(f"{getattr(structure, n):.4g}") for n in FITTED}, indent=1))
    print(json.dumps(asdict(metrics(structure)), indent=1))
    return 0


def cmd_fmu_build(args: argparse.Namespace) -> int:
    from plant_emulator.fmu.build import EXAMPLE_SOURCE, build_c_fmu
    from plant_emulator.fmu.instance import FmuRefused, read_description

    try:
        path = build_c_fmu(args.source_dir or EXAMPLE_SOURCE, args.dest)
        read_description(path)
    except (OSError, subprocess.CalledProcessError, FmuRefused) as exc:
        detail = exc.stderr if isinstance(exc, subprocess.CalledProcessError) else exc
        print(f"ralf-hil plant fmu-build: build failed: {detail}", file=sys.stderr)
        return 2
    print(path)
    return 0


def register(subparsers: Any) -> None:
    """Add ``plant`` and its four tools to ``ralf-hil``."""
    text = "the plant model's figures, speed probe, calibration and FMU build"
    plant = subparsers.add_parser("plant", help=text, description=text)
    tools = plant.add_subparsers(dest="plant_tool", metavar="TOOL", required=True)
    p = tools.add_parser("report", help="draw docs/plant-model.md's figures and print its measured numbers as JSON")
    p.add_argument("--out", default="docs/img", help="directory for the PNGs (default: docs/img)")
    p.set_defaults(func=cmd_report)
    p = tools.add_parser("speed-probe", help="measure why the emulated arm vibrates less at 4 in/s than at 5 in/s (JSON)")
    p.add_argument("--only", nargs="*", default=None, metavar="NAME", help="variant names (default: all)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_speed_probe)
    p = tools.add_parser("calibration", help="the calibration metrics of the structure's defaults (JSON)")
    p.add_argument("--fit", action="store_true", help="re-fit the stiffnesses from the current defaults first")
    p.set_defaults(func=cmd_calibration)
    p = tools.add_parser("fmu-build", help="build a C source co-simulation FMU with the machine's C compiler")
    p.add_argument(
        "source_dir",
        nargs="?",
        default=None,
        help="directory with modelDescription.xml and the C sources (default: the example plant shipped with the package, examples/fmu/two_mode_plant in a checkout)",
    )
    p.add_argument("dest", nargs="?", default="two_mode_plant.fmu", help="the FMU to write (default: two_mode_plant.fmu)")
    p.set_defaults(func=cmd_fmu_build)
