"""Bad search spaces and properties are refused in one line; good ones build the rig's own formats."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, find, given, settings

from protocol.channel_faults import ChannelFault
from service_kit.link_faults import Scenario
from workbench.search.engine import Budget
from workbench.search.properties import Properties, PropertyError, parse_property
from workbench.search.space import SpaceError, parse_space, space_from
from workbench.search.strategies import candidates
from workbench.stimulus import Stimulus

BASE = {"duration_s": [1.0, 4.0, 0.5]}
SPACE = space_from(
    {
        "duration_s": [1.0, 4.0, 0.5],
        "link_faults": [
            {"link": "zenoh", "kinds": ["interrupt", "batch"], "start_s": [0.5, 3.0, 0.005], "length_s": [0.0, 1.0, 0.005]},
            {"link": "can", "kinds": ["rpdo"], "start_s": [1.0, 2.0, 0.01], "length_s": [0.01, 0.2, 0.01], "drop": [0.1, 1.0, 0.1], "duplicate": [0, 0.5, 0.1]},
        ],
        "max_link_faults": 3,
        "stalls": [{"at_s": [0.5, 1.0, 0.1], "wall_s": [0.0, 0.1, 0.01]}],
        "channel_faults": [
            {"channels": ["AI3", "AI4"], "kind": "offset", "start_s": [0.5, 2.0, 0.1], "length_s": [0.1, 1.0, 0.1], "params": {"offset_v": 0.5}}
        ],
        "stimuli": [
            {
                "inputs": ["disturbance.link2", "valve.u1"],
                "shape": "step",
                "start_s": [0.5, 2.0, 0.1],
                "length_s": [0.1, 1.0, 0.1],
                "params": {"size": [0, 8, 1]},
            }
        ],
        "fault_seed": [0, 5],
        "settings": {"controller.batch_size": [10, 40, 10], "dsp.fft_width": {"choices": [256, 512]}, "controller.timeouts.stale_after_s": [0.5, 2.0, 0.5]},
        "fixed": {"controller": {"tf_download_samples": 0, "timeouts": {"plant_heartbeat_s": 0.5}}},
    }
)


@pytest.mark.parametrize(
    ("space", "says"),
    [
        ({"duration_s": [4.0, 1.0]}, "inverted range: min 4 > max 1"),
        ({**BASE, "link_faults": [{"link": "zenoh", "kinds": [], "start_s": 0, "length_s": 1}]}, "at least 1 item"),
        ({**BASE, "link_faults": [{"link": "can", "kinds": ["interrupt"], "start_s": 0, "length_s": 1}]}, "can has no message kind 'interrupt'"),
        ({**BASE, "link_faults": [{"link": "can", "kinds": ["sync"], "start_s": 0, "length_s": 1, "drop": [0.5, 2.0]}]}, "drop is a probability"),
        ({**BASE, "settings": {"controller.no_such_setting": [1, 2]}}, "no_such_setting"),
        ({**BASE, "settings": {"dsp.fft_width": {"choices": []}}}, "at least 1 item"),
        ({**BASE, "channel_faults": [{"channels": ["AI9"], "kind": "open", "start_s": 0, "length_s": 1}]}, "unknown channel 'AI9'"),
        ({**BASE, "channel_faults": [{"channels": ["AI1"], "kind": "offset", "start_s": 0, "length_s": 1}]}, "AI1 offset"),
        ({"duration_s": [0.0, 1.0]}, "duration_s must be positive"),
        ({**BASE, "fixed": {"pump": {}}}, "unknown service 'pump'"),
        ({**BASE, "stimuli": [{"inputs": ["valve.u9"], "shape": "step", "start_s": 0, "length_s": 1, "params": {"size": 1}}]}, "valve.u9 step"),
        ({**BASE, "stimuli": [{"inputs": ["valve.u1"], "shape": "step", "start_s": 0, "length_s": 1, "params": {"size": [0, 50]}}]}, "valve.u1 step"),
        ({**BASE, "settings": {"dsp.fft_width": [256, 300000, 256]}}, "dsp: "),
        ({**BASE, "settings": {"dsp.fft_width": {"choices": [256, 7]}}}, "dsp: "),
    ],
)
def test_a_bad_space_is_one_line(space: dict, says: str) -> None:
    with pytest.raises(SpaceError) as err:
        space_from(space)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_space_file_that_is_not_yaml_is_one_line() -> None:
    with pytest.raises(SpaceError, match="neither JSON nor YAML"):
        parse_space("duration_s: [1, 2\nfoo: : :")


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("streek(1)", "no property named 'streek' (did you mean 'streak'?)"),
        ("within(defl3_in, -1, 1)", "no run record holds a signal 'defl3_in' (did you mean 'defl2_in'?)"),
        ("within(truth.nothing[0], -1, 1)", "no run record holds a signal 'truth.nothing[0]'"),
        ("within(events.explosion, 0, 0)", "'events.explosion'"),
        ("within(defl1_in, 1, -1)", "LOW is above HIGH"),
        ("streak(-1)", "streak's N is a count"),
        ("verdict(GOOD)", "verdict's LEVEL is one of PASS, DEGRADED, FAIL, INVALID"),
        ("mode(0)", "REL_TOL must be positive"),
        ("streak", "is not NAME(ARG, ...)"),
        ("within(defl1_in)", "takes 3 to 4 arguments, got 1"),
    ],
)
def test_a_bad_property_is_one_line(text: str, says: str) -> None:
    with pytest.raises(PropertyError) as err:
        parse_property(text)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_no_property_and_a_budget_of_zero_are_refused() -> None:
    with pytest.raises(PropertyError, match="no property given"):
        Properties.parse([])
    with pytest.raises(ValueError, match="at least one run"):
        Budget(0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(candidates(SPACE))
def test_every_candidate_is_a_valid_scenario_and_valid_settings(candidate) -> None:  # type: ignore[no-untyped-def]
    """The rig's own schemas (the scenario file's, the channel faults', the settings') accept every draw."""
    from workbench.hil import check_settings

    faults = candidate.faults()
    if faults is not None:
        scenario = Scenario.model_validate(faults)
        for f in scenario.faults:
            assert f.stop_s is not None and 0 <= f.stop_s - f.start_s <= 1.0 + 1e-9
    for c in candidate.channel_faults:
        ChannelFault.model_validate(c)
    Stimulus(candidate.stimulus).plans()  # the services' own check of the profiles
    check_settings(candidate.rig_settings())
    assert 1.0 <= candidate.duration_s <= 4.0
    assert candidate.settings["controller"]["timeouts"]["plant_heartbeat_s"] == 0.5  # a group keeps its fixed keys
    assert isinstance(candidate.settings["controller"]["batch_size"], int)  # an integer grid stays integers


def test_shrinking_goes_to_fewer_faults_shorter_runs_smaller_and_earlier_faults() -> None:
    """Hypothesis's own minimiser, asked for any run with a fault longer than 0.3 s,
    lands on one fault at the earliest start, just over 0.3 s, on the shortest run,
    every setting at its first value."""
    minimal = find(
        candidates(SPACE),
        lambda c: any(f["stop_s"] - f["start_s"] > 0.3 + 1e-9 for f in c.scenario.get("faults", [])),
        settings=settings(database=None, max_examples=500, suppress_health_check=list(HealthCheck)),
    )
    (fault,) = minimal.scenario["faults"]
    assert fault == {"link": "zenoh", "kinds": ["interrupt"], "start_s": 0.5, "stop_s": 0.805, "drop": 1.0}
    assert minimal.duration_s == 1.0 and minimal.scenario["stalls"] == [] and minimal.channel_faults == [] and minimal.stimulus == []
    assert minimal.scenario["seed"] == 0
    assert minimal.settings["controller"]["batch_size"] == 10 and minimal.settings["dsp"]["fft_width"] == 256


def test_a_pushing_candidate_shrinks_to_a_small_push() -> None:
    minimal = find(
        candidates(SPACE),
        lambda c: any(p["size"] >= 3 for p in c.stimulus),
        settings=settings(database=None, max_examples=500, suppress_health_check=list(HealthCheck)),
    )
    assert minimal.stimulus == [{"input": "disturbance.link2", "shape": "step", "at_s": 0.5, "for_s": 0.1, "size": 3}]
    assert minimal.scenario == {} and minimal.channel_faults == []
