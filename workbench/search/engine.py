"""The search: Hypothesis drives candidates through a runner until one violates
the property, shrinks it to a minimal one, and the minimal one is run again.

The runner (candidate -> :class:`~workbench.search.runner.Outcome`) is
injected: the rig's (:func:`~workbench.search.runner.rig_runner`) or, in
tests of the engine itself, a pure function. Outcomes are kept by candidate,
so Hypothesis asking for a candidate twice (shrinking, the final replay)
costs one run. The budget:

* ``runs``: how many candidates to generate (Hypothesis's ``max_examples``);
* ``shrink_runs``: how many more rig runs shrinking may take once a
  violation is found (after that a new candidate counts as holding, so
  Hypothesis ends with the smallest violation it has run);
* ``seconds`` (optional): generating stops once that much wall time has gone
  by (shrinking then still gets its runs).

With ``seed`` the search is deterministic for a deterministic runner (the
co-simulation and lockstep are); with ``database`` (a directory) Hypothesis
keeps the violations it found there and a later search of the same space and
property replays them first.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hypothesis import HealthCheck, Phase, given
from hypothesis import seed as hypothesis_seed
from hypothesis import settings as hypothesis_settings
from hypothesis.database import DirectoryBasedExampleDatabase
from hypothesis.errors import Flaky

from workbench.search.runner import Outcome
from workbench.search.space import SearchSpace
from workbench.search.strategies import Candidate, candidates


class Violation(AssertionError):
    """A candidate whose run violated the property."""

    def __init__(self, candidate: Candidate, outcome: Outcome) -> None:
        super().__init__("; ".join(r.line() for r in outcome.results if not r.passed))
        self.candidate = candidate
        self.outcome = outcome


class SearchFlaky(RuntimeError):
    """The runner gave two answers for one candidate: the search cannot shrink (one line)."""


@dataclass(frozen=True)
class Budget:
    runs: int
    shrink_runs: int | None = None
    """Default: as many as ``runs``."""
    seconds: float | None = None

    def __post_init__(self) -> None:
        if self.runs < 1:
            raise ValueError(f"the budget must allow at least one run, got {self.runs}")
        if self.shrink_runs is not None and self.shrink_runs < 0:
            raise ValueError(f"the shrink budget must not be negative, got {self.shrink_runs}")
        if self.seconds is not None and not self.seconds > 0:
            raise ValueError(f"the time budget must be positive, got {self.seconds}")


@dataclass
class Coverage:
    """What the runs tried."""

    runs: int = 0
    distinct: int = 0
    most_link_faults: int = 0
    most_channel_faults: int = 0
    most_stalls: int = 0
    kinds: set[str] = field(default_factory=set)
    durations: list[float] = field(default_factory=list)
    settings: dict[str, set[str]] = field(default_factory=dict)

    def add(self, c: Candidate) -> None:
        self.runs += 1
        faults = c.scenario.get("faults") or []
        self.most_link_faults = max(self.most_link_faults, len(faults))
        self.most_stalls = max(self.most_stalls, len(c.scenario.get("stalls") or []))
        self.most_channel_faults = max(self.most_channel_faults, len(c.channel_faults))
        self.kinds |= {f"{f['link']}/{k}" for f in faults for k in f["kinds"]} | {f"{x['channel']}/{x['kind']}" for x in c.channel_faults}
        self.kinds |= {f"{p['input']}/{p['shape']}" for p in c.stimulus}
        self.durations.append(c.duration_s)
        for svc, values in c.settings.items():
            for name, value in values.items():
                self.settings.setdefault(f"{svc}.{name}", set()).add(repr(value))

    def line(self) -> str:
        span = f"{min(self.durations):g}-{max(self.durations):g} s" if self.durations else "none"
        varied = ", ".join(f"{k} ({len(v)} values)" for k, v in sorted(self.settings.items()) if len(v) > 1)
        return (
            f"{self.runs} runs, durations {span}, up to {self.most_link_faults} link faults, {self.most_stalls} stalls, "
            f"{self.most_channel_faults} channel faults in one run; fault kinds {', '.join(sorted(self.kinds)) or 'none'}"
            + (f"; settings varied: {varied}" if varied else "")
        )


@dataclass
class SearchResult:
    """A search's end: the minimal violation (or none), its confirmation, what was covered."""

    minimal: Candidate | None
    outcome: Outcome | None
    confirmed: Outcome | None
    coverage: Coverage
    shrink_runs: int
    first: Candidate | None = None
    """The first violation found (before shrinking)."""
    wall_s: float = 0.0

    @property
    def reproduced(self) -> bool:
        """The minimal violation violated the property again, with the same results."""
        return self.outcome is not None and self.confirmed is not None and self.confirmed.violated and self.confirmed.same_as(self.outcome)


def database_key(space: SearchSpace, property_text: str, clock: str) -> bytes:
    """The example database's key: one per space, property and clock."""
    return hashlib.sha384(f"{space.digest()}\n{property_text}\n{clock}".encode()).digest()


