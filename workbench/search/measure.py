"""The worked example of docs/fault-search.md, run and measured.

``python -m workbench.search.measure docs/results/fault-search`` runs
``ralf-hil search`` on ``docs/scenarios/search-interrupt-outage.yaml`` (seed
1, a fresh example database) and writes ``example.txt`` (its output, the
bundle's path made relative) and ``rate.md`` (runs, wall time, runs per
second, the host and its load before and after).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

from workbench.hostinfo import host_line, load_average
from workbench.search.strategies import Candidate

SPACE = Path(__file__).resolve().parents[2] / "docs" / "scenarios" / "search-interrupt-outage.yaml"
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
    command = "ralf-hil search docs/scenarios/search-interrupt-outage.yaml " + " ".join(f"'{a}'" if "(" in a else a for a in ARGS)
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


if __name__ == "__main__":
    print(json.dumps(measure(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results/fault-search"))))
