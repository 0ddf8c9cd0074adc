"""The search's strategies in a user's own ``@given`` test.

::

    from hypothesis import given, settings
    from workbench.search.assertions import assert_holds
    from workbench.search.space import load_space
    from workbench.search.strategies import candidates

    SPACE = load_space("interrupt-outage.yaml")

    @settings(max_examples=10, deadline=None)
    @given(candidates(SPACE))
    def test_no_stale_parameters(candidate):
        assert_holds(candidate, "within(counters.stale_episodes, 0, 0)")

:func:`assert_holds` runs the candidate on a :class:`workbench.hil.HilRig`
and judges the property; a violation writes a failure bundle
(:mod:`workbench.search.bundle`) and fails with its lines and the bundle's
path. Hypothesis shrinks the failing candidate and calls the test with the
minimal one last, so the path in the failure it reports is the minimal
candidate's bundle.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

from workbench.search.bundle import bundle_name, write_bundle
from workbench.search.properties import Properties
from workbench.search.runner import SearchClock, evaluate
from workbench.search.strategies import Candidate


def assert_holds(
    candidate: Candidate, *properties: str | Sequence[str], clock: SearchClock = "cosim", bundles: str | Path = "search-out", seed: int = 0
) -> None:
    """Run ``candidate`` and fail (``AssertionError`` naming the bundle) if any property does not PASS."""
    __tracebackhide__ = True
    texts = [p for item in properties for p in ([item] if isinstance(item, str) else list(item))]
    parsed = Properties.parse(texts)
    staging = Path(tempfile.mkdtemp(prefix="ralf-search-assert-"))
    try:
        outcome, record = evaluate(candidate, parsed, clock, keep=staging)
        if not outcome.violated:
            return
        directory = write_bundle(
            Path(bundles) / bundle_name(candidate, parsed.text), candidate, property_text=parsed.text, properties=texts, clock=clock, seed=seed,
            lines=outcome.lines(), summary=outcome.summary, recording=record.recording,
        )  # fmt: skip
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    failed = "\n".join(line for line, r in zip(outcome.lines(), outcome.results) if not r.passed)
    raise AssertionError(f"{candidate.describe()}\n{failed}\nbundle: {directory}")
