"""The search engine with a pure runner: what it finds, how small, how repeatably."""

from __future__ import annotations

import itertools
from pathlib import Path

from workbench.checks.result import judged
from workbench.search.engine import Budget, search
from workbench.search.runner import Outcome
from workbench.search.space import space_from
from workbench.search.strategies import Candidate

SPACE = space_from(
    {
        "duration_s": [2.0, 6.0, 0.5],
        "link_faults": [
            {"link": "zenoh", "kinds": ["interrupt"], "start_s": [1.0, 3.0, 0.005], "length_s": [0.0, 1.5, 0.005]},
            {"link": "can", "kinds": ["tpdo", "rpdo"], "start_s": [1.0, 3.0, 0.005], "length_s": [0.0, 0.5, 0.005]},
        ],
        "max_link_faults": 3,
    }
)
ALLOWANCE_S = 0.37


def longest_interrupt_outage(c: Candidate) -> float:
    return max((f["stop_s"] - f["start_s"] for f in c.scenario.get("faults", []) if f["kinds"] == ["interrupt"]), default=0.0)


def outage_runner(calls: list[Candidate] | None = None):  # type: ignore[no-untyped-def]
    """A stand-in rig: the property fails when an interrupt outage lasts the allowance or longer."""

    def run(c: Candidate) -> Outcome:
        if calls is not None:
            calls.append(c)
        longest = longest_interrupt_outage(c)
        ok = longest < ALLOWANCE_S - 1e-9
        return Outcome((judged("outage", ok, longest, ALLOWANCE_S, "s", f"outage {longest:.3f} s", None),), "stand-in", 0.0)

    return run


def test_it_finds_the_violation_and_shrinks_it_to_the_boundary() -> None:
    result = search(SPACE, outage_runner(), Budget(runs=30, shrink_runs=200), property_text="outage", seed=3)
    assert result.minimal is not None and result.reproduced
    (fault,) = result.minimal.scenario["faults"]
    assert fault["kinds"] == ["interrupt"] and fault["start_s"] == 1.0
    assert abs(fault["stop_s"] - fault["start_s"] - ALLOWANCE_S) < 1e-6  # exactly the allowance, on the 5 ms grid
    assert result.minimal.duration_s == 2.0
    assert result.first is not None and longest_interrupt_outage(result.first) >= ALLOWANCE_S


def test_the_same_seed_makes_the_same_search() -> None:
    a: list[Candidate] = []
    b: list[Candidate] = []
    ra = search(SPACE, outage_runner(a), Budget(runs=20, shrink_runs=50), property_text="outage", seed=11)
    rb = search(SPACE, outage_runner(b), Budget(runs=20, shrink_runs=50), property_text="outage", seed=11)
    assert [c.key() for c in a] == [c.key() for c in b] and ra.minimal == rb.minimal


def test_a_second_search_starts_from_the_kept_violation(tmp_path: Path) -> None:
    db = tmp_path / "examples"
    first = search(SPACE, outage_runner(), Budget(runs=30, shrink_runs=200), property_text="outage", seed=5, database=db)
    assert first.minimal is not None and any(db.rglob("*"))
    calls: list[Candidate] = []
    again = search(SPACE, outage_runner(calls), Budget(runs=30, shrink_runs=0), property_text="outage", seed=99, database=db)
    assert calls[0] == first.minimal  # replayed before anything new is generated
    assert again.minimal == first.minimal


def test_a_spent_budget_without_a_violation_says_what_it_covered() -> None:
    never = lambda c: Outcome((judged("fine", True, 0, 1, "", "fine", None),), "stand-in", 0.0)  # noqa: E731
    result = search(SPACE, never, Budget(runs=15), property_text="fine", seed=1)
    assert result.minimal is None and result.confirmed is None
    assert 0 < result.coverage.runs <= 15
    assert result.coverage.line().startswith(f"{result.coverage.runs} runs, durations ")


def test_the_time_budget_stops_generating() -> None:
    ticks = itertools.count(0.0, 10.0)  # each look at the clock: 10 s later
    calls: list[Candidate] = []
    never = lambda c: calls.append(c) or Outcome((judged("fine", True, 0, 1, "", "fine", None),), "stand-in", 0.0)  # noqa: E731
    result = search(SPACE, never, Budget(runs=50, seconds=25.0), property_text="fine", seed=1, monotonic=lambda: next(ticks))
    assert result.minimal is None and len(calls) == 2  # looked at 10 s and 20 s: ran; at 30 s: spent


def test_a_confirmation_that_differs_is_not_reproduced() -> None:
    runner = outage_runner()
    fine = Outcome((judged("outage", True, 0, ALLOWANCE_S, "s", "outage 0 s", None),), "stand-in", 0.0)
    result = search(SPACE, runner, Budget(runs=30, shrink_runs=50), property_text="outage", seed=3, confirm=lambda c: fine)
    assert result.minimal is not None and not result.reproduced


def test_batches_run_ahead_and_the_search_ends_as_without_them() -> None:
    batches: list[int] = []
    plain = search(SPACE, outage_runner(), Budget(runs=30, shrink_runs=200), property_text="outage", seed=3)
    runner = outage_runner()

    def prefetch(chunk: list[Candidate]) -> list[Outcome]:
        batches.append(len(chunk))
        return [runner(c) for c in chunk]

    batched = search(SPACE, runner, Budget(runs=30, shrink_runs=200), property_text="outage", seed=3, prefetch=prefetch, batch=4)
    assert batched.minimal == plain.minimal and batched.first == plain.first
    assert batches and all(n == 4 for n in batches[:-1])
    assert batched.coverage.runs >= plain.coverage.runs  # a batch may run past the first violation


def test_a_runner_that_raises_ends_the_search_unshrunk() -> None:
    calls: list[Candidate] = []

    def broken(c: Candidate) -> Outcome:
        calls.append(c)
        raise LookupError("the record holds no signal 'counters.nothing'")

    try:
        search(SPACE, broken, Budget(runs=20), property_text="broken", seed=1)
    except LookupError as exc:
        assert "counters.nothing" in str(exc)
    else:
        raise AssertionError("the runner's error was swallowed")
    assert len(calls) == 1  # not shrunk as a violation
