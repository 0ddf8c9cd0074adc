"""Candidates run in batches as tasks of the campaign engine (:mod:`workbench.campaign.engine`).

:func:`engine_prefetch` gives :func:`workbench.search.engine.search` a
``prefetch``: each batch of candidates becomes one Dask task per candidate
(:meth:`Engine.map`), run on the engine's workers (a local cluster, or a
scheduler's), and the outcomes come back to the one process where Hypothesis
runs. A task that failed (a worker died, the rig raised) is run again here,
so its outcome, or its error, is the search's as without batches.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from workbench.search.properties import Properties
from workbench.search.runner import Outcome, SearchClock, evaluate
from workbench.search.strategies import Candidate


def run_task(item: tuple[dict[str, Any], list[str], str]) -> Outcome:
    """Worker side: one candidate (as a mapping), its properties' texts and the clock -> its outcome."""
    data, texts, clock = item
    root = logging.getLogger()
    if not root.handlers:  # a worker's runs: their WARNING lines are counted in their verdicts, not printed
        root.addHandler(logging.NullHandler())
    return evaluate(Candidate.from_dict(data), Properties.parse(texts), "lockstep" if clock == "lockstep" else "cosim")[0]


def engine_prefetch(properties: Sequence[str], clock: SearchClock, engine: Any = None) -> Any:
    """A ``prefetch`` running each batch on ``engine`` (default: :func:`current_engine`)."""
    texts = list(properties)

    def prefetch(batch: list[Candidate]) -> list[Outcome]:
        from workbench.campaign.engine import current_engine

        eng = engine or current_engine()
        results = eng.map(run_task, [(c.as_dict(), texts, clock) for c in batch], description="search batch", show_progress=False)
        return [r.value if r.ok and r.value is not None else run_task((c.as_dict(), texts, clock)) for r, c in zip(results, batch)]

    return prefetch
