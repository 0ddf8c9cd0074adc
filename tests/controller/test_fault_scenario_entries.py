"""The fault scenario's entries beside the link faults: loop stalls and a slowed
DSP board, and the SYNC outage that drops every n-th SYNC (the cases the
retired single-knob settings used to hold)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller.fault_stage import LoopStalls
from dsp_service.core import DspCore
from protocol.settings import DspSettings
from service_kit.link_faults import FaultEngine, ScenarioError, parse_scenario, scenario_setting

EVERY_50TH_SYNC = {"faults": [{"link": "can", "kinds": ["sync"], "start_s": 0.2425, "outage": {"every_s": 0.25, "length_s": 0.005}}]}


def test_a_stall_freezes_the_loop_before_its_tick_only() -> None:
    stalls = LoopStalls.from_scenario(parse_scenario(json.dumps({"stalls": [{"at_s": 1.0, "wall_s": 0.4}, {"at_s": 2.5, "wall_s": 0.1}]})), 200.0)
    assert stalls.stall_at_tick == 200
    assert [t for t in range(1000) if stalls.stall_now(t)] == [200, 500]
    assert (stalls.stall_now(200), stalls.stall_now(500)) == (0.4, 0.1)
    twice = LoopStalls.from_scenario(parse_scenario('{"stalls": [{"at_s": 1.0, "wall_s": 0.4}, {"at_s": 1.001, "wall_s": 0.2}]}'), 200.0)
    assert twice.at_ticks == {200: pytest.approx(0.6)}  # both round to tick 200: they add up


def test_no_stall_means_the_loop_checks_nothing() -> None:
    assert LoopStalls.from_scenario(None, 200.0).stall_at_tick is None
    assert LoopStalls.from_scenario(parse_scenario(json.dumps(EVERY_50TH_SYNC)), 200.0).stall_at_tick is None


def test_the_documented_sync_outage_drops_every_50th_sync_at_200_hz() -> None:
    engine = FaultEngine(parse_scenario(json.dumps(EVERY_50TH_SYNC)))
    dropped = [tick for tick in range(20_000) if engine.decide("sync", tick, tick / 200.0, 0.0).dropped]
    assert dropped == list(range(49, 20_000, 50))


@pytest.mark.parametrize(
    "text",
    [
        '{"stalls": [{"at_s": 1.0, "wall_s": 61}]}',
        '{"stalls": [{"at_s": -1.0, "wall_s": 0.1}]}',
        '{"stalls": [{"at_s": 1.0}]}',
        '{"stalls": [{"at_s": 1.0, "wall_s": 0.1, "every_s": 2}]}',
        '{"dsp_delay_s": 11}',
        '{"dsp_delay_s": -0.1}',
        '{"dsp_delay_s": NaN}',
    ],
)
def test_bad_entries_are_one_line(text: str) -> None:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text)
    assert "\n" not in str(info.value)


def test_the_setting_reads_inline_json_or_a_file(tmp_path: Path) -> None:
    assert scenario_setting("") is None and scenario_setting("  ") is None
    assert scenario_setting('{"dsp_delay_s": 0.3}').dsp_delay_s == 0.3  # type: ignore[union-attr]
    path = tmp_path / "slow.yaml"
    path.write_text("dsp_delay_s: 0.2\nstalls:\n  - {at_s: 3, wall_s: 0.5}\n")
    scenario = scenario_setting(str(path))
    assert scenario is not None and scenario.dsp_delay_s == 0.2 and scenario.stalls[0].wall_s == 0.5


def test_the_dsp_board_takes_its_delay_from_the_scenario() -> None:
    base = {"can_interface": "virtual", "fft_width": 256}
    assert DspCore(DspSettings(**base)).extra_delay_s == 0.0
    assert DspCore(DspSettings(**base, fault_scenario='{"dsp_delay_s": 0.35}')).extra_delay_s == 0.35
