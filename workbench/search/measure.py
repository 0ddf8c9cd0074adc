"""The worked example of docs/fault-search.md, run and measured.

``python -m workbench.search.measure docs/results/fault-search`` runs
``ralf-hil search`` on ``docs/search/interrupt-outage.yaml`` (seed
1, a fresh example database) and writes ``example.txt`` (its output, the
bundle's path made relative) and ``rate.md`` (runs, wall time, runs per
second, the host and its load before and after).

``python -m workbench.search.measure --planted docs/results/fault-search`` runs the
search on each planted weakness of :mod:`workbench.search.planted` from seeds 0..4
with a generous budget and writes ``planted.md``: per seed the runs until the first
violation, the runs spent shrinking, whether the minimal violation is the known one
(within one grid step), the wall time, and the median over the seeds.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from workbench.hostinfo import host_line, load_average
from workbench.search.strategies import Candidate

SEEDS = (0, 1, 2, 3, 4)
PLANTED_BUDGET = (60, 100)
"""Candidates to generate and runs shrinking may take, per seed: well past what the tests allow."""

SPACE = Path(__file__).resolve().parents[2] / "docs" / "search" / "interrupt-outage.yaml"
ARGS = ["--property", "within(counters.stale_episodes, 0, 0)", "--budget", "10", "--shrink-budget", "40", "--seed", "1"]


def measure(out: Path) -> dict[str, object]:
    from workbench.cli import main

    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ralf-search-measure-") as tmp:
        before = load_average()
        started = time.monotonic()
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            code = main(["search", str(SPACE), *ARGS, "--out", tmp])
        wall = time.monotonic() - started
        after = load_average()
        text = printed.getvalue().replace(str(Path(tmp).resolve()), "search-out")
        bundle = Path(tmp) / text.strip().splitlines()[-1].removeprefix("bundle: search-out/")
        info = json.loads((bundle / "bundle.json").read_text(encoding="utf-8"))
        reproduce = (bundle / "reproduce.txt").read_text(encoding="utf-8").replace(str(Path(tmp).resolve()), "search-out")
    runs = int(info["search"]["runs"]) + 1  # and the confirming run
    command = "ralf-hil search docs/search/interrupt-outage.yaml " + " ".join(f"'{a}'" if "(" in a else a for a in ARGS)
    first = Candidate.from_dict(info["search"]["first"]).describe() if info["search"].get("first") else "none"
    (out / "example.txt").write_text(
        f"$ {command}\n{text}(exit {code})\n\n# the first violation met: {first}\n\n$ cat search-out/{bundle.name}/reproduce.txt\n{reproduce}", encoding="utf-8"
    )
    result: dict[str, object] = {
        "runs": runs,
        "wall_s": round(wall, 2),
        "runs_per_s": round(runs / wall, 2),
        "load_before": before,
        "load_after": after,
        "exit": code,
    }
    (out / "rate.md").write_text(
        "# ralf-hil search: measured rate\n\n"
        f"`{command}`, co-simulated, one process (written by `python -m workbench.search.measure docs/results/fault-search`).\n\n"
        "| runs (with the confirming one) | wall time (s) | runs per second | load before | load after |\n| ---: | ---: | ---: | --- | --- |\n"
        f"| {runs} | {wall:.1f} | {runs / wall:.2f} | {before} | {after} |\n\n{host_line()}\n",
        encoding="utf-8",
    )
    return result


def push_threshold(template: Candidate) -> int:
    """The smallest integer force (N) of a 0.1 s push from 1 s on a 2 s run that breaks the deflection
    bound, bisected on [0, 100] (the plant's response grows with the force)."""
    from workbench.search.planted import DEFLECTION_BOUND_IN
    from workbench.search.properties import Properties
    from workbench.search.runner import evaluate

    prop = Properties.parse([f"within(defl2_in, -{DEFLECTION_BOUND_IN}, {DEFLECTION_BOUND_IN})"])
    (push,) = template.stimulus

    def breaks(force: int) -> bool:
        c = Candidate(2.0, {}, [], template.settings, [{**push, "at_s": 1.0, "for_s": 0.1, "size": force}])
        return evaluate(c, prop)[0].violated

    low, high = 0, 100
    if not breaks(high):
        raise RuntimeError("a 100 N push of 0.1 s does not break the deflection bound")
    while high - low > 1:
        mid = (low + high) // 2
        low, high = (low, mid) if breaks(mid) else (mid, high)
    return high


def _faults_only(c: Candidate) -> str:
    """The candidate's line without its settings (the space's fixed ones: nothing in these spaces varies them)."""
    return Candidate(c.duration_s, c.scenario, c.channel_faults, {}, c.stimulus).describe()


def _median(values: list[float]) -> float:
    return float(statistics.median(values))


def measure_planted(out: Path, seeds: tuple[int, ...] = SEEDS, log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Search every planted weakness from each seed; write ``planted.md`` (see the module's docstring)."""
    from workbench.search.engine import Budget, search
    from workbench.search.planted import WEAKNESSES, push_differs
    from workbench.search.properties import Properties
    from workbench.search.runner import rig_runner
    from workbench.search.space import space_from

    out.mkdir(parents=True, exist_ok=True)
    runs, shrink = PLANTED_BUDGET
    before, date = load_average(), datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    rows: list[dict[str, Any]] = []
    sections: list[str] = []
    for w in WEAKNESSES:
        space, prop = space_from(w.space), Properties.parse([w.property_text])
        known = w.known
        differs = w.differs
        per_seed: list[dict[str, Any]] = []
        for seed in seeds:
            first_at: list[int] = []

            def note(n: int, _c: Candidate, outcome: Any, first_at: list[int] = first_at) -> None:
                if outcome.violated and not first_at:
                    first_at.append(n)

            result = search(space, rig_runner(prop), Budget(runs=runs, shrink_runs=shrink), property_text=prop.text, seed=seed, on_run=note)
            if differs is None and result.minimal is not None:
                threshold = push_threshold(result.minimal)
                known = f"{w.known}: {threshold} N"
                differs = lambda c, t=threshold: push_differs(c, t)  # noqa: E731
            why = differs(result.minimal) if differs is not None and result.minimal is not None else "no violation"
            row = {
                "weakness": w.name,
                "seed": seed,
                "first": first_at[0] if first_at else None,
                "shrink_runs": result.shrink_runs,
                "known": why is None,
                "why": why,
                "minimal": _faults_only(result.minimal) if result.minimal is not None else "none",
                "reproduced": result.reproduced,
                "wall_s": round(result.wall_s, 1),
            }
            log(json.dumps(row))
            per_seed.append(row)
        rows += per_seed
        lines = [
            f"## {w.name}\n",
            f"Property `{w.property_text}`. Known minimal: {known}.\n",
            "| seed | runs to the first violation | runs shrinking | known minimal (one grid step) | reproduced | wall time (s) | minimal violation |",
            "| ---: | ---: | ---: | --- | --- | ---: | --- |",
        ]
        for r in per_seed:
            known_cell = "yes" if r["known"] else f"no: {r['why']}"
            lines.append(
                f"| {r['seed']} | {r['first'] if r['first'] is not None else 'none'} | {r['shrink_runs']} | {known_cell} | {'yes' if r['reproduced'] else 'no'} | {r['wall_s']:.1f} | {r['minimal']} |"
            )
        found = [r for r in per_seed if r["first"] is not None]
        first_med = f"{_median([r['first'] for r in found]):g}" if len(found) == len(per_seed) else f"none in {len(per_seed) - len(found)} seeds"
        lines.append(
            f"| median | {first_med} | {_median([r['shrink_runs'] for r in per_seed]):g} | {sum(r['known'] for r in per_seed)} of {len(per_seed)} | "
            f"{sum(r['reproduced'] for r in per_seed)} of {len(per_seed)} | {_median([r['wall_s'] for r in per_seed]):.1f} | |"
        )
        lines.append(
            f"\nWorst seed: {max((r['first'] for r in found), default=0)} runs to the first violation, {max(r['shrink_runs'] for r in per_seed)} shrinking.\n"
        )
        sections.append("\n".join(lines))
    after = load_average()
    (out / "planted.md").write_text(
        "# ralf-hil search: runs each planted weakness needs\n\n"
        f"Written by `python -m workbench.search.measure --planted docs/results/fault-search` on {date}: the spaces and properties of "
        f"`workbench/search/planted.py`, co-simulated, one process, seeds {', '.join(map(str, seeds))}, a budget of {runs} candidates and "
        f"{shrink} runs shrinking per seed. Runs to the first violation count from 1 (the first candidate run); the runs shrinking are the "
        "further runs until Hypothesis ended (a candidate asked for twice costs one); the wall time includes the confirming run "
        "(and, for the first search, the imports). The minimal violations are shown without the spaces' fixed settings. "
        f"Load before {before}, after {after}.\n\n" + "\n".join(sections) + f"\n{host_line()}\n",
        encoding="utf-8",
    )
    return rows


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--planted"]:
        measure_planted(Path(args[1] if len(args) > 1 else "docs/results/fault-search"))
    else:
        print(json.dumps(measure(Path(args[0] if args else "docs/results/fault-search"))))
