"""The query gate (service_kit/query_gate.py): a token bucket per query kind, every refusal counted, logged once per interval."""

from __future__ import annotations

import logging

import pytest

from service_kit.inbox import Limit
from service_kit.query_gate import QUERY_LIMITS, QueryGate, gate


def test_burst_then_the_rate_then_refused_and_counted(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    g = QueryGate("tf", Limit(rate_per_s=2.0, burst=3), clock=lambda: now[0])
    caplog.set_level(logging.WARNING, logger="service_kit.query_gate")
    assert [g.admit() for _ in range(5)] == [True, True, True, False, False]
    now[0] = 1.0  # two tokens refilled
    assert [g.admit() for _ in range(3)] == [True, True, False]
    for _ in range(5):
        g.note_answered()
    g.note_failed()
    assert g.as_dict() == {"q_tf_answered": 5, "q_tf_failed": 1, "q_tf_dropped_rate": 3}
    assert len([r for r in caplog.records if "queries a second" in r.getMessage()]) == 1  # once per interval, not per query


def test_every_query_kind_the_rig_answers_has_a_limit() -> None:
    from protocol.rig_description import RIG

    queryables = {c.suffix.rsplit("/", 1)[-1] for c in RIG.channels if c.kind == "queryable"}
    assert queryables <= set(QUERY_LIMITS), queryables
    assert gate("tf").limit == QUERY_LIMITS["tf"]


def test_the_rig_answers_queries_only_on_its_gated_queryables() -> None:
    """Every ``declare_queryable`` of the rig's packages is the DSP's TF
    queryable or a board's parameter table (``BOARD/params``,
    service_kit/param_commands.py), the queryable channels of the rig
    description, each answer through its gate; no other code of the rig
    answers a query (liveliness and admin-space queries are zenoh's:
    docs/reliability.md)."""
    import re
    from pathlib import Path

    from protocol.rig_description import RIG

    root = Path(__file__).resolve().parents[2]
    declared = {
        f"{path.relative_to(root)}: {match}"
        for package in ("controller", "dsp_service", "plant_emulator", "protocol", "service_kit", "workbench")
        for path in sorted((root / package).rglob("*.py"))
        for match in re.findall(r"declare_queryable\(([^)]*)\)", path.read_text())
    }
    assert declared == {"dsp_service/service.py: self.keys.tf, self._on_tf_query", "service_kit/param_commands.py: self.keys.params, self._on_query"}, declared
    assert {c.suffix for c in RIG.channels if c.kind == "queryable"} == {"dsp/tf", "controller/params", "plant/params"}
