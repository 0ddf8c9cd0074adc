"""``ralf-hil search SPACE.yaml --property P --budget N``: find the smallest scenario that breaks the rig.

Exit codes: 1 with the failure bundle's path when a violation was found (and
confirmed by a run of its own), 0 when the budget was spent without one
(how many runs, what they covered), 2 on bad input (one line, before any
run). ``--replay BUNDLE`` runs a bundle's scenario again and judges its
property: 1 when it fails again, 0 when it holds.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from workbench.search.properties import Properties
    from workbench.search.runner import Outcome, SearchClock
    from workbench.search.strategies import Candidate


def register(sub: Any) -> None:
    p = sub.add_parser("search", help="search a space of faults and settings for the smallest scenario that violates a property (docs/fault-search.md)")
    p.add_argument("space", nargs="?", help="the search space (YAML or JSON: duration_s, link_faults, stalls, channel_faults, settings, fixed)")
    p.add_argument(
        "--property",
        action="append",
        default=[],
        metavar="P",
        help="what every run must hold: streak(1), within(SIGNAL, LOW, HIGH), mode(0.1, 7), detected(CAUSE, DETECTION, S), valves_zero_within(events.channel_fault, 50), verdict(DEGRADED), no_error(); repeatable",
    )
    p.add_argument("--budget", type=int, default=None, metavar="N", help="candidates to try (co-simulated runs)")
    p.add_argument("--shrink-budget", type=int, default=None, metavar="N", help="further runs shrinking a violation may take (default: --budget)")
    p.add_argument("--time-budget", type=float, default=None, metavar="S", help="stop trying new candidates after S seconds of wall time")
    p.add_argument("--seed", type=int, default=0, help="the search's seed (the same seed, space and property: the same search)")
    p.add_argument("--clock", choices=("cosim", "lockstep"), default="cosim", help="the rig's clock (default cosim; lockstep: the services in one process)")
    p.add_argument("--out", default="search-out", help="where the failure bundle goes (default: search-out)")
    p.add_argument("--db", default=None, help="Hypothesis's example database (default: OUT/examples): a later search starts from the violations kept there")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="run the candidates in batches as Dask tasks on a local cluster of N workers (default: one process)",
    )
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786", help="run the batches on this Dask scheduler's workers (docs/campaigns.md)")
    p.add_argument("--batch", type=int, default=None, metavar="N", help="candidates per batch with --workers/--scheduler (default: the engine's workers)")
    p.add_argument("--replay", default=None, metavar="BUNDLE", help="run a failure bundle again and judge its property (exit 1: it fails again)")
    p.set_defaults(func=cmd_search)


def _fail(message: str) -> int:
    print(f"ralf-hil search: {' '.join(message.split())}", file=sys.stderr)
    return 2


def confirm_into(directory: Path, properties: Properties, clock: SearchClock) -> Any:
    """A confirmation run whose files (the MCAP recording) stay in ``directory``."""
    from workbench.search.runner import evaluate

    def run(candidate: Candidate) -> Outcome:
        outcome, record = evaluate(candidate, properties, clock, keep=directory)
        run.recording = record.recording  # type: ignore[attr-defined]
        return outcome

    return run


def cmd_replay(args: argparse.Namespace) -> int:
    from workbench.search.bundle import read_bundle
    from workbench.search.properties import Properties
    from workbench.search.runner import evaluate
    from workbench.search.strategies import Candidate

    directory = Path(args.replay)
    try:
        info = read_bundle(directory)
        candidate = Candidate.from_dict(info["candidate"])
        properties = Properties.parse(info.get("properties") or [info["property"]])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return _fail(f"{directory}: not a failure bundle ({exc})")
    clock: SearchClock = "lockstep" if info.get("clock") == "lockstep" else "cosim"
    with tempfile.TemporaryDirectory(prefix="ralf-search-replay-") as tmp:
        outcome, _ = evaluate(candidate, properties, clock, keep=Path(tmp))
    print(outcome.summary)
    for line in outcome.lines():
        print(line)
    if outcome.violated:
        print(f"violated again: {properties.text}")
        return 1
    print(f"holds: {properties.text}")
    return 0


def cmd_search(args: argparse.Namespace) -> int:
    from workbench.campaign.engine import current_engine, engine_scope
    from workbench.checks.record_signals import SignalNotInRecord
    from workbench.hil import RigSettingError
    from workbench.progress import activity
    from workbench.search.batches import engine_prefetch
    from workbench.search.bundle import bundle_name, write_bundle
    from workbench.search.engine import Budget, SearchFlaky, search
    from workbench.search.properties import Properties, PropertyError
    from workbench.search.runner import evaluate
    from workbench.search.space import SpaceError, load_space

    logging.getLogger().addHandler(logging.NullHandler())  # the runs' WARNING lines are counted in their verdicts, not printed
    if args.replay is not None:
        return cmd_replay(args)
    if args.space is None:
        return _fail("give a search space (SPACE.yaml) or --replay BUNDLE")
    if args.budget is None:
        return _fail("give a budget: --budget N (candidates to try)")
    try:
        budget = Budget(args.budget, args.shrink_budget, args.time_budget)
        space = load_space(args.space)
        properties = Properties.parse(args.property)
    except (ValueError, SpaceError, PropertyError) as exc:
        return _fail(str(exc))
    out = Path(args.out)
    db = Path(args.db) if args.db else out / "examples"
    clock: SearchClock = args.clock
    counts = {"runs": 0, "violations": 0}
    last = [""]

    def on_run(n: int, candidate: Candidate, outcome: Outcome) -> None:
        counts["runs"] = n
        counts["violations"] += int(outcome.violated)
        last[0] = candidate.describe()

    def progress() -> str:
        return f"search: {counts['runs']} runs, {counts['violations']} violating; last: {last[0][:120]}"

    staging = Path(tempfile.mkdtemp(prefix="ralf-search-confirm-"))
    confirm = confirm_into(staging, properties, clock)
    print(
        f"ralf-hil search: {space.name}, property {properties.text}, budget {budget.runs} runs (+{budget.runs if budget.shrink_runs is None else budget.shrink_runs} to shrink), seed {args.seed}, {clock}",
        file=sys.stderr,
    )
    if args.workers is not None and args.workers < 1:
        return _fail(f"--workers must be at least 1, got {args.workers}")
    if args.batch is not None and args.batch < 1:
        return _fail(f"--batch must be at least 1, got {args.batch}")
    batched = args.workers is not None or args.scheduler is not None
    try:
        with activity(progress), engine_scope(args.scheduler, args.workers) if batched else nullcontext():
            batch = args.batch or (current_engine().slots() if batched else 1)
            result = search(
                space, lambda c: evaluate(c, properties, clock)[0], budget, property_text=properties.text, seed=args.seed, database=db, clock=clock,
                on_run=on_run, confirm=confirm, prefetch=engine_prefetch([p.text for p in properties.items], clock) if batched else None, batch=batch,
            )  # fmt: skip
    except SearchFlaky as exc:
        shutil.rmtree(staging, ignore_errors=True)
        return _fail(str(exc))
    except (SignalNotInRecord, RigSettingError) as exc:
        shutil.rmtree(staging, ignore_errors=True)
        return _fail(str(exc))
    covered = result.coverage.line()
    if result.minimal is None or result.outcome is None or result.confirmed is None:
        shutil.rmtree(staging, ignore_errors=True)
        print(f"no violation of {properties.text} in {result.coverage.runs} runs ({result.wall_s:.1f} s); covered: {covered}")
        return 0
    directory = write_bundle(
        out / bundle_name(result.minimal, properties.text), result.minimal, property_text=properties.text, properties=[p.text for p in properties.items],
        clock=clock, seed=args.seed, lines=result.confirmed.lines(), summary=result.confirmed.summary, recording=getattr(confirm, "recording", None),
        search={"runs": result.coverage.runs, "shrink_runs": result.shrink_runs, "first": result.first.as_dict() if result.first else None,
                "covered": covered, "reproduced": result.reproduced},
    )  # fmt: skip
    shutil.rmtree(staging, ignore_errors=True)
    print(f"minimal violation ({result.coverage.runs} runs, {result.shrink_runs} of them shrinking, {result.wall_s:.1f} s): {result.minimal.describe()}")
    for line in result.confirmed.lines():
        print(f"  {line}")
    if not result.reproduced:
        print("the confirming run did not repeat the violation exactly: the runs are not deterministic (see the bundle)")
    print(f"bundle: {directory}")
    return 1
