"""The search's strategies in a user's own @given test, through HilRig."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest
from hypothesis import Phase, given, settings

from workbench.search.assertions import assert_holds
from workbench.search.planted import INTERRUPT_OUTAGE, STALE_AFTER_S, TPDO_LOSS
from workbench.search.properties import Properties
from workbench.search.runner import evaluate
from workbench.search.space import space_from
from workbench.search.strategies import Candidate, candidates

pytestmark = pytest.mark.slow
SPACE = space_from({**INTERRUPT_OUTAGE, "link_faults": [{**INTERRUPT_OUTAGE["link_faults"][0], "length_s": [STALE_AFTER_S + 0.2, 1.0, 0.1]}]})


def test_a_failing_given_test_names_its_bundle(tmp_path: Path) -> None:
    @settings(max_examples=5, deadline=None, database=None, derandomize=True, phases=(Phase.generate,))
    @given(candidates(SPACE))
    def users_test(candidate: Candidate) -> None:
        assert_holds(candidate, "within(counters.stale_episodes, 0, 0)", bundles=tmp_path)

    with pytest.raises(AssertionError) as err:
        users_test()
    bundle = Path(str(err.value).splitlines()[-1].removeprefix("bundle: "))
    assert "stays_within(counters.stale_episodes) FAIL" in str(err.value)
    assert (bundle / "recording.mcap").is_file() and (bundle / "faults.yaml").is_file()


def test_lockstep_judges_a_candidate_as_the_cosimulation_does() -> None:
    """The same candidate in lockstep (the services in one process) and co-simulated: the same results."""
    prop = Properties.parse(["within(counters.stale_episodes, 0, 0)", "within(counters.interrupts_lost, 0, 3)"])
    fault = {"link": "zenoh", "kinds": ["interrupt"], "start_s": 2.0, "stop_s": 2.6, "drop": 1.0}
    candidate = Candidate(3.0, {"seed": 0, "faults": [fault], "stalls": []}, [], {k: v for k, v in INTERRUPT_OUTAGE["fixed"].items()})
    cosim, _ = evaluate(candidate, prop, "cosim")
    lockstep, _ = evaluate(candidate, prop, "lockstep")
    assert cosim.violated and cosim.same_as(lockstep), (cosim.lines(), lockstep.lines())


class PicklingEngine:
    """The campaign engine's ``map`` in this process: each item and result through pickle, as to a Dask worker."""

    def __init__(self) -> None:
        self.batches: list[int] = []

    def map(self, fn, items, **_: object):  # type: ignore[no-untyped-def]
        from workbench.campaign.engine import TaskOutcome

        self.batches.append(len(items))
        return [TaskOutcome(i, str(i), pickle.loads(pickle.dumps(fn(pickle.loads(pickle.dumps(item)))))) for i, item in enumerate(items)]


def test_batches_through_the_engine_find_what_one_process_finds() -> None:
    """Candidates run as engine tasks (pickled there and back), then fed to Hypothesis: the same search."""
    from workbench.search.batches import engine_prefetch
    from workbench.search.engine import Budget, search
    from workbench.search.runner import rig_runner

    space = space_from(TPDO_LOSS)
    prop = Properties.parse(["no_error()"])
    budget = Budget(runs=6, shrink_runs=0)
    alone = search(space, rig_runner(prop), budget, property_text=prop.text, seed=2)
    engine = PicklingEngine()
    batched = search(space, rig_runner(prop), budget, property_text=prop.text, seed=2, prefetch=engine_prefetch([prop.text], "cosim", engine), batch=3)
    assert alone.first is not None and batched.first == alone.first and batched.minimal == alone.minimal
    assert engine.batches and engine.batches[0] == 3
