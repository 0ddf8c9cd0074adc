"""``ralf-hil measure TOOL``: the stand-alone measurements behind the
figures in docs/ (each prints its table; the bench items of ``ralf-hil
bench`` measure the headline numbers):

* ``hotpath``: controller tick and plant step and their parts
  (:mod:`workbench.bench.hotpath`);
* ``cosim-parts``: where a co-simulated tick goes (:mod:`workbench.bench.cosim_parts`);
* ``recording``: what ``--record`` costs the real-time loop (:mod:`workbench.recording.bench`);
* ``live``: what ``--live`` costs it (:mod:`workbench.live.bench`);
* ``input-flood``: what a flood of tools' commands costs it (:mod:`workbench.bench.input_flood`);
* ``xcp-timing``: what the controller's XCP slave and a DAQ master cost it (:mod:`workbench.bench.xcp_timing`);
* ``campaign``: the campaign engine's throughput and overheads (:mod:`workbench.campaign.measure`).

The rig-running ones (``recording``, ``live``, ``input-flood``, ``xcp-timing``, ``campaign``) open the
rig's udp_multicast bus: run them inside ``.ci/loopback-netns``.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from typing import Any


def _hotpath(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--controller-side",
        type=float,
        nargs="?",
        const=10.0,
        default=None,
        metavar="SECONDS",
        help="instead: the controller's share of a co-simulated tick in CPU time over SECONDS simulated (default 10)",
    )


def _cosim_parts(p: argparse.ArgumentParser) -> None:
    p.add_argument("seconds", type=float, nargs="?", default=None, help="simulated seconds (default: 20; with --plant: 10)")
    p.add_argument("--plant", action="store_true", help="instead: the plant side alone, its wire calls replayed")
    p.add_argument(
        "--compare", default=None, metavar="TREE", help="instead: this tree against the ralf-hil sources in TREE, alternating (a before/after table)"
    )
    p.add_argument("--rounds", type=int, default=3, help="with --compare: rounds of the two trees (default 3)")
    p.add_argument("--write", default=None, metavar="PATH", help="with --compare: also write the table there (docs/results/cosim-parts.md)")


def _recording(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pairs", type=int, default=3, help="pairs of runs, without and with --record (default 3)")
    p.add_argument("--duration", type=float, default=20.0, help="wall seconds per run (default 20)")
    p.add_argument("--json", default=None, help="also write every run's numbers to this file")
    p.add_argument("--writer-only", action="store_true", help="only the recorder's own CPU cost per frame and batch (no rig runs)")


def _live(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=20.0, help="seconds of control per run (default 20)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of the three arms, the order rotated each round (default 2)")
    p.add_argument("--rate", type=float, default=20.0, help="the view's --live-rate (default 20)")
    p.add_argument("--json", default=None, help="also write every run's numbers and the medians to this file")


def _input_flood(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=20.0, help="seconds of control per run (default 20)")
    p.add_argument("--rounds", type=int, default=3, help="rounds of the arms, the order rotated each round (default 3)")
    p.add_argument("--messages", type=int, default=20_000, help="commands in the flood (default 20000)")
    p.add_argument("--at", type=float, default=5.0, help="seconds into the control the flood starts (default 5)")
    p.add_argument("--other", default=None, metavar="RALF_HIL", help="another installation's ralf-hil executable: a third arm, flooded alike")
    p.add_argument("--json", default=None, help="also write every run's numbers to this file")


def _xcp_timing(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=20.0, help="seconds of control per run (default 20)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of the three arms, the order rotated each round (default 2)")
    p.add_argument("--json", default=None, help="also write every run's numbers and the medians to this file")
    p.add_argument("--markdown", default=None, help="also write the page of figures (docs/results/xcp-timing.md)")


def _campaign(p: argparse.ArgumentParser) -> None:
    p.add_argument("--blocks", type=int, default=2, help="interleaved blocks of one- and two-worker sweeps (default 2)")
    p.add_argument("--runs", type=int, default=6, help="lockstep runs per sweep (default 6)")
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run (default 10)")
    p.add_argument("--json", default=None, help="also write the result to this file")


TOOLS: dict[str, tuple[str, str, Callable[[argparse.ArgumentParser], None]]] = {
    "hotpath": ("workbench.bench.hotpath", "controller tick and plant step, and their parts, against the 100 µs target", _hotpath),
    "cosim-parts": ("workbench.bench.cosim_parts", "where a co-simulated tick goes (or the plant side alone, replayed)", _cosim_parts),
    "recording": ("workbench.recording.bench", "what recording costs the real-time loop (pairs of ralf-hil up without and with --record)", _recording),
    "live": ("workbench.live.bench", "what the live view costs the real-time loop (without --live, with it, with a client)", _live),
    "input-flood": ("workbench.bench.input_flood", "what a flood of tools' commands costs the real-time loop (undisturbed and flooded runs)", _input_flood),
    "xcp-timing": ("workbench.bench.xcp_timing", "what XCP costs the real-time loop (off, on without a master, with a pyxcp DAQ master)", _xcp_timing),
    "campaign": ("workbench.campaign.measure", "the campaign engine: throughput on one and two workers, start-up and scheduling costs", _campaign),
}
"""Tool name -> (module whose ``main(args) -> int`` runs it, one-line help, its options)."""


def cmd_measure(args: argparse.Namespace) -> int:
    module = importlib.import_module(TOOLS[args.measure_tool][0])
    return int(module.main(args))


def register(subparsers: Any) -> None:
    """Add ``measure`` and its tools to ``ralf-hil`` (the tools are imported only when run)."""
    text = "the stand-alone measurements behind the figures in docs/"
    measure = subparsers.add_parser("measure", help=text, description=text)
    tools = measure.add_subparsers(dest="measure_tool", metavar="TOOL", required=True)
    for name, (_module, text, add_arguments) in TOOLS.items():
        p = tools.add_parser(name, help=text, description=text)
        add_arguments(p)
        p.set_defaults(func=cmd_measure)