def _hypothesis(space: SearchSpace, runs: int, seed: int, database: Path | None, key: bytes | None, body: Callable[[Candidate], None]) -> Callable[[], None]:
    """``body`` as a Hypothesis test over ``space``'s candidates (seeded, no deadline, one bug)."""

    @hypothesis_settings(
        max_examples=runs,
        deadline=None,
        database=DirectoryBasedExampleDatabase(str(database)) if database is not None else None,
        report_multiple_bugs=False,
        suppress_health_check=list(HealthCheck),
        phases=(Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink),
        print_blob=False,
    )
    @hypothesis_seed(seed)
    @given(candidates(space))
    def probe(candidate: Candidate) -> None:
        body(candidate)

    if key is not None:
        probe._hypothesis_internal_database_key = key  # type: ignore[attr-defined]
    return probe


def generated(space: SearchSpace, runs: int, seed: int) -> list[Candidate]:
    """The candidates a search of ``space`` with ``seed`` generates, in order, while none
    violates (Hypothesis run with every candidate holding: nothing runs)."""
    seen: list[Candidate] = []
    keys: set[str] = set()

    def note(candidate: Candidate) -> None:
        if candidate.key() not in keys:
            keys.add(candidate.key())
            seen.append(candidate)

    _hypothesis(space, runs, seed, None, None, note)()
    return seen


Prefetch = Callable[[list[Candidate]], list[Outcome]]
"""Runs a batch of candidates at once (:mod:`workbench.search.batches`: Dask tasks)."""


def search(
    space: SearchSpace,
    runner: Callable[[Candidate], Outcome],
    budget: Budget,
    *,
    property_text: str,
    seed: int = 0,
    database: Path | None = None,
    clock: str = "cosim",
    on_run: Callable[[int, Candidate, Outcome], None] | None = None,
    confirm: Callable[[Candidate], Outcome] | None = None,
    prefetch: Prefetch | None = None,
    batch: int = 4,
    monotonic: Callable[[], float] = time.monotonic,
) -> SearchResult:
    """Search ``space`` for a candidate whose run violates the property; shrink it; run the minimal
    one again (through ``confirm``, default the runner: a fresh run, not the kept outcome).

    With ``prefetch`` the candidates Hypothesis will generate (:func:`generated`: the same seed
    draws the same ones while none violates) are run ``batch`` at a time through it, until a
    batch holds a violation or the budget is spent; Hypothesis then finds their outcomes kept
    and runs only what it asks beyond them (the database's examples, shrinking) one by one.

    A runner that raises (a signal the record does not hold, a setting the rig refuses) ends
    the search at once: every later candidate is taken as holding, and the error is raised
    once Hypothesis is done, instead of being shrunk as if it were a violation."""
    outcomes: dict[str, Outcome] = {}
    coverage = Coverage()
    state = {"shrink_runs": 0}
    first: list[Candidate] = []
    shrink_budget = budget.runs if budget.shrink_runs is None else budget.shrink_runs
    started = monotonic()

    def keep(candidate: Candidate, outcome: Outcome) -> None:
        outcomes[candidate.key()] = outcome
        coverage.add(candidate)
        if on_run is not None:
            on_run(coverage.runs, candidate, outcome)

    if prefetch is not None:
        if batch < 1:
            raise ValueError(f"a batch holds at least one candidate, got {batch}")
        ahead = generated(space, budget.runs, seed)
        for i in range(0, len(ahead), batch):
            if budget.seconds is not None and monotonic() - started > budget.seconds:
                break
            chunk = ahead[i : i + batch]
            results = prefetch(chunk)
            for candidate, outcome in zip(chunk, results, strict=True):
                keep(candidate, outcome)
            if any(o.violated for o in results):
                break

    error: list[BaseException] = []

    def outcome_of(candidate: Candidate) -> Outcome | None:
        key = candidate.key()
        if key in outcomes:
            return outcomes[key]
        if error:
            return None  # the search is over: see below
        if first:
            if state["shrink_runs"] >= shrink_budget:
                return None  # shrinking has spent its runs: not run, taken as holding
            state["shrink_runs"] += 1
        elif budget.seconds is not None and monotonic() - started > budget.seconds:
            return None  # generating has spent its time
        try:
            outcome = runner(candidate)
        except Exception as exc:  # noqa: BLE001 - not a violation: the search ends with it, unshrunk
            error.append(exc)
            return None
        keep(candidate, outcome)
        return outcome

    def body(candidate: Candidate) -> None:
        outcome = outcome_of(candidate)
        if outcome is not None and outcome.violated:
            if not first:
                first.append(candidate)
            raise Violation(candidate, outcome)

    probe = _hypothesis(space, budget.runs, seed, database, database_key(space, property_text, clock), body)
    minimal: Candidate | None = None
    violated: Outcome | None = None
    try:
        probe()
    except Violation as v:
        minimal, violated = v.candidate, v.outcome
    except Flaky as exc:
        raise SearchFlaky(f"the runner gave two answers for one candidate: {' '.join(str(exc).split())[:300]}") from None
    if error:
        raise error[0]
    confirmed = (confirm or runner)(minimal) if minimal is not None else None
    return SearchResult(minimal, violated, confirmed, coverage, state["shrink_runs"], first[0] if first else None, monotonic() - started)
