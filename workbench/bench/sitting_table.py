"""The table of one sitting of ``ralf-hil bench --only zenoh`` runs, trees against each other.

``python -m workbench.bench.sitting_table FOLDER [--label TREE=TEXT ...]`` reads the bench
JSONs ``FOLDER/TREE-ROUND.json`` (one per tree and round, written with ``bench --json``)
and prints one row per run, in round order and, within a round, in the order the labels are
given: the DSP's step inside the service (``dsp_compute``), the same step stand-alone
(``dsp_step_standalone``, absent in benches that predate it), their ratio, the bare zenoh
ping-pong and the round trip less the step against it, with each run's time and load. The
table of ``docs/results/dsp-in-service.md`` is this command's output over
``docs/results/dsp-in-service`` (a test keeps them equal)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

HEADER = (
    "| round | tree | time (UTC) | load (1 min) start → end | dsp_compute p50 / p99 µs | dsp_step_standalone p50 / p99 µs "
    "| in-service / stand-alone p50 | zenoh ping-pong p50 µs | round trip less compute / ping-pong p50 |\n"
    "| ---: | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |"
)


def _row(tree: str, run: str, label: str, bench: dict[str, Any]) -> str:
    m = bench["items"]["zenoh"]["measurements"]
    machine = bench["machine"]
    compute, standalone = m["dsp_compute"], m.get("dsp_step_standalone")
    load = f"{machine['load_average_at_start'][0]:.1f} → {machine['load_average_at_end'][0]:.1f}"
    alone = f"{standalone['p50_us']:.0f} / {standalone['p99_us']:.0f} | {compute['ratio']['p50']:.2f}×" if standalone else "– | –"
    return (
        f"| {run} | {label} | {machine['date'][11:19]} | {load} | {compute['p50_us']:.0f} / {compute['p99_us']:.0f} | {alone} "
        f"| {m['zenoh_pingpong']['p50_us']:.0f} | {m['dsp_rtt_minus_compute']['ratio']['p50']:.2f}× |"
    )


def sitting_table(folder: Path, labels: dict[str, str]) -> str:
    """The table (header and rows) of the JSONs in ``folder``; ``labels``: tree → its text, in row order."""
    runs = []
    for path in folder.glob("*.json"):
        tree, _, run = path.stem.rpartition("-")
        if tree not in labels or not run.isdigit():
            raise ValueError(f"{path.name}: not TREE-ROUND.json with TREE one of {', '.join(labels)}")
        runs.append((int(run), list(labels).index(tree), tree, run, path))
    if not runs:
        raise ValueError(f"{folder}: no bench JSON (TREE-ROUND.json) to table")
    rows = [_row(tree, run, labels[tree], json.loads(path.read_text(encoding="utf-8"))) for _, _, tree, run, path in sorted(runs)]
    return HEADER + "\n" + "\n".join(rows)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workbench.bench.sitting_table", description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--label", action="append", default=[], metavar="TREE=TEXT", help="a tree's text in the table, in row order (default: the tree itself)")
    args = p.parse_args(argv)
    labels = dict(item.partition("=")[::2] for item in args.label)
    if not args.folder.is_dir():
        print(f"sitting_table: {args.folder}: not a folder", file=sys.stderr)
        return 2
    if not labels:
        labels = {path.stem.rpartition("-")[0]: path.stem.rpartition("-")[0] for path in sorted(args.folder.glob("*.json"))}
    try:
        print(sitting_table(args.folder, labels))
    except (ValueError, KeyError) as exc:
        print(f"sitting_table: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
