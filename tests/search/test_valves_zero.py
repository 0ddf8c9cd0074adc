"""``valves_zero_within``: both valves at zero within N ms of a fault and staying there, judged on
stand-in run records whose answer is known by construction; its bad forms refused in one line;
channel-fault sizes drawn from a range."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from protocol.channel_faults import ChannelFault
from workbench.search.properties import PropertyError, parse_property
from workbench.search.space import SpaceError, space_from
from workbench.search.strategies import candidates

TS = 0.005


def _record(
    u1: list[float], u2: list[float] | None = None, *, events: tuple[tuple[str, float], ...] = (), error: str | None = None, scenario: Any = None
) -> Any:
    """A run record of len(u1) ticks (t_s = k Ts), the plant's events, the controller's end."""
    n = len(u1)
    columns = {"t_s": np.arange(n) * TS, "u1_v": np.asarray(u1, float), "u2_v": np.asarray(u1 if u2 is None else u2, float)}
    return SimpleNamespace(
        columns=columns,
        events=[SimpleNamespace(kind=k, sim_time_s=t) for k, t in events],
        error=error,
        counters={"valves_zeroed": 1},
        config={"sample_rate_hz": 1 / TS},
        settings={"plant": {"scenario": scenario}} if scenario is not None else {},
    )


def _judge(text: str, record: Any) -> Any:
    return parse_property(text).judge(record)


def test_a_stop_on_the_first_faulted_sample_is_zero_latency() -> None:
    """Tick 199 reads the plant's sample of 1.0 s (the fault's first); a monitor stops the run there:
    its row is not recorded, the valves' zero takes its slot, 0 ms after the fault."""
    record = _record([0.5] * 199, events=(("channel_fault", 1.0),), error="stopped by monitor policy: input_rate: tick 199")
    result = _judge("valves_zero_within(events.channel_fault, 0)", record)
    assert result.passed and result.measured == pytest.approx(0.0, abs=1e-9), result.line()
    assert "the controller stopped the run: stopped by monitor policy" in result.line()


def test_valves_that_never_settle_at_zero_fail_and_say_no_monitor_stopped() -> None:
    u = [0.0 if k % 3 == 1 else 0.0049 for k in range(400)]  # through zero now and then, never for good
    result = _judge("valves_zero_within(events.channel_fault, 50)", _record(u, events=(("channel_fault", 1.0),)))
    assert result.level == "FAIL" and math.isinf(result.measured), result.line()
    assert "no valves_at_zero(u1_v, u2_v) after the cause events.channel_fault at 1 s" in result.line() and "no monitor stopped the run" in result.line()


@pytest.mark.parametrize(("zero_from_tick", "within_ms", "passes"), [(209, 55, True), (209, 54, False), (215, 85, True), (215, 84, False)])
def test_the_latency_is_the_first_tick_from_which_both_stay_zero(zero_from_tick: int, within_ms: float, passes: bool) -> None:
    """Both valves zero from tick k to the end (the second a tick after the first): at the plant's
    time (k + 1) Ts, whatever zeros came before."""
    u1 = [0.0 if k >= zero_from_tick or k == 205 else 1.0 for k in range(400)]
    u2 = [0.0 if k >= zero_from_tick + 1 else -1.0 for k in range(400)]  # the second valve a tick later
    result = _judge(f"valves_zero_within(events.channel_fault, {within_ms})", _record(u1, u2, events=(("channel_fault", 1.0),)))
    expected = (zero_from_tick + 2) * TS - 1.0
    assert result.passed is passes and result.measured == pytest.approx(expected, abs=1e-9), result.line()


def test_the_fault_cause_is_the_scenario_s_earliest_channel_fault() -> None:
    scenario = {"channel_faults": [{"channel": "AI3", "kind": "stuck", "start_s": 1.2}, {"channel": "AI1", "kind": "open", "start_s": 1.1}]}
    for given_as in (scenario, json.dumps(scenario)):
        record = _record([1.0] * 219, error="stopped by monitor policy: input_stuck: tick 219", scenario=given_as)
        result = _judge("valves_zero_within(fault, 10)", record)
        assert result.passed and result.details["cause_t_s"] == pytest.approx(1.1) and result.measured == pytest.approx(0.0, abs=1e-9), result.line()


def test_a_run_without_the_cause_holds_and_one_too_short_compared_nothing() -> None:
    assert _judge("valves_zero_within(events.channel_fault, 50)", _record([1.0] * 100)).passed
    assert _judge("valves_zero_within(fault, 50)", _record([1.0] * 100)).passed
    short = _judge("valves_zero_within(events.channel_fault, 50)", _record([1.0] * 205, events=(("channel_fault", 1.0),)))
    assert short.level == "INVALID" and "before the limit 1.05 s" in short.line(), short.line()


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("valves_zero_within(events.channel_fault, -1)", "valves_zero_within's N_MS must not be negative, got '-1'"),
        ("valves_zero_within(events.channel_falt, 50)", "no run record holds a signal 'events.channel_falt' (did you mean 'events.channel_fault'?)"),
        ("valves_zero_within(defl1_in, 50)", "valves_zero_within's CAUSE is a plant event (events.channel_fault) or fault"),
        ("valves_zero_within(fault, soon)", "valves_zero_within's N_MS must be a number, got 'soon'"),
        ("valves_zero_within(fault)", "takes 2 arguments, got 1"),
        ("valves_zero(fault, 5)", "did you mean 'valves_zero_within'?"),
    ],
)
def test_a_bad_valves_zero_property_is_one_line(text: str, says: str) -> None:
    with pytest.raises(PropertyError) as err:
        parse_property(text)
    assert says in str(err.value) and "\n" not in str(err.value)


SIZES = space_from(
    {
        "duration_s": 2.0,
        "channel_faults": [
            {"channels": ["AI3", "AI1"], "kind": "offset", "start_s": [1.0, 1.2, 0.05], "length_s": 1.0, "params": {"offset_v": [-2.0, 0.0, 0.05]}},
            {
                "channels": ["AI4"],
                "kind": "noise",
                "start_s": 1.0,
                "length_s": 0.5,
                "params": {"sigma_v": {"min": 0.1, "max": 0.5, "step": 0.1}, "seed": [0, 5]},
            },
        ],
    }
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(candidates(SIZES))
def test_a_channel_fault_s_size_is_drawn_from_its_range(candidate: Any) -> None:
    for fault in candidate.channel_faults:
        ChannelFault.model_validate(fault)  # the plant's own schema
        if fault["kind"] == "offset":
            assert -2.0 <= fault["offset_v"] <= 0.0 and round(fault["offset_v"] / 0.05, 6).is_integer()
        else:
            assert fault["sigma_v"] in (0.1, 0.2, 0.3, 0.4, 0.5) and isinstance(fault["seed"], int) and 0 <= fault["seed"] <= 5


def test_a_size_range_the_plant_refuses_at_either_end_is_one_line() -> None:
    bad = {"duration_s": 2.0, "channel_faults": [{"channels": ["AI3"], "kind": "offset", "start_s": 1.0, "length_s": 1.0, "params": {"offset_v": [-30, 0]}}]}
    with pytest.raises(SpaceError) as err:
        space_from(bad)
    assert "AI3 offset" in str(err.value) and "\n" not in str(err.value)
