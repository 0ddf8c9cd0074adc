"""The known minimal violations of the planted weaknesses, judged within one grid step of the allowance."""

from __future__ import annotations

from workbench.search.planted import (
    PLANTED,
    TPDO_LOSS_MINIMAL_S,
    blind_band_differs,
    interrupt_outage_differs,
    push_differs,
    tpdo_dropped,
    tpdo_loss_differs,
)
from workbench.search.strategies import Candidate


def _outage(link: str, kind: str, start: float, length: float, duration: float) -> Candidate:
    fault = {"link": link, "kinds": [kind], "drop": 1.0, "start_s": start, "stop_s": round(start + length, 9)}
    return Candidate(duration, {"faults": [fault]}, [], {})


def test_the_interrupt_outage_is_known_at_the_stale_allowance() -> None:
    assert interrupt_outage_differs(_outage("zenoh", "interrupt", 2.0, 0.5, 3.0)) is None
    assert interrupt_outage_differs(_outage("zenoh", "interrupt", 2.0, 0.505, 3.0)) is None  # one grid step
    assert interrupt_outage_differs(_outage("zenoh", "interrupt", 2.0, 0.6, 3.0)) is not None
    assert interrupt_outage_differs(_outage("zenoh", "interrupt", 2.0, 0.5, 3.5)) is not None
    two = Candidate(3.0, {"faults": [_outage("zenoh", "interrupt", 2.0, 0.5, 3.0).scenario["faults"][0]] * 2}, [], {})
    assert interrupt_outage_differs(two) is not None


def test_the_tpdo_loss_is_known_at_the_allowance_periods_plus_one() -> None:
    known = _outage("can", "tpdo", 1.0, TPDO_LOSS_MINIMAL_S, 1.5)
    assert tpdo_dropped(known) == 51 and tpdo_loss_differs(known) is None
    assert tpdo_loss_differs(_outage("can", "tpdo", 1.0, 0.27, 1.5)) is not None
    assert tpdo_loss_differs(_outage("can", "tpdo", 1.2, TPDO_LOSS_MINIMAL_S, 1.5)) is not None


def test_the_push_is_known_at_the_measured_threshold() -> None:
    push = {"input": "disturbance.link2", "shape": "step", "at_s": 1.0, "for_s": 0.1, "size": 40.0}
    assert push_differs(Candidate(2.0, {}, [], {}, [push]), 40) is None
    assert push_differs(Candidate(2.0, {}, [], {}, [{**push, "size": 42.0}]), 40) is not None
    assert push_differs(Candidate(2.0, {}, [], {}, [{**push, "at_s": 1.05}]), 40) is not None
    assert PLANTED["push-on-link-2"].differs is None  # its threshold is measured, not known from a setting


def test_the_blind_band_is_known_one_step_inside_the_rate_limit() -> None:
    fault = {"channel": "AI3", "kind": "offset", "start_s": 1.0, "end_s": 2.0, "offset_v": -0.45}
    assert blind_band_differs(Candidate(1.5, {}, [fault], {})) is None
    assert blind_band_differs(Candidate(1.5, {}, [{**fault, "offset_v": -0.3}], {})) is not None
    assert blind_band_differs(Candidate(1.5, {}, [{**fault, "channel": "AI1"}], {})) is not None
